"""Speed and memory benchmark: prints a Markdown table.

Each configuration runs in its own subprocess (so the peak resident memory is its own), on the
full Victoria Park log unless ``--segments`` cuts it, float64, after compilation:

    python experiments/benchmark.py                      # the standard table
    python experiments/benchmark.py --only nano-N10      # one row
    python experiments/benchmark.py --segments 1000      # quick look on the first 1000 scans

Rows: NANO with 10, 100 and 1000 particles (capacity 512), NANO at 10 particles with capacities
256, 512 and 1024 (cost per scan should grow only by the capacity's linear term), NANO at 10
particles in one compiled call (no chunks: the cost of the progress reporting), with the
optimistix fixed-point solver instead of the while_loop, the other particle methods at 10
particles (targets: at most 2x NANO's run time), EKF-SLAM with 512 landmark slots (target:
at most 60 s for the whole log) and NASRUKF with 512 feature slots (target: at most 2x NANO's
10-particle run time).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time

ROWS: dict[str, list[str]] = {
    "nano-N10": [],
    "nano-N100": ["filter.n_particles=100"],
    "nano-N1000": ["filter.n_particles=1000"],
    "nano-N10-cap256": ["filter.capacity=256"],
    "nano-N10-cap1024": ["filter.capacity=1024"],
    "nano-N10-onechunk": ["output.chunk=100000"],
    "nano-N10-optimistix": ["nano.solver=optimistix"],
    "fastslam1-N10": ["filter.method=fastslam1"],
    "fastslam2-N10": ["filter.method=fastslam2"],
    "ufastslam-N10": ["filter.method=ufastslam"],
    "iterated-gn-N10": ["filter.method=iterated", "iterated.solver=gauss_newton"],
    "iterated-lm-N10": ["filter.method=iterated", "iterated.solver=levenberg_marquardt"],
    "ekf_slam-cap512": ["filter.method=ekf_slam"],
    "nasrukf": ["filter.method=nasrukf"],
}


def run_one(name: str, overrides: list[str], config: str, segments: int | None, data: str | None) -> dict:
    """Run one configuration in this process and return its measurements."""
    import jax

    from nanoslam_jax._devices import setup_run_devices
    from nanoslam_jax.config import load_config
    from nanoslam_jax.experiment import load_log
    from nanoslam_jax.filter import reported_map, run_filter, settings_from_config

    cfg = load_config(config, overrides)
    setup_run_devices(cfg.filter.split_devices, cfg.filter.n_particles)  # as `nanoslam run` does
    log = load_log(cfg, data)
    seg = log.segments
    if segments is not None:
        seg = type(seg)(*(a[:segments] for a in seg))
    static, params = settings_from_config(cfg, seg.k_max)
    t0 = time.perf_counter()
    run = run_filter(static, params, seg, cfg.seed, chunk=cfg.output.chunk)
    total = time.perf_counter() - t0
    n = int(seg.time.shape[0])
    return {
        "name": name,
        "method": cfg.filter.method,
        "particles": static.n_particles,
        "devices": static.devices,
        "capacity": static.capacity,
        "scans": n,
        "compile_s": run.compile_s,
        "run_s": run.run_s,
        "ms_per_scan": 1e3 * run.run_s / n,
        "total_s": total,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "landmarks": int(jax.numpy.sum(reported_map(run.state).active)),
        "backend": jax.default_backend(),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--only", nargs="*", choices=list(ROWS), help="rows to run (default: all)")
    p.add_argument("--config", default="configs/victoria_park_nano.yaml")
    p.add_argument("--segments", type=int, help="use only the first N segments")
    p.add_argument("--data", help="log directory")
    p.add_argument("--json", help="also write the rows as JSON here")
    p.add_argument("--single", help=argparse.SUPPRESS)
    args = p.parse_args()

    if args.single:
        print(json.dumps(run_one(args.single, ROWS[args.single], args.config, args.segments, args.data)))
        return

    rows = []
    for name in args.only or list(ROWS):
        cmd = [sys.executable, __file__, "--single", name, "--config", args.config]
        if args.segments:
            cmd += ["--segments", str(args.segments)]
        if args.data:
            cmd += ["--data", args.data]
        res = subprocess.run(cmd, capture_output=True, text=True, env=os.environ.copy())
        if res.returncode != 0:
            print(f"{name}: failed\n{res.stderr[-2000:]}", file=sys.stderr)
            continue
        rows.append(json.loads(res.stdout.strip().splitlines()[-1]))
        r = rows[-1]
        print(f"{name}: {r['run_s']:.2f} s run, {r['compile_s']:.1f} s compile", file=sys.stderr, flush=True)

    head = "| row | method | particles | devices | capacity | scans | compile [s] | run [s] | ms/scan | peak RSS [MB] | landmarks |"
    print(head)
    print("|" + "---|" * (head.count("|") - 1))
    for r in rows:
        print(f"| {r['name']} | {r['method']} | {r['particles']} | {r['devices']} | {r['capacity']} | {r['scans']} | {r['compile_s']:.1f} | "
              f"{r['run_s']:.2f} | {r['ms_per_scan']:.3f} | {r['peak_rss_mb']:.0f} | {r['landmarks']} |")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=2)


if __name__ == "__main__":
    main()
