"""The UTIAS MRCLAM results table: finished `nanoslam sweep`s of configs/sweeps/mrclam_robots.yaml
(or of subsets of its methods, one directory each) as one Markdown row per robot, association and
method.

    nanoslam sweep configs/sweeps/mrclam_robots.yaml --out results/mrclam_robots
    python experiments/mrclam_table.py results/mrclam_robots [more sweep directories] [--data DIR]

Each row: the map's RMSE after the best rigid alignment onto the surveyed landmarks, pairs found by
position (survey_rmse: median, interquartile range and worst over the seeds), landmarks found and
spurious (medians), the same RMSE pairing each landmark with the surveyed one of its barcode
(known association), and the dead-reckoning map of the same robot (every sighting projected from
the dead-reckoned path, averaged per barcode, paired by barcode) with its ratio to the median.
Seeds are summarised under the failed-seed rule of every command (``nanoslam_jax.eval._scoring``): a
failed run (e.g. a landmark capacity overflow under the sweep's ``fail_on_overflow``) is counted in
the row and counts as the worst value (an infinite RMSE, ``-inf`` landmarks found), so a median
that more than half the seeds failed is ``inf`` (the finished runs' values are given beside it).
"""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path

from nanoslam_jax.eval._scoring import format_number, summarize_runs
from nanoslam_jax.app.config import load_config, resolve_data_dir
from nanoslam_jax.data import dead_reckoning_map, load_mrclam
from nanoslam_jax.eval.metrics import map_alignment_metrics
import jax

jax.config.update("jax_enable_x64", True)  # the library computes in float64

#: Table labels and order of the methods and associations.
METHODS = {
    "ekf_slam": "EKF-SLAM",
    "fastslam1": "FastSLAM 1.0",
    "fastslam2": "FastSLAM 2.0",
    "ufastslam": "UFastSLAM",
    "iterated": "Iterated",
    "nano": "NANO",
}
ASSOCIATIONS = {"known": "known", "nearest": "unknown"}


def _order(key: tuple) -> tuple:
    robot, assoc, method = key
    names = list(METHODS)
    return robot, list(ASSOCIATIONS).index(assoc), names.index(method) if method in names else len(names), method


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("sweep", nargs="+", help="sweep output directories (each holding results.csv)")
    p.add_argument("--data", help="the MRCLAM dataset directory (default: as configs/mrclam.yaml finds it)")
    args = p.parse_args()
    cfg = load_config(Path(__file__).resolve().parents[1] / "configs" / "mrclam.yaml")
    rows = []
    for d in args.sweep:
        # settings a sweep fixes for all its runs (its `set:`) are in its resolved base config
        base = Path(d) / "base_config.yaml"
        fixed = load_config(base) if base.is_file() else cfg
        defaults = {
            "data.robot": str(fixed.data.robot),
            "filter.association": fixed.filter.association,
            "filter.method": fixed.filter.method,
        }
        with open(Path(d) / "results.csv") as f:
            rows += [{**defaults, **{k: v for k, v in r.items() if v != ""}} for r in csv.DictReader(f)]
    directory = resolve_data_dir(cfg, args.data)
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        key = (
            int(r.get("data.robot") or cfg.data.robot),
            r.get("filter.association") or cfg.filter.association,
            r.get("filter.method") or cfg.filter.method,
        )
        groups.setdefault(key, []).append(r)
    baseline = {}
    for robot in sorted({k[0] for k in groups}):
        raw = load_mrclam(directory, robot)
        m = dead_reckoning_map(raw)
        baseline[robot] = map_alignment_metrics(m.xy, raw.truth_landmarks, m.ids, raw.landmark_ids)["rmse"]
    print(
        "| robot | association | method | runs (failed) | map RMSE median [IQR] worst (m) | found | spurious "
        "| paired by barcode (m) | DR map (m) | DR / SLAM |"
    )
    print("|---:|---|---|---:|---|---:|---:|---:|---:|---:|")
    for (robot, assoc, method), rs in sorted(groups.items(), key=lambda kv: _order(kv[0])):
        st = summarize_runs(
            rs,
            ["survey_rmse", "survey_found", "survey_spurious", "survey_rmse_by_id"],
            stats=("median", "q1", "q3", "worst"),
        )
        med = st["survey_rmse_median"]
        by_id = st["survey_rmse_by_id_median"]
        by_id_s = "-" if math.isnan(by_id) else format_number(by_id)
        ratio = f"{baseline[robot] / med:.0f}x" if math.isfinite(med) and med > 0 else "-"
        if st["n_runs"] == 1:  # a deterministic method: one value
            rmse = format_number(med)
        elif math.isfinite(med):
            rmse = (
                f"{format_number(med)} [{format_number(st['survey_rmse_q1'])}, "
                f"{format_number(st['survey_rmse_q3'])}] {format_number(st['survey_rmse_worst'])}"
            )
        else:  # more than half the seeds failed: the finished runs beside the inf
            done = sorted(float(r["survey_rmse"]) for r in rs if r.get("status", "ok") == "ok" and r.get("survey_rmse"))
            vals = "-".join(format_number(v) for v in (done[:1] + done[-1:] if len(done) > 1 else done))
            rmse = f"inf (the {len(done)} finished: {vals})" if done else "inf"
        found = "-" if not math.isfinite(st["survey_found_median"]) else f"{st['survey_found_median']:g}"
        spurious = "-" if not math.isfinite(st["survey_spurious_median"]) else f"{st['survey_spurious_median']:g}"
        print(
            f"| {robot} | {ASSOCIATIONS.get(assoc, assoc)} | {METHODS.get(method, method)} | "
            f"{st['n_runs']} ({st['n_failed']}) | {rmse} | {found} | {spurious} | {by_id_s} | "
            f"{baseline[robot]:.2f} | {ratio} |"
        )


if __name__ == "__main__":
    main()
