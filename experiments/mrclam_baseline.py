"""The dead-reckoning map of UTIAS MRCLAM: the baseline a SLAM map of each robot's log is read against.

    python experiments/mrclam_baseline.py                     # ../shared/data/utias_mrclam/MRCLAM_Dataset1
    python experiments/mrclam_baseline.py --data DIR --robots 1 3 --json baseline.json

For each robot: its log (nanoslam_jax.data.load_mrclam), the dead-reckoned path (the (v, omega)
odometry integrated exactly), every landmark sighting projected from it and averaged per barcode
(nanoslam_jax.data.dead_reckoning_map), and that map against the surveyed landmarks after the
best rigid alignment, paired by landmark id (nanoslam_jax.eval.metrics.map_alignment_metrics). Prints a
Markdown table.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from nanoslam_jax.app.config import load_config, resolve_data_dir
from nanoslam_jax.data import MRCLAM_ROBOTS, dead_reckoning_map, load_mrclam
from nanoslam_jax.eval.metrics import map_alignment_metrics
import jax

jax.config.update("jax_enable_x64", True)  # the library computes in float64


def baseline(directory: Path, robot: int, match_radius: float) -> dict:
    """The dead-reckoning map figures of one robot's log."""
    raw = load_mrclam(directory, robot)
    dr_map = dead_reckoning_map(raw)
    m = map_alignment_metrics(dr_map.xy, raw.truth_landmarks, dr_map.ids, raw.landmark_ids, match_radius)
    return {
        "robot": robot,
        "duration_s": float(raw.dr[-1, 0]),
        "odometry_samples": int(raw.dr.shape[0]),
        "sightings": int(dr_map.counts.sum()),
        "scans": int(np.unique(raw.detections[:, 0]).size),
        "landmarks_seen": int(dr_map.ids.size),
        "landmarks_surveyed": int(raw.landmark_ids.size),
        "dr_map_rmse": m["rmse"],
        "dr_map_found": m["n_found"],
        "align_rotation_deg": m["align_rotation_deg"],
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument(
        "--data",
        help="the MRCLAM dataset directory (default: data.path, $NANOSLAM_DATA, "
        "../shared/data/utias_mrclam/MRCLAM_Dataset1)",
    )
    p.add_argument("--robots", type=int, nargs="+", default=list(MRCLAM_ROBOTS), choices=MRCLAM_ROBOTS)
    p.add_argument("--radius", type=float, default=0.5, help="match radius (m) of the found landmarks")
    p.add_argument("--json", help="also write the figures here")
    args = p.parse_args()
    cfg = load_config(None, ["data.kind=victoria_park", "data.format=mrclam", "model.motion=unicycle"])
    directory = resolve_data_dir(cfg, args.data)
    rows = [baseline(directory, r, args.radius) for r in args.robots]
    print(
        f"UTIAS MRCLAM, {directory}: dead-reckoning map against the surveyed landmarks after a rigid alignment "
        f"by landmark id\n"
    )
    print(
        f"| robot | duration (s) | odometry samples | sightings | scans | landmarks seen | DR map RMSE (m) "
        f"| found within {args.radius:g} m |"
    )
    print("|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(
            f"| {r['robot']} | {r['duration_s']:.1f} | {r['odometry_samples']} | {r['sightings']} | {r['scans']} "
            f"| {r['landmarks_seen']} of {r['landmarks_surveyed']} | {r['dr_map_rmse']:.3f} | {r['dr_map_found']} |"
        )
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
