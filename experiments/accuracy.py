"""Accuracy over seeds: one config, S seeds vmapped in one compiled program; prints a Markdown table.

    python experiments/accuracy.py configs/victoria_park_nano.yaml --seeds 8
    python experiments/accuracy.py configs/victoria_park_nano.yaml --seeds 8 --set filter.estimate=mean
    python experiments/accuracy.py configs/victoria_park_best.yaml --seeds 16 --set filter.estimate=path
    python experiments/accuracy.py configs/victoria_park_best.yaml --seeds 32 --first-seed 100 --without-fix 1223.3

Reports, per seed and summarised (median, interquartile range, min, max): ``rmse_fixed``,
``rmse_aligned`` and their ``*_clean`` variants (docs/method/victoria-park.md, "Scoring against GPS"), and the landmarks
(all, and confirmed) in the best particle's map. With ``filter.estimate: path`` also the filter's
own estimate of the same runs (``rmse_*_best``), a paired comparison of the two. With
``--without-fix T`` (repeatable) also the two RMSEs with the GPS fix nearest each time T left out
(``rmse_*_without``): how much of a figure single fixes make (the 136 m outlier at t = 1223.3 s,
:mod:`nanoslam_jax.gps_floor`). The protocol's figures are always those with every fix. With
``smoother.enabled`` (configs/victoria_park_best.yaml) each seed's path and map are smoothed
(:mod:`nanoslam_jax.smoother`) and scored, with the path it started from (``rmse_*_path``) and
the filter's own estimate (``rmse_*_best``) beside them; a seed whose smoother did not converge
is named. Each seed is scored as every command scores a run (``nanoslam_jax._scoring.score_run``)
and the seeds are summarised under its failed-seed rule (a seed whose estimate became non-finite
is counted, named, and counts as an infinite error).
"""

from __future__ import annotations

import argparse
import json

import jax
import numpy as np

from nanoslam_jax import enable_compile_cache
from nanoslam_jax._scoring import (
    MapEstimate,
    companion_tracks,
    failure_reason,
    format_number,
    score_run,
    summarize_runs,
)
from nanoslam_jax.config import load_config
from nanoslam_jax.experiment import load_log
from nanoslam_jax.filter import (
    reported_map,
    reported_trajectory,
    run_batch,
    settings_from_config,
    stack_params,
    text_progress,
)
from nanoslam_jax.metrics import evaluate
from nanoslam_jax.smoother import smooth_filter_run

KEYS = ("rmse_fixed", "rmse_aligned", "rmse_fixed_clean", "rmse_aligned_clean", "final_error")


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

    cfg = load_config(args.config, args.overrides)
    log = load_log(cfg, args.data)
    static, params = settings_from_config(cfg, log.segments.k_max)
    seeds = np.arange(args.first_seed, args.first_seed + args.seeds)
    try:  # run_batch refuses a method it cannot run (dead reckoning: `nanoslam run` scores it) before tracing
        run = run_batch(
            static,
            stack_params([params] * len(seeds)),
            log.segments,
            seeds,
            chunk=cfg.output.chunk,
            progress=text_progress(f"{cfg.name} x{len(seeds)} seeds"),
        )
    except ValueError as e:
        p.error(str(e))
    t = np.asarray(log.segments.time)
    keys = KEYS + (("rmse_fixed_best", "rmse_aligned_best") if static.estimate == "path" else ())
    gps = np.asarray(log.raw.gps)
    keep = np.ones(len(gps), bool)
    for tf in args.without_fix:
        j = int(np.argmin(np.abs(gps[:, 0] - tf)))
        print(f"left out in rmse_*_without: the GPS fix at t = {gps[j, 0]:.3f} s ({gps[j, 1]:.2f}, {gps[j, 2]:.2f})")
        keep[j] = False
    if args.without_fix:
        keys += ("rmse_fixed_without", "rmse_aligned_without")
    est = reported_trajectory(static.estimate, run.outputs, run.state)
    if cfg.smoother.enabled:  # the final best particle's path and map refined offline, per seed
        keys += ("rmse_fixed_path", "rmse_aligned_path", "smoother_iterations", "smoother_merged", "smoother_s")
    mk = dict(rotation_deg=cfg.metrics.gps_rotation_deg, jump_speed=cfg.metrics.jump_speed, frame=log.frame)
    maps = jax.tree.map(np.asarray, jax.vmap(reported_map)(run.state))
    rows = []
    for i, s in enumerate(seeds):
        traj, before, extra = np.asarray(est[i]), None, {}
        if cfg.smoother.enabled and np.all(np.isfinite(traj)):
            sm = smooth_filter_run(run, traj, log.segments, params, cfg.smoother, cfg.filter.prior, i)
            before, traj = traj, sm.poses
            extra = dict(smoother_iterations=sm.iterations, smoother_merged=sm.merged, smoother_s=sm.seconds)
            if not sm.converged:
                print(f"warning: seed {s}: the smoother stopped after {sm.iterations} iterations without converging")
        act = maps.active[i]
        m = score_run(
            log,
            traj,
            cfg.metrics,
            MapEstimate(maps.mean[i][act], maps.confirmed[i][act]),
            companion_tracks(
                static.estimate, np.asarray(run.outputs.best_pose[i]), np.asarray(run.outputs.mean_pose[i]), before
            ),
        )
        m.update(extra)
        if args.without_fix and m["finite"]:
            w = evaluate(t, traj[:, :2], gps[keep], **mk)
            m.update(rmse_fixed_without=w["rmse_fixed"], rmse_aligned_without=w["rmse_aligned"])
        reason = failure_reason(t, traj)
        rows.append(
            {
                "seed": int(s),
                "status": "failed" if reason else "ok",
                "reason": reason,
                **{k: m.get(k, float("nan")) for k in keys + ("n_landmarks", "n_confirmed")},
                "finite": m["finite"],
            }
        )

    print(
        f"\n{cfg.name}: {cfg.filter.method}, {static.n_particles} particles, {len(seeds)} seeds, "
        f"{t.shape[0]} scans, batch run {run.run_s:.1f} s (compile {run.compile_s:.1f} s)\n"
    )
    print("| seed | " + " | ".join(keys) + " | landmarks | confirmed |")
    print("|---" * (len(keys) + 3) + "|")
    for r in rows:
        print(
            f"| {r['seed']} | "
            + " | ".join(format_number(float(r[k])) for k in keys)
            + f" | {r['n_landmarks']} | {r['n_confirmed']} |"
        )
    st = summarize_runs(rows, keys + ("n_landmarks", "n_confirmed"))
    summary = {
        k: {x: st[f"{k}_{x}"] for x in ("median", "q1", "q3", "min", "max")}
        for k in keys + ("n_landmarks", "n_confirmed")
    }
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
            )


if __name__ == "__main__":
    main()
