"""Where a run's compilation time goes: the filter program compiled with one part switched at a
time, each in a fresh process with the compilation cache off.

For each variant it prints the time to trace and lower the program (Python and JAX: the step's
functions traced once per compiled branch) and XLA's compile time, and the difference to the lean
program (row buckets and the device split off). A part's cost is that difference: what the
row buckets' extra branches, the device split, landmark management, the proposal cost to compile.

    python experiments/compile_breakdown.py                                   # NANO-SLAM, 10 and 100 particles
    python experiments/compile_breakdown.py --particles 100 --config configs/victoria_park_nano.yaml
    python experiments/compile_breakdown.py --particles 10 --set filter.method=ufastslam
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

LEAN = ["filter.row_buckets=never", "filter.split_devices=never"]
VARIANTS = {
    "lean: row buckets and device split off": LEAN,
    "defaults (filter.row_buckets, filter.split_devices auto)": [],
    "+ row buckets (always)": ["filter.row_buckets=always", "filter.split_devices=never"],
    "+ device split (always)": ["filter.row_buckets=never", "filter.split_devices=always"],
    "- landmark management (map.manage false)": [*LEAN, "map.manage=false"],
    "prior proposal instead (filter.method fastslam1)": [*LEAN, "filter.method=fastslam1"],
}

_CHILD = textwrap.dedent(
    """
    import json, os, sys, time
    from nanoslam_jax.app._devices import setup_run_devices
    from nanoslam_jax.app.config import load_config
    import nanoslam_jax
    config, sets = sys.argv[1], json.loads(sys.argv[2])
    cfg = load_config(config or None, sets)
    setup_run_devices(cfg)
    import jax
    from nanoslam_jax.app.experiment import load_log
    from nanoslam_jax.app.filters import settings_from_config
    from nanoslam_jax.methods import _scan
    with nanoslam_jax.float64():
        log = load_log(cfg, None)
        seg = log.segments
        n = int(seg.time.shape[0])
        static, params = settings_from_config(cfg, seg.k_max, n)
        chunk = max(1, min(cfg.output.chunk, n))
        padded, valid = _scan._pad(seg, chunk)
        piece = jax.tree.map(lambda a: a[:chunk], padded)
        state = _scan._init(static, params, jax.random.key(0))
        t0 = time.perf_counter()
        lowered = _scan._chunk.lower(static, params, state, piece, valid[:chunk])
        t1 = time.perf_counter()
        lowered.compile()
        t2 = time.perf_counter()
    print(json.dumps({"lower_s": t1 - t0, "compile_s": t2 - t1, "row_buckets": list(static.row_buckets),
                      "devices": static.devices, "segments": n}))
    """
)


def measure(config: str, sets: list[str]) -> dict:
    proc = subprocess.run(
        [sys.executable, "-c", _CHILD, config, json.dumps(sets)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"},
    )
    if proc.returncode != 0:
        raise RuntimeError(proc.stderr[-2000:])
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--config", default="configs/victoria_park_nano.yaml", help="base config ('' for the embedded default)"
    )
    ap.add_argument("--particles", type=int, nargs="+", default=[10, 100])
    ap.add_argument("--set", action="append", default=[], help="key=value for every variant")
    ap.add_argument("--only", nargs="*", help="variants whose name starts with one of these words")
    args = ap.parse_args(argv)
    print("| particles | variant | trace + lower [s] | XLA compile [s] | total [s] | vs lean [s] |")
    print("|---|---|---|---|---|---|")
    for n in args.particles:
        lean_total = None
        for name, sets in VARIANTS.items():
            if args.only and not any(name.startswith(w) for w in args.only) and lean_total is not None:
                continue
            r = measure(args.config, [f"filter.n_particles={n}", *args.set, *sets])
            total = r["lower_s"] + r["compile_s"]
            lean_total = total if lean_total is None else lean_total
            print(
                f"| {n} | {name} | {r['lower_s']:.1f} | {r['compile_s']:.1f} | {total:.1f} | {total - lean_total:+.1f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
