"""Cost per scan against the landmark capacity, on the same log: NANO-SLAM on the embedded
default's simulated park log at several ``filter.capacity`` values, in this process one after the
other, and a Markdown table of milliseconds per scan (after compilation), the ratio to the
smallest capacity, the RMSE and the map (identical wherever the map fits every capacity)::

    python experiments/capacity_cost.py
    python experiments/capacity_cost.py --particles 10 --capacity 512 4096 --set filter.split_devices=never
"""

from __future__ import annotations

import argparse
import tempfile

from nanoslam_jax.app.config import load_config
from nanoslam_jax.app.experiment import run_experiment


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--particles", type=int, default=100, help="filter.n_particles")
    ap.add_argument("--capacity", type=int, nargs="+", default=[512, 2048, 8192, 16384], help="filter.capacity values")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args()
    rows = []
    for cap in args.capacity:
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
            rows.append((cap, run_experiment(cfg, out, progress=False)))
    base = rows[0][1]["ms_per_scan"]
    print(f"\nNANO-SLAM, {args.particles} particles, embedded default log\n")
    print("| capacity | ms per scan | vs smallest | RMSE [m] | landmarks (confirmed) | overflow |")
    print("|---|---|---|---|---|---|")
    for cap, m in rows:
        print(
            f"| {cap} | {m['ms_per_scan']:.2f} | {m['ms_per_scan'] / base:.2f}x | {m['rmse_fixed']:.3f} "
            f"| {m['n_landmarks']} ({m['n_confirmed']}) | {m.get('landmark_overflow', 0)} |"
        )


if __name__ == "__main__":
    main()
