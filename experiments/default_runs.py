"""A config over several simulated logs and filter seeds: the spread behind README's figures of the
embedded default.

    python experiments/default_runs.py                         # the embedded default, 8 logs x 4 seeds
    python experiments/default_runs.py --sims 4 --seeds 4 filter.n_particles=10
    python experiments/default_runs.py --config my.yaml --json runs.json

All logs are padded to the same detection rows per scan (one compiled program). For each
simulated log (``sim.seed`` = 0, 1, ...) the filter seeds ``1000 * sim.seed + i`` run
vmapped in one program, run and scored by the engine of ``nanoslam compare``
(``nanoslam_jax.app.compare.run_method``) against the truth, next to dead reckoning on the same log, and its reported map (confirmed landmarks) against the
trees its true path could see, in the SLAM frame and after the trajectory's rigid alignment.
Prints one line per run and the medians, quartiles and worst cases. Runs are scored as every
command scores one (``nanoslam_jax.eval._scoring.score_run``) and summarised under its failed-seed rule
(a run whose estimate became non-finite is counted and counts as the worst value).
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import numpy as np

from nanoslam_jax.app.compare import CompareSpec, MethodSpec, method_config, run_method
from nanoslam_jax.app.config import load_config
from nanoslam_jax.app.experiment import load_log
from nanoslam_jax.app.filters import settings_from_config
from nanoslam_jax.eval._scoring import score_run, seed_summary
from nanoslam_jax.methods import dead_reckoning

jax.config.update("jax_enable_x64", True)  # the library computes in float64


def runs_on_log(config: str | None, overrides: list[str], sim_seed: int, n_seeds: int) -> list[dict]:
    """Every filter seed's figures on the simulated log of ``sim_seed``, run and scored by the engine
    of ``nanoslam compare``."""
    spec = CompareSpec(
        name="default_runs",
        base=config,
        methods=(MethodSpec("run", ()),),
        seeds=n_seeds,
        first_seed=1000 * sim_seed,
        set=(*overrides, f"sim.seed={sim_seed}"),
        source=config or "the embedded default",
    )
    cfg = method_config(spec, spec.methods[0])
    if cfg.data.kind != "simulated":
        raise SystemExit(
            f"{config or 'embedded default'}: data.kind is {cfg.data.kind!r}; this script needs simulated logs"
        )
    log = load_log(cfg)
    _, params = settings_from_config(cfg, log.segments.k_max)
    dr = score_run(log, np.asarray(dead_reckoning(params, jax.tree.map(np.asarray, log.segments))), cfg.metrics)
    nan = float("nan")
    rows = []
    for m in run_method(spec, spec.methods[0], log, timed=False).rows:
        rows.append(
            dict(
                sim_seed=sim_seed,
                seed=m["seed"],
                status=m["status"],
                reason=m["reason"],
                rmse_fixed=m.get("rmse_fixed", nan),
                rmse_aligned=m.get("rmse_aligned", nan),
                dr_rmse_fixed=dr.get("rmse_fixed", nan),
                dr_over_slam=dr.get("rmse_fixed", nan) / m.get("rmse_fixed", nan),
                n_confirmed=m["n_confirmed"],
                found=m["map_found_fraction"],
                spurious=m["map_spurious_fraction"],
                found_aligned=m.get("map_found_fraction_aligned", nan),
                spurious_aligned=m.get("map_spurious_fraction_aligned", nan),
                overflow=m["landmark_overflow"],
            )
        )
    return rows


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", help="a config with data.kind: simulated (default: the embedded default)")
    p.add_argument("--sims", type=int, default=8, help="simulated logs: sim.seed 0 .. sims-1")
    p.add_argument("--seeds", type=int, default=4, help="filter seeds per log")
    p.add_argument("--json", help="also write every run's row here")
    p.add_argument("overrides", nargs="*", help="key=value config overrides")
    a = p.parse_args()
    t0 = time.perf_counter()
    # One detection-row count for every log, so that one program serves them all.
    k_max = max(load_log(load_config(a.config, a.overrides + [f"sim.seed={s}"])).segments.k_max for s in range(a.sims))
    overrides = [f"data.k_max={k_max}"] + a.overrides
    rows = []
    for sim_seed in range(a.sims):
        for r in runs_on_log(a.config, overrides, sim_seed, a.seeds):
            rows.append(r)
            print(
                f"sim {r['sim_seed']} seed {r['seed']}: RMSE {r['rmse_fixed']:.2f} m (aligned {r['rmse_aligned']:.2f}), "
                f"dead reckoning {r['dr_rmse_fixed']:.1f} m ({r['dr_over_slam']:.1f}x); {r['n_confirmed']} confirmed, "
                f"found {100 * r['found_aligned']:.0f} %, spurious {100 * r['spurious_aligned']:.1f} % (aligned)",
                flush=True,
            )
    col = {k: np.array([r[k] for r in rows], float) for k in rows[0] if k not in ("status", "reason")}
    failed = [r["status"] != "ok" for r in rows]

    def spread(v):
        s = seed_summary(v, failed, "min")
        return f"median {s['median']:.2f} (IQR {s['q1']:.2f}-{s['q3']:.2f}), worst {s['worst']:.2f}"

    print(
        f"\n{len(rows)} runs, {time.perf_counter() - t0:.0f} s"
        + (f", {sum(failed)} failed (non-finite estimate; counted as the worst value)" if any(failed) else "")
    )
    print(f"RMSE fixed [m]: {spread(col['rmse_fixed'])}; aligned: {spread(col['rmse_aligned'])}")

    def st(k, goal):  # one column under the failed-seed rule (found: higher is better)
        return seed_summary(col[k], failed, goal)

    dos, fa, sa = st("dr_over_slam", "max"), st("found_aligned", "max"), st("spurious_aligned", "min")
    print(
        f"dead reckoning [m]: {col['dr_rmse_fixed'].min():.1f}-{col['dr_rmse_fixed'].max():.1f}; "
        f"dead reckoning / SLAM: median {dos['median']:.1f}, least {dos['worst']:.1f}"
    )
    print(
        f"confirmed landmarks: median {st('n_confirmed', None)['median']:.0f}; aligned map: found median "
        f"{100 * fa['median']:.0f} % (least {100 * fa['worst']:.0f} %), spurious median "
        f"{100 * sa['median']:.1f} % (most {100 * sa['worst']:.1f} %); "
        f"SLAM frame: found {100 * st('found', 'max')['median']:.0f} %, "
        f"spurious {100 * st('spurious', 'min')['median']:.1f} %"
    )
    print(
        f"RMSE < 2 m: {int(np.sum(col['rmse_fixed'] < 2))}/{len(rows)}; found >= 90 % and spurious <= 10 % (aligned): "
        f"{int(np.sum((col['found_aligned'] >= 0.9) & (col['spurious_aligned'] <= 0.1)))}/{len(rows)}; "
        f"capacity overflow in {int(np.sum(col['overflow'] > 0))}"
    )
    if a.json:
        with open(a.json, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
