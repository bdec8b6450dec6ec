"""``nanoslam sweep``: the command line of batch hyperparameter sweeps.

nanoslam sweep configs/sweep_example.yaml --out results/sweep1
nanoslam sweep configs/sweep_example.yaml --out results/sweep1 --resume
nanoslam sweep configs/sweep_example.yaml --out results/sweep1 --backend ray --ray-address auto
"""

from __future__ import annotations

import argparse
import datetime as _dt
import sys
from collections.abc import Sequence
from pathlib import Path

__all__ = ["add_sweep_parser", "sweep_command"]


def add_sweep_parser(sub, parents: Sequence[argparse.ArgumentParser] = ()) -> argparse.ArgumentParser:
    """Register the ``sweep`` subcommand on an ``add_subparsers`` object.

    Args:
        sub: the ``add_subparsers`` object.
        parents: parsers whose options ``sweep`` shares with the other subcommands.
    """
    w = sub.add_parser(
        "sweep",
        parents=list(parents),
        help="run a hyperparameter sweep: one compiled program per shape, vmapped over configs and seeds",
        description="Run the configurations of a sweep file (grid and random samples of traced hyperparameters, "
        "shape settings, seeds) in batches of one compiled program per shape. Results go to "
        "DIR/results.csv as each batch finishes; an interrupted sweep continues with --resume.",
    )
    w.add_argument("sweep", help="sweep YAML, e.g. configs/sweep_example.yaml")
    w.add_argument("--out", help="sweep directory (default: results/sweep-<name>-<timestamp>)")
    w.add_argument("--resume", action="store_true", help="continue the sweep in --out, skipping finished runs")
    w.add_argument("--data", help="log directory (overrides data.path and $NANOSLAM_DATA)")
    w.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a key of the base config, e.g. --set filter.capacity=256 (repeatable)",
    )
    w.add_argument("--backend", choices=["local", "ray"], help="where batches run (default: the file's run.backend)")
    w.add_argument(
        "--parallel",
        choices=["auto", "single", "devices", "processes"],
        help="how the local backend uses several cores (default: the file's run.parallel)",
    )
    w.add_argument("--workers", type=int, help="cores to use (default: all this process may run on)")
    w.add_argument(
        "--vectorize",
        choices=["auto", "vmap", "map"],
        help="how a batch is computed: vmap (vectorised), map (one run after another, bit-identical to "
        "single runs), auto (default: the file's run.vectorize)",
    )
    w.add_argument("--batch", type=int, help="runs per compiled call (default: the file's run.batch, or automatic)")
    w.add_argument("--ray-address", help="Ray cluster address (default: the file's ray.address, else a local instance)")
    w.add_argument("--dry-run", action="store_true", help="list the configurations and runs, run nothing")
    w.add_argument("--quiet", action="store_true", help="no progress on stderr")
    return w


def sweep_command(args) -> int:
    """Run ``nanoslam sweep`` with parsed arguments; returns the exit status."""
    import dataclasses

    from nanoslam_jax.app.config import ConfigError
    from nanoslam_jax.app.sweep._expand import expand
    from nanoslam_jax.app.sweep._spec import load_sweep

    spec = load_sweep(args.sweep, tuple(args.overrides))
    if getattr(args, "no_cache", False):
        spec = dataclasses.replace(spec, run=dataclasses.replace(spec.run, compile_cache=False))
    if args.ray_address:
        spec = dataclasses.replace(spec, ray_address=args.ray_address)
    for flag in ("workers", "batch"):
        v = getattr(args, flag)
        if v is not None and v < 1:
            raise ConfigError(f"--{flag}: expected a positive integer, got {v}")
    if args.dry_run:
        points, runs, skipped = expand(spec)
        print(
            f"{spec.name}: {len(points)} configurations x {len(spec.seeds)} seeds = {len(runs)} runs"
            + (f" ({len(skipped)} invalid configurations skipped)" if skipped else "")
        )
        for p in points:
            print(f"  {p.config_id}: " + (", ".join(f"{k}={v!r}" for k, v in p.values.items()) or "base config"))
        return 0
    if args.out:
        out = Path(args.out)
    elif args.resume:
        raise ConfigError("--resume needs --out DIR (the sweep directory to continue)")
    else:
        out = Path("results") / f"sweep-{spec.name}-{_dt.datetime.now():%Y%m%d-%H%M%S}"

    from nanoslam_jax.app.sweep._runner import SweepOverrides, run_sweep

    try:
        res = run_sweep(
            spec,
            out,
            resume=args.resume,
            data_dir=args.data,
            progress=not args.quiet,
            overrides=SweepOverrides(
                backend=args.backend,
                parallel=args.parallel,
                workers=args.workers,
                batch=args.batch,
                vectorize=args.vectorize,
            ),
        )
    except KeyboardInterrupt:
        print(
            f"\nnanoslam: sweep interrupted; finished batches are saved in {out / 'results.csv'}; continue with:\n"
            f"  nanoslam sweep {args.sweep} --out {out} --resume",
            file=sys.stderr,
        )
        return 130
    if res.best is not None:
        m = spec.metric
        b = res.best
        values = ", ".join(f"{k}={b[k]!r}" for k in spec.swept_keys) or "the base config"
        print(
            f"best: {b['config_id']} ({values}): {m} median {b[f'{m}_median']:.4g} "
            f"[{b[f'{m}_q1']:.4g}, {b[f'{m}_q3']:.4g}] over {b['n_ok']}/{b['n_runs']} seeds -> {out / 'best.yaml'}"
        )
    else:
        print("no configuration finished ok; see summary.md")
    print(f"{res.n_runs} runs ({res.n_failed} failed, {res.n_skipped} resumed)")
    print(out)
    return 0
