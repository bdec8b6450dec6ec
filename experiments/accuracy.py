"""Accuracy over seeds of one config: a one-row `nanoslam compare` that prints every seed.

    python experiments/accuracy.py configs/victoria_park_nano.yaml --seeds 8
    python experiments/accuracy.py configs/victoria_park_nano.yaml --seeds 8 --set filter.estimate=mean
    python experiments/accuracy.py configs/victoria_park_best.yaml --seeds 32 --first-seed 100 --without-fix 1223.3

The seeds run and are scored by the engine of `nanoslam compare` (``nanoslam_jax.app.compare.run_method``:
S seeds vmapped in one compiled program, each smoothed when ``smoother.enabled``, each scored by
``nanoslam_jax.eval._scoring.score_run``), so its figures are those of a comparison file with this config
as its one row (configs/recommended.yaml holds the recommended configuration's rows). What this
preset adds: the per-seed table, and with ``--without-fix T`` (repeatable) the two RMSEs with the
GPS fix nearest each time T left out (``rmse_*_without``): how much of a figure single fixes make
(the 136 m outlier at t = 1223.3 s, :mod:`nanoslam_jax.eval.gps_floor`).

Reports, per seed and summarised (median, interquartile range, min, max): ``rmse_fixed``,
``rmse_aligned`` and their ``*_clean`` variants (docs/method/victoria-park.md), the landmarks (all,
and confirmed) in the reported map; with ``filter.estimate: path`` the filter's own estimate of the
same runs (``rmse_*_best``); with the smoother the path it started from (``rmse_*_path``) and its
iterations, joined landmarks and time. A failed seed (a non-finite estimate) is counted, named and
counts as an infinite error (the scorer's failed-seed rule).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from nanoslam_jax import enable_compile_cache
from nanoslam_jax.eval._scoring import format_number, summarize_runs
from nanoslam_jax.app.compare import CompareSpec, MethodSpec, method_config, run_method
from nanoslam_jax.app.config import ConfigError
from nanoslam_jax.app.experiment import load_log
from nanoslam_jax.methods import text_progress
from nanoslam_jax.eval.metrics import evaluate
import jax

jax.config.update("jax_enable_x64", True)  # the library computes in float64

KEYS = ("rmse_fixed", "rmse_aligned", "rmse_fixed_clean", "rmse_aligned_clean", "final_error")
#: Columns reported when the runs have them (the filter's own estimate, the smoother's).
OPTIONAL = (
    "rmse_fixed_best",
    "rmse_aligned_best",
    "rmse_fixed_path",
    "rmse_aligned_path",
    "smoother_iterations",
    "smoother_merged",
    "smoother_s",
)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("config")
    p.add_argument("--seeds", type=int, default=8)
    p.add_argument("--first-seed", type=int, default=0)
    p.add_argument("--data")
    p.add_argument("--set", dest="overrides", action="append", default=[])
    p.add_argument("--json", help="write per-seed rows and the summary here")
    p.add_argument(
        "--without-fix",
        type=float,
        action="append",
        default=[],
        metavar="T",
        help="also score without the GPS fix nearest time T s (repeatable)",
    )
    p.add_argument("--no-cache", action="store_true", help="do not use the persistent compilation cache")
    args = p.parse_args()
    if not args.no_cache:
        enable_compile_cache()  # as every nanoslam command: a repeated call loads the batch program

    name = Path(args.config).stem
    spec = CompareSpec(
        name=name,
        base=args.config,
        methods=(MethodSpec(name, ()),),
        seeds=args.seeds,
        first_seed=args.first_seed,
        set=tuple(args.overrides),
        source=args.config,
    )
    try:
        cfg = method_config(spec, spec.methods[0])
    except ConfigError as e:
        p.error(str(e))
    log = load_log(cfg, args.data)
    res = run_method(
        spec,
        spec.methods[0],
        log,
        progress=text_progress(f"{name} x{args.seeds} seeds"),
        timed=False,
        keep_trajectories=True,
    )
    rows = res.rows
    keys = KEYS + tuple(k for k in OPTIONAL if any(k in r for r in rows))

    gps = np.asarray(log.raw.gps)
    keep = np.ones(len(gps), bool)
    for tf in args.without_fix:
        j = int(np.argmin(np.abs(gps[:, 0] - tf)))
        print(f"left out in rmse_*_without: the GPS fix at t = {gps[j, 0]:.3f} s ({gps[j, 1]:.2f}, {gps[j, 2]:.2f})")
        keep[j] = False
    if args.without_fix:
        keys += ("rmse_fixed_without", "rmse_aligned_without")
        t = np.asarray(log.segments.time)
        mk = dict(rotation_deg=cfg.metrics.gps_rotation_deg, jump_speed=cfg.metrics.jump_speed, frame=log.frame)
        for r, traj in zip(rows, res.trajectories or []):
            if r.get("finite"):
                w = evaluate(t, np.asarray(traj)[:, :2], gps[keep], **mk)
                r.update(rmse_fixed_without=w["rmse_fixed"], rmse_aligned_without=w["rmse_aligned"])
    for r in rows:
        if r.get("smoother_converged") is False:
            print(f"warning: seed {r['seed']}: the smoother stopped after {r['smoother_iterations']} iterations")

    print(
        f"\n{cfg.name}: {cfg.filter.method}, {cfg.filter.n_particles} particles, {len(rows)} seeds, "
        f"{log.segments.time.shape[0]} scans, batch run {res.batch_run_s:.1f} s\n"
    )
    print("| seed | " + " | ".join(keys) + " | landmarks | confirmed |")
    print("|---" * (len(keys) + 3) + "|")
    for r in rows:
        cells = " | ".join(format_number(float(r.get(k, float("nan")))) for k in keys)
        print(f"| {r['seed']} | {cells} | {r.get('n_landmarks', '')} | {r.get('n_confirmed', '')} |")
    columns = keys + ("n_landmarks", "n_confirmed")
    st = summarize_runs(rows, columns)
    summary = {k: {x: st[f"{k}_{x}"] for x in ("median", "q1", "q3", "min", "max")} for k in columns}
    print("\n| metric | median | IQR | min | max |\n|---|---|---|---|---|")
    for k, q in summary.items():
        print(
            f"| {k} | {format_number(q['median'])} | {format_number(q['q1'])} - {format_number(q['q3'])} | "
            f"{format_number(q['min'])} | {format_number(q['max'])} |"
        )
    if st["n_failed"]:
        print(
            f"\n{st['n_failed']} of {len(rows)} seeds failed (counted as an infinite error): seeds "
            f"{st['failed_seeds'].replace(';', ', ')}: {st['reasons']}"
        )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(
                {
                    "config": args.config,
                    "overrides": args.overrides,
                    "rows": rows,
                    "summary": summary,
                    "n_failed": st["n_failed"],
                    "failed_seeds": st["failed_seeds"],
                },
                f,
                indent=2,
                default=float,
            )


if __name__ == "__main__":
    main()
