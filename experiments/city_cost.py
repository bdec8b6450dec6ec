"""Cost per scan at a city-sized map: NANO-SLAM on the simulated city and on the default park log.

Runs NANO-SLAM (``filter.n_particles`` 100, ``filter.capacity`` 16384 by default) on the city of
``nanoslam simulate --scenario city`` (``data.kind: city``, ``city.distance_m`` from
``--distance``) and on the embedded default's simulated park log (``data.kind: simulated``, 240 s,
250 trees), in this process one after the other, and prints a Markdown table: milliseconds per
scan (after compilation), scans, landmarks in the map (all and confirmed), the landmark capacity's
overflow (detections that found no free slot), the RMSE against the truth and dead reckoning's
RMSE on the same log::

    python experiments/city_cost.py                        # the full 20 km city (about 5 min on 2 cores)
    python experiments/city_cost.py --distance 3000        # a 3 km drive through the same city
    python experiments/city_cost.py --particles 10 --capacity 4096 --set city.blocks=6
    python experiments/city_cost.py --repeats 3            # each log 3 times, alternating; medians

With ``--repeats`` the logs are run in turn (city, park, city, park, ...) and the table gives
each log's median milliseconds per scan with every run's in brackets, and the ratio of the
medians: on a shared machine the park's short run varies by tens of percent from run to run.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time

from nanoslam_jax.app.config import load_config
from nanoslam_jax.app.experiment import run_experiment


def _row(label: str, overrides: list[str]) -> dict:
    cfg = load_config(None, overrides)
    with tempfile.TemporaryDirectory() as out:
        t0 = time.perf_counter()
        m = run_experiment(cfg, out, progress=False)
        wall = time.perf_counter() - t0
    return dict(label=label, wall_s=wall, **m)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--distance", type=float, default=20000.0, help="city.distance_m (m)")
    ap.add_argument("--particles", type=int, default=100, help="filter.n_particles")
    ap.add_argument("--capacity", type=int, default=16384, help="filter.capacity (landmark slots per particle)")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--skip-park", action="store_true", help="only the city")
    ap.add_argument("--repeats", type=int, default=1, help="runs of each log, in turn")
    args = ap.parse_args()
    common = [
        "filter.method=nano",
        f"filter.n_particles={args.particles}",
        f"filter.capacity={args.capacity}",
        "output.plots=false",
        "output.progress=false",
        *args.overrides,
    ]
    logs = [(f"city {args.distance / 1000:g} km", ["data.kind=city", f"city.distance_m={args.distance}", *common])]
    if not args.skip_park:
        logs.append(("park (default simulated)", ["data.kind=simulated", *common]))
    runs: dict[str, list[dict]] = {label: [] for label, _ in logs}
    for _ in range(args.repeats):
        for label, overrides in logs:
            runs[label].append(_row(label, overrides))
    print(f"\nNANO-SLAM, {args.particles} particles, filter.capacity {args.capacity}\n")
    print(
        "| log | ms per scan | scans | landmarks (confirmed) | overflow | RMSE [m] | dead reckoning RMSE [m] | wall [s] |"
    )
    print("|---|---|---|---|---|---|---|---|")
    medians = {}
    for label, rows in runs.items():
        ms = [r["ms_per_scan"] for r in rows]
        medians[label] = statistics.median(ms)
        each = f" ({', '.join(f'{m:.1f}' for m in ms)})" if len(ms) > 1 else ""
        r = rows[0]
        print(
            f"| {label} | {medians[label]:.1f}{each} | {r['n_segments']} | {r['n_landmarks']} ({r['n_confirmed']}) | "
            f"{r['landmark_overflow']} | {r['rmse_fixed']:.2f} | {r.get('dr_rmse_fixed', float('nan')):.2f} | "
            f"{statistics.median(x['wall_s'] for x in rows):.0f} |"
        )
    if len(medians) == 2:
        city, park = medians.values()
        print(f"\ncity / park (medians): {city / park:.2f}x")


if __name__ == "__main__":
    main()
