"""Seconds per log of one study point: a single run, timed after compilation, in a fresh process.

The study's accuracy runs are batches of seeds vmapped in one program over several JAX devices;
a batch's time divided by its size is not what one run costs (batched runs are cheaper per run,
and a process that exposes several JAX devices runs a single program more slowly). So each point
is timed in a process of its own, set up as ``nanoslam run`` sets itself up
(:func:`~nanoslam_jax.app._devices.setup_run_devices`: the particles split over the cores from 64
particles up), running the point's first seed alone over the study's log (the filter, and with
``smoother.enabled`` the smoother after it, as ``nanoslam run`` does):

    python -m nanoslam_jax.app.study._timing CONFIG.yaml --json OUT.json [--data DIR] [--segments N]
        [--repeats 3] [--budget-s 60] [--cache DIR]

The run is repeated (the program is compiled once per repeat, or loaded from the persistent
compilation cache ``--cache``) up to ``--repeats`` times while the timed runs add up to less
than ``--budget-s`` seconds; the JSON holds every timed run, their median (``seconds_per_log``)
and minimum, the compilation time of the first, the devices the particles were split over and
the peak resident memory.
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import sys
from typing import Optional, Sequence

__all__ = ["time_point", "main"]


def time_point(
    config_path: str,
    data_dir: Optional[str],
    segments: Optional[int],
    repeats: int,
    budget_s: float,
    cache: Optional[str] = None,
) -> dict:
    """Time single runs of a config in this process (call it first thing, before any JAX work).

    Args:
        config_path: the point's resolved config (its ``seed`` is the seed timed).
        data_dir: log directory overriding ``data.path``.
        segments: use only the first this many segments (``None``: all).
        repeats: most timed runs.
        budget_s: no further run once the timed runs add up to this many seconds.
        cache: JAX persistent compilation cache directory (``None``: none).

    Returns:
        ``seconds_per_log`` (median of the runs), ``seconds_per_log_min``, ``runs_s`` (each run),
        ``timing_runs``, ``compile_s`` (first run), ``ms_per_scan``, ``scans``, ``devices``,
        ``peak_rss_mb``.
    """
    from nanoslam_jax.app._devices import setup_run_devices
    from nanoslam_jax.app.config import load_config

    cfg = load_config(config_path)
    setup_run_devices(cfg)  # as `nanoslam run` does
    import numpy as np

    from nanoslam_jax.methods import run_filter
    from nanoslam_jax.app.filters import settings_from_config
    from nanoslam_jax.smoother._smoother import smooth_filter_run
    from nanoslam_jax.lib._cache import enable_compile_cache
    from nanoslam_jax.app.sweep import load_log_data

    if cache:
        enable_compile_cache(cache)
    log = load_log_data(cfg, data_dir, segments)
    static, params = settings_from_config(cfg, log.segments.k_max)
    runs: list[float] = []
    compile_s = None
    while len(runs) < repeats and (not runs or sum(runs) < budget_s):
        r = run_filter(static, params, log.segments, cfg.seed, chunk=cfg.output.chunk)
        if not np.all(np.isfinite(np.asarray(r.outputs.best_pose))):
            raise FloatingPointError(f"{config_path}: the timed run's estimate is not finite")
        compile_s = r.compile_s if compile_s is None else compile_s
        smoother_s = 0.0
        if cfg.smoother.enabled:  # the offline smoother after the run, part of what one run costs
            path = np.asarray(static.estimate.trajectory(r.outputs, r.state))
            smoother_s = smooth_filter_run(r, path, log.segments, params, cfg.smoother, static.prior).seconds
        runs.append(r.run_s + smoother_s)
    scans = int(log.segments.time.shape[0])
    med = statistics.median(runs)
    return {
        "seconds_per_log": med,
        "seconds_per_log_min": min(runs),
        "runs_s": runs,
        "timing_runs": len(runs),
        "compile_s": compile_s,
        "ms_per_scan": 1e3 * med / scans,
        "scans": scans,
        "devices": static.devices,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def main(argv: Optional[Sequence[str]] = None) -> int:
    """The command line of the timing process (used by the study runner)."""
    p = argparse.ArgumentParser(description="Time single runs of one config (a study point).")
    p.add_argument("config")
    p.add_argument("--json", required=True, help="write the measurements here")
    p.add_argument("--data")
    p.add_argument("--segments", type=int)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--budget-s", type=float, default=60.0)
    p.add_argument("--cache")
    a = p.parse_args(argv)
    out = time_point(a.config, a.data, a.segments, a.repeats, a.budget_s, a.cache)
    with open(a.json, "w") as f:
        json.dump(out, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
