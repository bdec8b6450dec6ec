"""A whole run on one device against the same run split over two JAX CPU devices, in one process.

Both programs are compiled first and then run alternately over the whole log (this VM's speed
drifts too much to compare separate processes); prints each run's time and the resample count
(the same in both: the split computes the same run).

    python experiments/micro/split_ab.py --particles 100 --repeat 2
"""

from __future__ import annotations

import argparse
import dataclasses


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", default="configs/victoria_park_nano.yaml")
    p.add_argument("--data", help="log directory")
    p.add_argument("--particles", type=int, default=100)
    p.add_argument("--repeat", type=int, default=2)
    args = p.parse_args()

    import jax

    jax.config.update("jax_num_cpu_devices", 2)
    jax.config.update("jax_enable_x64", True)  # the library computes in float64
    from nanoslam_jax.app.config import load_config
    from nanoslam_jax.app.experiment import load_log
    from nanoslam_jax.methods import run_filter
    from nanoslam_jax.app.filters import settings_from_config

    cfg = load_config(args.config, [f"filter.n_particles={args.particles}", "filter.split_devices=always"])
    seg = load_log(cfg, args.data).segments
    split, params = settings_from_config(cfg, seg.k_max)
    if split.devices != 2:
        raise SystemExit(f"{args.particles} particles do not divide over 2 devices")
    settings = {"one device": dataclasses.replace(split, devices=1), "split over 2 devices": split}
    times = {k: [] for k in settings}
    for _ in range(args.repeat):
        for name, static in settings.items():
            run = run_filter(static, params, seg, cfg.seed, chunk=cfg.output.chunk)
            times[name].append(run.run_s)
            print(
                f"{name}: run {run.run_s:.2f} s (compile {run.compile_s:.1f} s), "
                f"{int(run.state.resample_count)} resamples",
                flush=True,
            )
    print(f"\n| {args.particles} particles | " + " | ".join(f"{k} [s]" for k in times) + " |")
    print("|---|" + "---|" * len(times))
    print("| run | " + " | ".join(" / ".join(f"{t:.2f}" for t in v) for v in times.values()) + " |")


if __name__ == "__main__":
    main()
