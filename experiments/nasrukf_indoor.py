"""NASRUKF with per-beam line and arc features on simulated indoor logs: pose, heading and Table 1
errors over seeds, adaptive against non-adaptive with a wrong configured process noise, and the run
time of a long log (docs/method/nasrukf-beams.md).

    .venv/bin/python experiments/nasrukf_indoor.py [--seeds 100-115] [--duration 60] [--wrong 3]
        [--set key=value ...]
    .venv/bin/python experiments/nasrukf_indoor.py --timing 300     # one 300 s log (12,000 scans)

For every seed ``s`` the config (``configs/nasrukf_indoor.yaml``) runs with ``seed = indoor.seed = s``
twice, with the odometry noise configured ``--wrong`` times smaller than the simulator's (the process
noise wrong by that factor): adaptive (noise.adaptive and nasrukf.adaptive_process on, the config) and
non-adaptive (both off). Prints a Markdown row per seed and run, the median / worst over the seeds
(:func:`nanoslam_jax.metrics.seed_summary`: a failed run counts as the worst) and the fraction of
seeds where the adaptive run's position RMSE is below the non-adaptive one's.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from nanoslam_jax.config import load_config
from nanoslam_jax.experiment import execute
from nanoslam_jax.metrics import seed_summary

CONFIG = "configs/nasrukf_indoor.yaml"
#: The columns: metric, header, scale, digits.
COLUMNS = (
    ("rmse_fixed", "pos. RMSE (cm)", 100.0, 2),
    ("rmse_heading_deg", "heading RMSE (deg)", 1.0, 3),
    ("line_intercept_median", "intercept med. (cm)", 100.0, 2),
    ("line_slope_median", "slope med.", 1.0, 4),
    ("corner_median", "corner med. (cm)", 100.0, 2),
    ("arc_centre_median", "arc centre (cm)", 100.0, 2),
    ("arc_radius_median", "arc radius (cm)", 100.0, 2),
)
VARIANTS = {
    "adaptive": [],
    "non-adaptive": ["noise.adaptive=false", "nasrukf.adaptive_process=false"],
}


def _seeds(text: str) -> list[int]:
    lo, _, hi = text.partition("-")
    return list(range(int(lo), int(hi or lo) + 1))


def _arc_metrics(result) -> dict:
    """Table 1's arc errors of a run: its arc features against the log's true pillars."""
    from nanoslam_jax.metrics import arc_feature_errors

    truth = result.log.feature_truth
    if truth is None or result.state is None or not hasattr(result.state, "arc_table"):
        return {}
    arcs, active = (np.asarray(a) for a in result.state.arc_table())
    e = arc_feature_errors(arcs[active], truth.arcs)
    med = lambda v: float(np.nanmedian(np.abs(v))) if np.isfinite(v).any() else math.nan  # noqa: E731
    return {"arc_centre_median": med(e["centre_error"]), "arc_radius_median": med(e["radius_error"])}


def run_one(sets: list[str]) -> dict:
    cfg = load_config(CONFIG, [*sets, "output.progress=false"])
    t0 = time.perf_counter()
    try:
        res = execute(cfg, progress=False)
        m = dict(res.metrics)
        m.update(_arc_metrics(res))
        m["ok"] = bool(m.get("finite"))
    except Exception as e:  # a failed seed is reported, never dropped
        m = {"ok": False, "error": f"{type(e).__name__}: {e}"}
    m["wall_s"] = time.perf_counter() - t0
    return m


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="100-115")
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--wrong", type=float, default=3.0, help="configured odometry noise = simulator's / this")
    ap.add_argument("--timing", type=float, default=None, help="time one log of this many seconds instead")
    ap.add_argument("--set", action="append", default=[], help="config override key=value")
    args = ap.parse_args(argv)
    if args.timing:
        m = run_one([*args.set, f"indoor.duration={args.timing}", "indoor.seed=100"])
        print(
            f"{args.timing:.0f} s log: compile {m.get('compile_s', math.nan):.1f} s, run {m.get('run_s', math.nan):.2f} s"
        )
        return 0
    wrong = [f"unicycle.sigma_v={0.01 / args.wrong}", f"unicycle.sigma_omega_deg={1.0 / args.wrong}"]
    seeds = _seeds(args.seeds)
    rows: dict[str, list[dict]] = {v: [] for v in VARIANTS}
    print("| seed | run | " + " | ".join(h for _, h, _, _ in COLUMNS) + " | lines matched | lines in map | run s |")
    print("|" + "---|" * (len(COLUMNS) + 5))
    for s in seeds:
        for name, extra in VARIANTS.items():
            sets = [*args.set, *wrong, *extra, f"seed={s}", f"indoor.seed={s}", f"indoor.duration={args.duration}"]
            m = run_one(sets)
            rows[name].append(m)
            cells = [f"{m[k] * sc:.{d}f}" if m["ok"] and k in m else "fail" for k, _, sc, d in COLUMNS]
            print(
                f"| {s} | {name} | " + " | ".join(cells) + f" | {m.get('n_lines_matched', '-')}/{m.get('n_lines', '-')}"
                f" | {m.get('n_lines_est', '-')} | {m.get('run_s', math.nan):.1f} |",
                flush=True,
            )
    for name in VARIANTS:
        failed = [not m["ok"] for m in rows[name]]
        for stat in ("median", "worst"):
            cells = []
            for k, _, sc, d in COLUMNS:
                v = seed_summary([m.get(k, math.nan) for m in rows[name]], failed, "min", seeds)[stat]
                cells.append(f"{v * sc:.{d}f}")
            print(f"| {stat} | {name} | " + " | ".join(cells) + " | | | |")
    a = np.array([m.get("rmse_fixed", math.inf) if m["ok"] else math.inf for m in rows["adaptive"]])
    b = np.array([m.get("rmse_fixed", math.inf) if m["ok"] else math.inf for m in rows["non-adaptive"]])
    ah = np.array([m.get("rmse_heading_deg", math.inf) if m["ok"] else math.inf for m in rows["adaptive"]])
    bh = np.array([m.get("rmse_heading_deg", math.inf) if m["ok"] else math.inf for m in rows["non-adaptive"]])
    print(
        f"\nadaptive better (position RMSE): {np.mean(a < b) * 100:.0f} % of {len(seeds)} seeds; "
        f"(heading RMSE): {np.mean(ah < bh) * 100:.0f} %"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
