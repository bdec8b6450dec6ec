"""SLAM with line landmarks on simulated indoor logs: pose, heading and Table 1 errors over seeds
(docs/method/lines-arcs.md, "SLAM with lines indoors").

    .venv/bin/python experiments/indoor_lines_table.py [--config configs/indoor_lines.yaml] [--seeds 1-8]
        [--set key=value ...]

For every seed ``s`` the config runs (:func:`nanoslam_jax.app.experiment.execute`) with ``seed = s`` and
``indoor.seed = s`` (a new world, drive, noise and filter seed each); each run's metrics are its
``metrics.json`` figures. Prints one row per seed and the median and worst over the seeds (a failed run
counts as the worst, :func:`nanoslam_jax.eval.seed_summary`), as a Markdown table.
"""

from __future__ import annotations

import argparse
import sys
import time

from _seeds import parse_seeds

from nanoslam_jax.app.config import load_config
from nanoslam_jax.app.experiment import execute
from nanoslam_jax.eval import seed_summary
import jax

jax.config.update("jax_enable_x64", True)  # the library computes in float64

#: The columns: metric, header, scale, digits.
COLUMNS = (
    ("rmse_fixed", "pos. RMSE (cm)", 100.0, 2),
    ("rmse_heading_deg", "heading RMSE (deg)", 1.0, 2),
    ("line_intercept_median", "intercept med. (cm)", 100.0, 2),
    ("line_slope_median", "slope med.", 1.0, 4),
    ("line_intercept_worst", "intercept worst (cm)", 100.0, 2),
    ("corner_median", "corner med. (cm)", 100.0, 2),
    ("corner_worst", "corner worst (cm)", 100.0, 2),
)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default="configs/indoor_lines.yaml")
    ap.add_argument("--seeds", type=parse_seeds, default="1-8", help="seeds, e.g. 1-8")
    ap.add_argument("--set", action="append", default=[], help="config override key=value")
    args = ap.parse_args(argv)
    seeds = args.seeds
    rows, failed = [], []
    header = (
        "| seed | world | "
        + " | ".join(h for _, h, _, _ in COLUMNS)
        + " | lines matched | corners matched | lines in map |"
    )
    print(header)
    print("|" + "---|" * (header.count("|") - 1))
    for s in seeds:
        cfg = load_config(args.config, [*args.set, f"seed={s}", f"indoor.seed={s}", "output.progress=false"])
        t0 = time.perf_counter()
        try:
            m = execute(cfg, progress=False).metrics
            ok = bool(m.get("finite"))
        except Exception as e:  # a failed seed is reported, never dropped
            m, ok = {"data": f"failed: {type(e).__name__}: {e}"}, False
        rows.append(m)
        failed.append(not ok)
        cells = [f"{m[k] * sc:.{d}f}" if ok and k in m else "fail" for k, _, sc, d in COLUMNS]
        world = m.get("data", "").replace("simulated indoor ", "")
        print(
            f"| {s} | {world} | " + " | ".join(cells) + f" | {m.get('n_lines_matched', '-')}/{m.get('n_lines', '-')} | "
            f"{m.get('n_corners_matched', '-')}/{m.get('n_corners', '-')} | {m.get('n_lines_est', '-')} |"
            f"  <!-- {time.perf_counter() - t0:.0f} s -->",
            flush=True,
        )
    for stat in ("median", "worst"):
        cells = []
        for k, _, sc, d in COLUMNS:
            v = seed_summary([r.get(k, float("nan")) for r in rows], failed, "min", seeds)[stat]
            cells.append(f"{v * sc:.{d}f}")
        print(f"| {stat} | | " + " | ".join(cells) + " | | | |")
    print(
        f"| total | | {' | ' * (len(COLUMNS) - 1)} | {sum(r.get('n_lines_matched', 0) for r in rows)}/"
        f"{sum(r.get('n_lines', 0) for r in rows)} | {sum(r.get('n_corners_matched', 0) for r in rows)}/"
        f"{sum(r.get('n_corners', 0) for r in rows)} | {sum(r.get('n_lines_est', 0) for r in rows)} |"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
