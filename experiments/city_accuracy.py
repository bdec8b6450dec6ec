"""SLAM against dead reckoning on the simulated city over filter seeds, with the association found
(``filter.association: nearest``) and given (``known``, the simulator's landmark ids).

Runs NANO-SLAM (``filter.n_particles`` 100, ``filter.capacity`` 16384 by default) on the city of
``nanoslam simulate --scenario city`` (``city.distance_m`` from ``--distance``; the city and its log
stay those of ``city.seed``) once per filter seed (``seed``) and association, and prints a
Markdown table: each association's RMSE over the seeds (median, IQR, worst), dead reckoning's RMSE
over it, how many seeds are at least 10x better than dead reckoning, and the paired difference
nearest - known on the same seeds. The known association is a bound for every change to the
association and the map's management: it is what a perfect one would give with the same filter::

    python experiments/city_accuracy.py                         # 16 seeds, 20 km (about 70 min on 2 cores)
    python experiments/city_accuracy.py --seeds 1-4 --distance 8000 --out runs.jsonl

Each run's figures are appended to ``--out`` (JSON lines) as it ends; a second call with the same
file runs only the seeds and associations it does not hold yet.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np

from _seeds import format_seeds, parse_seeds
from nanoslam_jax.app.config import load_config
from nanoslam_jax.app.experiment import run_experiment

ASSOCIATIONS = ("nearest", "known")
KEPT = ("rmse_fixed", "rmse_aligned", "dr_rmse_fixed", "rmse_heading_deg", "n_landmarks", "landmark_overflow")


def _runs(path: Path) -> dict[tuple[int, str], dict]:
    if not path.exists():
        return {}
    rows = (json.loads(line) for line in path.read_text().splitlines() if line.strip())
    return {(r["seed"], r["association"]): r for r in rows}


def _run(seed: int, association: str, common: list[str]) -> dict:
    cfg = load_config(None, [*common, f"seed={seed}", f"filter.association={association}"])
    with tempfile.TemporaryDirectory() as out:
        m = run_experiment(cfg, out, progress=False)
    return dict(seed=seed, association=association, **{k: m[k] for k in KEPT})


def _summary(runs: dict[tuple[int, str], dict], seeds: list[int]) -> None:
    paired = [s for s in seeds if all((s, a) in runs for a in ASSOCIATIONS)]
    print(f"\n{len(paired)} seeds ({format_seeds(paired)}), RMSE [m] of the best particle's path\n")
    print("| association | median | IQR | worst | dead reckoning | seeds at 10x dead reckoning |")
    print("|---|---|---|---|---|---|")
    for a in ASSOCIATIONS:
        e = np.array([runs[s, a]["rmse_fixed"] for s in paired])
        dr = np.array([runs[s, a]["dr_rmse_fixed"] for s in paired])
        q1, q2, q3 = np.percentile(e, [25, 50, 75])
        print(
            f"| {a} | {q2:.1f} | {q1:.1f}-{q3:.1f} | {e.max():.1f} | {np.median(dr):.1f} | "
            f"{int(np.sum(10 * e <= dr))} of {len(paired)} |"
        )
    d = np.array([runs[s, "nearest"]["rmse_fixed"] - runs[s, "known"]["rmse_fixed"] for s in paired])
    q1, q2, q3 = np.percentile(d, [25, 50, 75])
    print(f"\nnearest - known, paired: median {q2:.1f} m, IQR {q1:.1f}-{q3:.1f} m, smallest {d.min():.1f} m")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=parse_seeds, default=parse_seeds("1-16"), help="filter seeds (default 1-16)")
    ap.add_argument("--distance", type=float, default=20000.0, help="city.distance_m (m)")
    ap.add_argument("--particles", type=int, default=100, help="filter.n_particles")
    ap.add_argument("--capacity", type=int, default=16384, help="filter.capacity (landmark slots per particle)")
    ap.add_argument("--out", type=Path, default=Path("city_accuracy.jsonl"), help="the runs' figures (JSON lines)")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args()
    common = [
        "data.kind=city",
        f"city.distance_m={args.distance}",
        "filter.method=nano",
        f"filter.n_particles={args.particles}",
        f"filter.capacity={args.capacity}",
        "output.plots=false",
        "output.progress=false",
        *args.overrides,
    ]
    runs = _runs(args.out)
    for seed in args.seeds:
        for a in ASSOCIATIONS:
            if (seed, a) in runs:
                continue
            runs[seed, a] = _run(seed, a, common)
            with args.out.open("a") as f:
                f.write(json.dumps(runs[seed, a]) + "\n")
            print(f"seed {seed} {a}: RMSE {runs[seed, a]['rmse_fixed']:.1f} m", flush=True)
    _summary(runs, args.seeds)


if __name__ == "__main__":
    main()
