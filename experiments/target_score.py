"""Rank a sweep's configurations by how far they are from issue 19's accuracy targets.

    python experiments/target_score.py results/best_victoria_park_tail/summary.csv

The targets of configs/victoria_park_best.yaml: median rmse_aligned at most 2.6 m, median
rmse_fixed at most 3.5 m, and the worst seed within 1.5x the median. A configuration's score is
the largest of the four ratios

    median aligned / 2.6,  median fixed / 3.5,
    worst aligned / (1.5 x median aligned),  worst fixed / (1.5 x median fixed),

so a score of at most 1 meets every target and the lowest score is the nearest. The statistics
are those of the sweep's ``summary.csv`` (median and maximum over the seeds, a failed seed counted
as an infinite error); a configuration with a failed seed is ranked last. Prints a Markdown table,
best first.
"""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path


def score(row: dict, aligned: float, fixed: float, worst: float) -> dict:
    """The four ratios and their maximum for one ``summary.csv`` row (NaN when a statistic is missing)."""

    def num(key: str) -> float:
        try:
            return float(row[key])
        except (KeyError, TypeError, ValueError):
            return math.nan

    ma, mf = num("rmse_aligned_median"), num("rmse_fixed_median")
    wa, wf = num("rmse_aligned_max"), num("rmse_fixed_max")
    r = {
        "median_aligned": ma / aligned,
        "median_fixed": mf / fixed,
        "worst_aligned": wa / (worst * ma),
        "worst_fixed": wf / (worst * mf),
    }
    failed = int(row.get("n_failed") or 0) > 0
    r["score"] = math.inf if failed or any(math.isnan(v) for v in r.values()) else max(r.values())
    return r


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("summary", help="a sweep's summary.csv")
    p.add_argument("--aligned", type=float, default=2.6, help="target median rmse_aligned [m] (2.6)")
    p.add_argument("--fixed", type=float, default=3.5, help="target median rmse_fixed [m] (3.5)")
    p.add_argument("--worst", type=float, default=1.5, help="target worst seed / median (1.5)")
    args = p.parse_args()
    path = Path(args.summary)
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    need = {"rmse_aligned_median", "rmse_fixed_median", "rmse_aligned_max", "rmse_fixed_max"}
    if not rows or not need <= set(rows[0]):
        raise SystemExit(
            f"{path}: expected a sweep's summary.csv with the columns {sorted(need)} "
            f"(written by nanoslam sweep since the summary has min/max)"
        )
    fixed_cols = {"config_id", "group", "n_runs", "n_ok", "n_failed", "reasons"}
    swept = [
        k for k in rows[0] if k not in fixed_cols and k.rsplit("_", 1)[-1] not in ("median", "q1", "q3", "min", "max")
    ]
    scored = sorted(
        ((score(r, args.aligned, args.fixed, args.worst), r) for r in rows),
        key=lambda t: (t[0]["score"], t[1]["config_id"]),
    )
    head = ["config", *swept, "aligned median / worst [m]", "fixed median / worst [m]", "score", "limited by"]
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for s, r in scored:
        lim = (
            max((k for k in s if k != "score"), key=lambda k: s[k])
            if math.isfinite(s["score"])
            else f"{r['n_failed']} failed seed(s)"
            if int(r.get("n_failed") or 0)
            else "no statistics"
        )
        cells = [
            r["config_id"],
            *(r[k] for k in swept),
            f"{float(r['rmse_aligned_median']):.2f} / {float(r['rmse_aligned_max']):.2f}",
            f"{float(r['rmse_fixed_median']):.2f} / {float(r['rmse_fixed_max']):.2f}",
            f"{s['score']:.3f}",
            lim,
        ]
        print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
