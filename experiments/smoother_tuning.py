"""Tune the offline smoother (:mod:`nanoslam_jax.smoother._smoother`): one batch of filter runs, every
combination of the smoother settings given, one Markdown table ranked by the targets' score.

    python experiments/smoother_tuning.py configs/victoria_park_best.yaml --seeds 16 \\
        --grid odometry_scale=0.03,0.1,0.3 floor_xy=0.05,0.1,0.2 floor_phi_deg=0.1,0.3,1.0

The filter runs once per seed (``filter.estimate: path`` is set); each setting smooths every
seed's final best particle's path and map and scores it, by the engine of ``nanoslam compare``
(``nanoslam_jax.app.compare.run_method``, whose run cache keeps the filter runs for every setting). A setting's score is that of
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
from nanoslam_jax.app.compare import CompareSpec, MethodSpec, run_method
from nanoslam_jax.app.config import load_config
from nanoslam_jax.app.experiment import load_log
from nanoslam_jax.eval._scoring import seed_summary
from nanoslam_jax.methods import text_progress
from target_score import score as target_score  # experiments/ is on the path when this script runs
import jax

jax.config.update("jax_enable_x64", True)  # the library computes in float64


def _summary(v: np.ndarray, ok: np.ndarray) -> dict:
    """One metric over the seeds under the failed-seed rule (a seed not ``ok`` counts as ``inf``)."""
    return seed_summary(v, ~np.asarray(ok, bool), "min")


def _score(fixed: np.ndarray, aligned: np.ndarray, ok: np.ndarray, a: float, f: float, w: float) -> float:
    """target_score.py's score of one setting's seeds (a seed not ``ok`` counts as a failed run)."""
    sf, sa = _summary(fixed, ok), _summary(aligned, ok)
    row = {
        "rmse_aligned_median": sa["median"],
        "rmse_fixed_median": sf["median"],
        "rmse_aligned_max": sa["max"],
        "rmse_fixed_max": sf["max"],
        "n_failed": max(sf["n_failed"], sa["n_failed"]),
    }
    return float(target_score(row, a, f, w)["score"])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("config")
    p.add_argument("--seeds", type=int, default=16)
    p.add_argument("--first-seed", type=int, default=0)
    p.add_argument("--data")
    p.add_argument("--set", dest="overrides", action="append", default=[])
    p.add_argument(
        "--grid",
        nargs="+",
        default=[],
        metavar="KEY=V1,V2",
        help="smoother keys (without 'smoother.') and their values; every combination runs",
    )
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
    seeds = np.arange(args.first_seed, args.first_seed + args.seeds)
    spec = CompareSpec(
        name=cfg.name,
        base=args.config,
        methods=(),
        seeds=args.seeds,
        first_seed=args.first_seed,
        set=(*args.overrides, "filter.estimate=path", "smoother.enabled=true"),
        source=args.config,
    )
    runs: dict = {}  # the filter runs, shared by every setting (they differ in the smoother only)
    nan = float("nan")
    base: list[dict] = []

    results = []
    combos = list(itertools.product(*grid.values())) or [()]
    for values in combos:
        sets = tuple(f"smoother.{k}={v:g}" for k, v in zip(grid, values))
        progress = text_progress(f"{cfg.name} x{len(seeds)} seeds") if not runs else None
        res = run_method(spec, MethodSpec("setting", sets), log, progress, timed=False, cache=runs)
        rows = [
            dict(
                seed=int(r["seed"]),
                rmse_fixed=r.get("rmse_fixed", nan),
                rmse_aligned=r.get("rmse_aligned", nan),
                rmse_fixed_path=r.get("rmse_fixed_path", nan),
                rmse_aligned_path=r.get("rmse_aligned_path", nan),
                iterations=r.get("smoother_iterations", 0),
                converged=bool(r.get("smoother_converged", False)),
                seconds=r.get("smoother_s", nan),
            )
            for r in res.rows
        ]
        base = base or [{"rmse_fixed": r["rmse_fixed_path"], "rmse_aligned": r["rmse_aligned_path"]} for r in rows]
        fx, al = (np.array([r[k] for r in rows]) for k in ("rmse_fixed", "rmse_aligned"))
        conv = np.array([r["converged"] for r in rows])
        setting = dict(zip(grid, values))
        score = _score(fx, al, conv, args.aligned, args.fixed, args.worst)
        results.append(dict(setting=setting, score=score, rows=rows))
        sf, sa = _summary(fx, conv), _summary(al, conv)
        print(
            f"{setting}: fixed {sf['median']:.2f} (worst {sf['worst']:.2f}), aligned {sa['median']:.2f} "
            f"(worst {sa['worst']:.2f}), score {score:.3f}, {conv.sum()}/{len(conv)} converged, "
            f"{np.median([r['seconds'] for r in rows]):.1f} s per seed",
            flush=True,
        )

    fx0, al0 = (np.array([b.get(k, nan) for b in base]) for k in ("rmse_fixed", "rmse_aligned"))
    all_ok = np.ones(len(seeds), bool)
    sf0, sa0 = _summary(fx0, all_ok), _summary(al0, all_ok)
    print(
        f"\n{cfg.name}, seeds {seeds[0]}-{seeds[-1]}: the unsmoothed path: fixed {sf0['median']:.2f} "
        f"(worst {sf0['worst']:.2f}), aligned {sa0['median']:.2f} (worst {sa0['worst']:.2f}), score "
        f"{_score(fx0, al0, np.ones(len(seeds), bool), args.aligned, args.fixed, args.worst):.3f}\n"
    )
    print(
        "| " + " | ".join(grid) + " | rmse_fixed median [IQR], worst | rmse_aligned median [IQR], worst | "
        "iterations (max) | score |"
    )
    print("|---" * (len(grid) + 4) + "|")
    for r in sorted(results, key=lambda r: r["score"]):
        fx, al = (np.array([x[k] for x in r["rows"]]) for k in ("rmse_fixed", "rmse_aligned"))
        ok = np.array([x["converged"] for x in r["rows"]])

        def q(v):
            st = _summary(v, ok)
            return f"{st['median']:.2f} [{st['q1']:.2f}, {st['q3']:.2f}], {st['worst']:.2f}"

        print(
            "| " + " | ".join(f"{v:g}" for v in r["setting"].values()) + f" | {q(fx)} | {q(al)} | "
            f"{max(x['iterations'] for x in r['rows'])} | {r['score']:.3f} |"
        )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(
                {"config": args.config, "overrides": args.overrides, "seeds": seeds.tolist(), "results": results},
                f,
                indent=2,
            )


if __name__ == "__main__":
    main()
