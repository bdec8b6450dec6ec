"""Two settings of the filter step compared back to back in one process (A/B).

On a machine whose speed drifts (a shared VM), two separate benchmark runs can differ by more
than the change being measured. Here both programs are compiled in one process and called
alternately over the same mid-log stretch from the same filter state, so a slow period hits
both; the table gives the minimum and the median of the repeats.

    python experiments/ab_step.py --particles 1000 --b filter.row_buckets=always --a filter.row_buckets=never
    python experiments/ab_step.py --particles 100 --b filter.split_devices=always --a filter.split_devices=never \
        --devices 2 --start 1000 --scans 300 --repeat 5

The state at ``--start`` comes from running setting A over the scans before it (on one device).
"""

from __future__ import annotations

import argparse
import dataclasses
import time


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", default="configs/victoria_park_nano.yaml")
    p.add_argument("--data", help="log directory")
    p.add_argument("--particles", type=int, default=100)
    p.add_argument("--a", nargs="*", default=[], help="overrides of setting A (key=value)")
    p.add_argument("--b", nargs="*", default=[], help="overrides of setting B (key=value)")
    p.add_argument("--start", type=int, default=1000, help="first scan of the timed stretch")
    p.add_argument("--scans", type=int, default=300, help="scans in the timed stretch")
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--devices", type=int, default=1, help="JAX CPU devices to expose (for split_devices)")
    args = p.parse_args()

    import jax

    if args.devices > 1:
        jax.config.update("jax_num_cpu_devices", args.devices)
    import numpy as np

    import nanoslam_jax  # noqa: F401  (float64)
    from nanoslam_jax.config import load_config
    from nanoslam_jax.experiment import load_log
    from nanoslam_jax.filter import filter_step, make_proposal, run_filter, settings_from_config

    base = [f"filter.n_particles={args.particles}"]
    cfgs = {k: load_config(args.config, base + list(v)) for k, v in (("A", args.a), ("B", args.b))}
    seg = load_log(cfgs["A"], args.data).segments
    settings = {k: settings_from_config(c, seg.k_max) for k, c in cfgs.items()}
    before = type(seg)(*(a[:args.start] for a in seg))
    static_a, params_a = settings["A"]
    state = run_filter(dataclasses.replace(static_a, devices=1), params_a, before, 0, chunk=args.start).state
    stretch = jax.tree.map(jax.numpy.asarray, type(seg)(*(a[args.start:args.start + args.scans] for a in seg)))

    programs = {}
    for k, (static, params) in settings.items():
        proposal = make_proposal(static, params)

        def scan(st, sg, pr, static=static, proposal=proposal):
            return jax.lax.scan(lambda c, x: filter_step(static, pr, proposal, c, x), st, sg)[0]

        t0 = time.perf_counter()
        programs[k] = jax.jit(scan).lower(state, stretch, params).compile()
        print(f"{k}: compiled in {time.perf_counter() - t0:.1f} s ({static.row_buckets=}, {static.devices=})", flush=True)
        jax.block_until_ready(programs[k](state, stretch, params))

    times = {k: [] for k in programs}
    for _ in range(args.repeat):
        for k, prog in programs.items():
            t0 = time.perf_counter()
            jax.block_until_ready(prog(state, stretch, settings[k][1]))
            times[k].append(1e3 * (time.perf_counter() - t0) / args.scans)

    print(f"\n{args.particles} particles, scans {args.start}-{args.start + args.scans}, {args.repeat} alternated repeats\n")
    print("| setting | overrides | min ms/scan | median ms/scan | all |")
    print("|---|---|---|---|---|")
    for k, v in times.items():
        over = " ".join(args.a if k == "A" else args.b) or "(config)"
        print(f"| {k} | {over} | {min(v):.3f} | {float(np.median(v)):.3f} | {' / '.join(f'{x:.2f}' for x in v)} |")


if __name__ == "__main__":
    main()
