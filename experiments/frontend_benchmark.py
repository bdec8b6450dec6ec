"""Speed of the raw laser front end on the whole Victoria Park log (docs/frontend.md).

    .venv/bin/python experiments/frontend_benchmark.py [--data DIR] [--repeats 5]

Prints one row per stage: reading LASER.txt, extract_features over all 7,230 scans at once, and
in chunks of 1000 scans (what `nanoslam detect` runs, for its progress bar). The front end is
NumPy: nothing is compiled, the first call is as fast as the others.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from nanoslam_jax.app.config import DetectorConfig  # noqa: E402
from nanoslam_jax.data import load_laser  # noqa: E402
from nanoslam_jax.frontend import extract_features, extract_features_chunked  # noqa: E402
import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)  # the library computes in float64


def timed(fn, repeats: int) -> tuple[np.ndarray, object]:
    out, times = None, []
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return np.asarray(times), out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", default=str(ROOT.parent / "shared" / "data" / "victoria_park"))
    p.add_argument("--repeats", type=int, default=5)
    args = p.parse_args(argv)
    cfg = DetectorConfig()
    t_load, scans = timed(lambda: load_laser(args.data), max(1, args.repeats // 2))
    t_all, feats = timed(lambda: extract_features(scans, cfg), args.repeats)
    t_chunk, _ = timed(lambda: extract_features_chunked(scans, cfg), args.repeats)
    print(
        f"{scans.n_scans} scans x {scans.n_beams} beams, {os.cpu_count()} CPUs; {feats.points.r.size} returns, "
        f"{feats.clusters.scan.size} clusters, {feats.lines.scan.size} lines, {feats.circles.scan.size} circles, "
        f"{feats.corners.scan.size} corners, {feats.breakpoints.scan.size} break points, "
        f"{feats.trees.scan.size} trees"
    )
    print("| stage | best (s) | median (s) | per scan (ms) | target |")
    print("|---|---|---|---|---|")
    for name, t, target in (
        ("read LASER.txt", t_load, ""),
        ("features, whole log at once", t_all, "<= 5 s"),
        ("features, chunks of 1000 scans (nanoslam detect)", t_chunk, "<= 5 s"),
    ):
        print(f"| {name} | {t.min():.2f} | {np.median(t):.2f} | {1000 * np.median(t) / scans.n_scans:.3f} | {target} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
