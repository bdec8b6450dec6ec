"""Tune the offline smoother (:mod:`nanoslam_jax.smoother`): one batch of filter runs, every
combination of the smoother settings given, one Markdown table ranked by the targets' score.

    python experiments/smoother_tuning.py configs/victoria_park_best.yaml --seeds 16 \\
        --grid odometry_scale=0.03,0.1,0.3 floor_xy=0.05,0.1,0.2 floor_phi_deg=0.1,0.3,1.0

The filter runs once per seed (``filter.estimate: path`` is set); each setting smooths every
seed's final best particle's path and map. A setting's score is that of
``experiments/target_score.py``: the largest of median rmse_aligned / 2.6 m, median rmse_fixed /
3.5 m and each metric's worst seed / (1.5 x its median); a seed whose smoother did not converge
counts as a failed run (score inf). The smoother's settings are host-side, so they are not a
``nanoslam sweep`` grid; this script is their sweep.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json

import numpy as np

from nanoslam_jax import enable_compile_cache
from nanoslam_jax.config import load_config
from nanoslam_jax.experiment import load_log
from nanoslam_jax.filter import reported_trajectory, run_batch, settings_from_config, stack_params, text_progress
from nanoslam_jax.metrics import evaluate
from nanoslam_jax.smoother import SmootherSettings, smooth_run, smoother_map
from target_score import score as target_score  # experiments/ is on the path when this script runs


def _score(fixed: np.ndarray, aligned: np.ndarray, ok: np.ndarray, a: float, f: float, w: float) -> float:
    """target_score.py's score of one setting's seeds (a seed not ``ok`` counts as a failed run)."""
    row = {"rmse_aligned_median": np.median(aligned), "rmse_fixed_median": np.median(fixed),
           "rmse_aligned_max": np.max(aligned), "rmse_fixed_max": np.max(fixed),
           "n_failed": int(np.sum(~ok | ~np.isfinite(fixed) | ~np.isfinite(aligned)))}
    return float(target_score(row, a, f, w)["score"])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("config")
    p.add_argument("--seeds", type=int, default=16)
    p.add_argument("--first-seed", type=int, default=0)
    p.add_argument("--data")
    p.add_argument("--set", dest="overrides", action="append", default=[])
    p.add_argument("--grid", nargs="+", default=[], metavar="KEY=V1,V2",
                   help="smoother keys (without 'smoother.') and their values; every combination runs")
    p.add_argument("--aligned", type=float, default=2.6)
    p.add_argument("--fixed", type=float, default=3.5)
    p.add_argument("--worst", type=float, default=1.5)
    p.add_argument("--json", help="write every setting's per-seed figures here")
    args = p.parse_args()
    enable_compile_cache()

    cfg = load_config(args.config, args.overrides + ["filter.estimate=path", "smoother.enabled=true"])
    names = [f.name for f in dataclasses.fields(cfg.smoother)]
    grid: dict[str, list[float]] = {}
    for item in args.grid:
        key, _, values = item.partition("=")
        if key not in names or not values:
            p.error(f"--grid {item!r}: expected KEY=V1,V2,... with KEY one of {', '.join(names)}")
        grid[key] = [float(v) for v in values.split(",")]
    log = load_log(cfg, args.data)
    static, params = settings_from_config(cfg, log.segments.k_max)
    seeds = np.arange(args.first_seed, args.first_seed + args.seeds)
    run = run_batch(static, stack_params([params] * len(seeds)), log.segments, seeds, chunk=cfg.output.chunk,
                    progress=text_progress(f"{cfg.name} x{len(seeds)} seeds"))
    paths = reported_trajectory("path", run.outputs, run.state)
    t = np.asarray(log.segments.time)
    mk = dict(rotation_deg=cfg.metrics.gps_rotation_deg, jump_speed=cfg.metrics.jump_speed, frame=log.frame)
    base = [evaluate(t, paths[i][:, :2], log.raw.gps, **mk) for i in range(len(seeds))]

    results = []
    combos = list(itertools.product(*grid.values())) or [()]
    for values in combos:
        sc = dataclasses.replace(cfg.smoother, **{k: (int(v) if k == "max_iter" else v) for k, v in zip(grid, values)})
        settings = SmootherSettings.from_config(sc)
        rows = []
        for i, s in enumerate(seeds):
            final, held = smoother_map(run, settings, i)
            sm = smooth_run(paths[i], final, log.segments, params, settings, cfg.filter.prior, held)
            m = evaluate(t, sm.poses[:, :2], log.raw.gps, **mk)
            rows.append(dict(seed=int(s), rmse_fixed=m["rmse_fixed"], rmse_aligned=m["rmse_aligned"],
                             rmse_fixed_path=base[i]["rmse_fixed"], rmse_aligned_path=base[i]["rmse_aligned"],
                             iterations=sm.iterations, converged=sm.converged, seconds=sm.seconds))
        fx, al = (np.array([r[k] for r in rows]) for k in ("rmse_fixed", "rmse_aligned"))
        conv = np.array([r["converged"] for r in rows])
        setting = dict(zip(grid, values))
        score = _score(fx, al, conv, args.aligned, args.fixed, args.worst)
        results.append(dict(setting=setting, score=score, rows=rows))
        print(f"{setting}: fixed {np.median(fx):.2f} (worst {fx.max():.2f}), aligned {np.median(al):.2f} "
              f"(worst {al.max():.2f}), score {score:.3f}, {conv.sum()}/{len(conv)} converged, "
              f"{np.median([r['seconds'] for r in rows]):.1f} s per seed", flush=True)

    fx0, al0 = (np.array([b[k] for b in base]) for k in ("rmse_fixed", "rmse_aligned"))
    print(f"\n{cfg.name}, seeds {seeds[0]}-{seeds[-1]}: the unsmoothed path: fixed {np.median(fx0):.2f} "
          f"(worst {fx0.max():.2f}), aligned {np.median(al0):.2f} (worst {al0.max():.2f}), score "
          f"{_score(fx0, al0, np.ones(len(seeds), bool), args.aligned, args.fixed, args.worst):.3f}\n")
    print("| " + " | ".join(grid) + " | rmse_fixed median [IQR], worst | rmse_aligned median [IQR], worst | "
          "iterations (max) | score |")
    print("|---" * (len(grid) + 4) + "|")
    for r in sorted(results, key=lambda r: r["score"]):
        fx, al = (np.array([x[k] for x in r["rows"]]) for k in ("rmse_fixed", "rmse_aligned"))
        q = lambda v: f"{np.median(v):.2f} [{np.percentile(v, 25):.2f}, {np.percentile(v, 75):.2f}], {v.max():.2f}"  # noqa: E731
        print("| " + " | ".join(f"{v:g}" for v in r["setting"].values()) + f" | {q(fx)} | {q(al)} | "
              f"{max(x['iterations'] for x in r['rows'])} | {r['score']:.3f} |")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"config": args.config, "overrides": args.overrides, "seeds": seeds.tolist(), "results": results}, f, indent=2)


if __name__ == "__main__":
    main()
