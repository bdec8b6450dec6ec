"""Cost per scan against the landmark capacity, on the same log: NANO-SLAM on the embedded
default's simulated park log at several ``filter.capacity`` values, in this process one after the
other, and a Markdown table of milliseconds per scan (after compilation), the ratio to the
smallest capacity, the RMSE and the map (identical wherever the map fits every capacity)::

    python experiments/capacity_cost.py
    python experiments/capacity_cost.py --particles 10 --capacity 512 4096 --set filter.split_devices=never
    python experiments/capacity_cost.py --capacity 512 16384 --repeats 5

With ``--repeats R`` the capacities are run in turn R times (the order reversed every other
round) and the table gives each capacity's median milliseconds per scan, every run's in
brackets, and the median over the rounds of each round's ratio to the smallest capacity.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile

from nanoslam_jax.app.config import load_config
from nanoslam_jax.app.experiment import run_experiment


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--particles", type=int, default=100, help="filter.n_particles")
    ap.add_argument("--capacity", type=int, nargs="+", default=[512, 2048, 8192, 16384], help="filter.capacity values")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--repeats", type=int, default=1, help="rounds over the capacities")
    args = ap.parse_args()
    runs: dict[int, list[dict]] = {cap: [] for cap in args.capacity}
    for r in range(args.repeats):
        for cap in args.capacity if r % 2 == 0 else args.capacity[::-1]:
            cfg = load_config(
                None,
                [
                    f"filter.n_particles={args.particles}",
                    f"filter.capacity={cap}",
                    "output.plots=false",
                    "output.progress=false",
                    *args.overrides,
                ],
            )
            with tempfile.TemporaryDirectory() as out:
                runs[cap].append(run_experiment(cfg, out, progress=False))
    base = runs[args.capacity[0]]
    print(f"\nNANO-SLAM, {args.particles} particles, embedded default log\n")
    print("| capacity | ms per scan | vs smallest | RMSE [m] | landmarks (confirmed) | overflow |")
    print("|---|---|---|---|---|---|")
    for cap, ms in runs.items():
        each = [m["ms_per_scan"] for m in ms]
        ratio = statistics.median(a["ms_per_scan"] / b["ms_per_scan"] for a, b in zip(ms, base))
        shown = f"{statistics.median(each):.2f}" + (
            f" ({', '.join(f'{x:.2f}' for x in each)})" if len(each) > 1 else ""
        )
        m = ms[0]
        print(
            f"| {cap} | {shown} | {ratio:.2f}x | {m['rmse_fixed']:.3f} "
            f"| {m['n_landmarks']} ({m['n_confirmed']}) | {m.get('landmark_overflow', 0)} |"
        )


if __name__ == "__main__":
    main()
