"""The UTIAS MRCLAM results table: a finished `nanoslam sweep` of configs/sweeps/mrclam_robots.yaml
(or a subset of its methods) as one Markdown row per robot, association and method.

    nanoslam sweep configs/sweeps/mrclam_robots.yaml --out results/mrclam_robots
    python experiments/mrclam_table.py results/mrclam_robots [--data DIR]

Each row: the map's RMSE after the best rigid alignment onto the surveyed landmarks, pairs found by
position (survey_rmse: median, interquartile range and worst over the seeds), landmarks found and
spurious (medians), the same RMSE pairing each landmark with the surveyed one of its barcode
(known association), and the dead-reckoning map of the same robot (every sighting projected from
the dead-reckoned path, averaged per barcode, paired by barcode) with its ratio to the median.
Failed runs are counted in the row, never dropped from it silently.
"""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path

import numpy as np

from nanoslam_jax.config import load_config, resolve_data_dir
from nanoslam_jax.data import dead_reckoning_map, load_mrclam
from nanoslam_jax.metrics import map_alignment_metrics


def _stats(values: list[float]) -> tuple[float, float, float, float]:
    v = np.asarray(values, dtype=float)
    if v.size == 0:
        return (math.nan,) * 4
    q1, med, q3 = np.percentile(v, [25, 50, 75])
    return float(med), float(q1), float(q3), float(np.max(v))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("sweep", help="the sweep's output directory (holding results.csv)")
    p.add_argument("--data", help="the MRCLAM dataset directory (default: as configs/mrclam.yaml finds it)")
    args = p.parse_args()
    with open(Path(args.sweep) / "results.csv") as f:
        rows = list(csv.DictReader(f))
    cfg = load_config(Path(__file__).resolve().parents[1] / "configs" / "mrclam.yaml")
    directory = resolve_data_dir(cfg, args.data)
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        key = (int(r.get("data.robot") or cfg.data.robot), r.get("filter.association") or cfg.filter.association,
               r.get("filter.method") or cfg.filter.method)
        groups.setdefault(key, []).append(r)
    baseline = {}
    for robot in sorted({k[0] for k in groups}):
        raw = load_mrclam(directory, robot)
        m = dead_reckoning_map(raw)
        baseline[robot] = map_alignment_metrics(m.xy, raw.truth_landmarks, m.ids, raw.landmark_ids)["rmse"]
    print("| robot | association | method | seeds (failed) | map RMSE median [IQR] worst (m) | found | spurious "
          "| by barcode, median (m) | DR map (m) | DR / SLAM |")
    print("|---:|---|---|---:|---|---:|---:|---:|---:|---:|")
    for (robot, assoc, method), rs in sorted(groups.items()):
        ok = [r for r in rs if r["status"] == "ok" and r.get("survey_rmse") not in ("", None)]
        med, q1, q3, worst = _stats([float(r["survey_rmse"]) for r in ok])
        found = np.median([float(r["survey_found"]) for r in ok]) if ok else math.nan
        spur = np.median([float(r["survey_spurious"]) for r in ok]) if ok else math.nan
        by_id = [float(r["survey_rmse_by_id"]) for r in ok if r.get("survey_rmse_by_id") not in ("", None)]
        by_id_s = f"{np.median(by_id):.3f}" if by_id else "-"
        print(f"| {robot} | {assoc} | {method} | {len(rs)} ({len(rs) - len(ok)}) | {med:.3f} [{q1:.3f}, {q3:.3f}] "
              f"{worst:.3f} | {found:g} | {spur:g} | {by_id_s} | {baseline[robot]:.2f} | {baseline[robot] / med:.0f}x |")


if __name__ == "__main__":
    main()
