"""Speed and memory benchmark: prints Markdown tables (and writes them as JSON with ``--json``).

Each configuration runs in its own subprocess (so the peak resident memory is its own), on the
full Victoria Park log unless ``--segments`` cuts it, float64, after compilation, without the
persistent compilation cache (so ``compile [s]`` is a cold compilation):

    python experiments/benchmark.py                      # the standard table and the second run
    python experiments/benchmark.py --only nano-N10      # one row
    python experiments/benchmark.py --only second-run    # the compilation cache alone
    python experiments/benchmark.py --only data          # the data pipeline alone
    python experiments/benchmark.py --segments 1000      # quick look on the first 1000 scans
    python experiments/benchmark.py --json docs/data/benchmark.json   # the docs' performance table

``second-run``: ``nanoslam run CONFIG`` twice, each in a fresh process, with an empty
compilation cache (``NANOSLAM_CACHE_DIR`` in a temporary directory) before the first. It reports
each run's ``compile_s`` (what ``run_filter`` times around ``.lower(...).compile()`` of the chunk
program: tracing, lowering, and compiling or loading from the cache), JAX's own statistics of the
whole run (trace, lower, backend compile-or-load time; cache hits and misses, from its monitoring
events) and whether the two runs' ``trajectory.csv`` and ``map.csv`` are identical. Target: the
second run spends at most 3 s compiling.

``management``: the cost of landmark management, paired. One process compiles the config with
and without ``map.manage`` (10 particles), then runs the two programs alternately (A B, B A, ...)
``--repeats`` times (at least 5), so both see the same machine: the VM's drift between rows, which
on a shared 2-core machine is the size of the effect, cancels. Reports each setting's best and
median run time, the ratio of the bests and the median of the per-round ratios. Target: the
managed program at most 1.2x the unmanaged one.

``data``: the data pipeline without the filter, best of 5 (after one warm-up): simulating the
default log (``SimConfig()``; target at most 2 s) and cutting the real log into segments
(``make_segments`` with the paper's 30 m range; target at most 0.5 s).

Rows: NANO with 10, 100 and 1000 particles (capacity 512), NANO at 10 particles with capacities
256, 512 and 1024 (cost per scan should grow only by the capacity's linear term), NANO at 10
particles in one compiled call (no chunks: the cost of the progress reporting), with the
optimistix fixed-point solver instead of the while_loop, the other particle methods at 10
particles (targets: at most 2x NANO's run time), EKF-SLAM with 512 landmark slots (target:
at most 60 s for the whole log) and NASRUKF with 512 feature slots (target: at most 2x NANO's
10-particle run time). ``nano-N10-unmanaged`` switches landmark management off (target: the
managed ``nano-N10`` at most 1.2x its run time).
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
import jax

jax.config.update("jax_enable_x64", True)  # the library computes in float64

SECOND_RUN = "second-run"
DATA = "data"
MANAGEMENT = "management"

#: The ``management`` table's two settings (the 10-particle row with and without management).
MANAGEMENT_VARIANTS = {"managed": [], "unmanaged": ["map.manage=false"]}

#: Targets of the ``data`` table, seconds.
DATA_TARGETS = {"simulate the default log": 2.0, "segments of the real log": 0.5}

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
    "nano-N10-unmanaged": ["map.manage=false"],
}


def _segments(cfg, data: str | None, segments: int | None):
    """The log's segments (the first ``segments`` only, when given), after setting the devices up
    as ``nanoslam run`` does."""
    from nanoslam_jax.app._devices import setup_run_devices
    from nanoslam_jax.app.experiment import load_log

    setup_run_devices(cfg)
    seg = load_log(cfg, data).segments
    return seg if segments is None else type(seg)(*(a[:segments] for a in seg))


def run_one(
    name: str, overrides: list[str], config: str, segments: int | None, data: str | None, repeats: int = 1
) -> dict:
    """Run one configuration in this process and return its measurements (``run_s``: the best of
    ``repeats`` runs of the compiled program; ``compile_s``: the first run's)."""
    import jax

    from nanoslam_jax.app.config import load_config
    from nanoslam_jax.methods import reported_map, run_filter
    from nanoslam_jax.app.filters import settings_from_config

    cfg = load_config(config, overrides)
    seg = _segments(cfg, data, segments)
    static, params = settings_from_config(cfg, seg.k_max)
    load_before = os.getloadavg()[0]
    t0 = time.perf_counter()
    run = run_filter(static, params, seg, cfg.seed, chunk=cfg.output.chunk)
    total = time.perf_counter() - t0
    run_times = [run.run_s]
    for _ in range(repeats - 1):
        run_times.append(run_filter(static, params, seg, cfg.seed, chunk=cfg.output.chunk).run_s)
    run = run._replace(run_s=min(run_times))
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
        "run_s_all": run_times,
        "ms_per_scan": 1e3 * run.run_s / n,
        "total_s": total,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "landmarks": int(jax.numpy.sum(reported_map(run.state).active)),
        "backend": jax.default_backend(),
        # The machine's 1-minute load average before and after the run: on a shared VM a load
        # above its cores means the row was measured while other work competed for them.
        "load": [round(load_before, 2), round(os.getloadavg()[0], 2)],
    }


def second_run(config: str, data: str | None) -> dict:
    """``nanoslam run CONFIG`` twice in fresh processes over an empty cache; see the module docstring."""
    with tempfile.TemporaryDirectory(prefix="nanoslam-bench-") as tmp:
        env = {**os.environ, "NANOSLAM_CACHE_DIR": str(Path(tmp) / "cache")}
        env.pop("JAX_COMPILATION_CACHE_DIR", None)
        runs = []
        for name in ("first", "second"):
            cmd = [
                sys.executable,
                "-m",
                "nanoslam_jax.app.cli",
                "run",
                config,
                "--out",
                str(Path(tmp) / name),
                "--quiet",
            ]
            if data:
                cmd += ["--data", data]
            load = os.getloadavg()[0]
            t0 = time.perf_counter()
            res = subprocess.run(cmd, capture_output=True, text=True, env=env)
            wall = time.perf_counter() - t0
            if res.returncode != 0:
                raise RuntimeError(f"{' '.join(cmd)} failed:\n{res.stderr[-2000:]}")
            m = json.loads((Path(tmp) / name / "metrics.json").read_text())
            runs.append(
                dict(
                    run=name,
                    compile_s=m["compile_s"],
                    run_s=m["run_s"],
                    wall_s=wall,
                    jax=m["compilation"],
                    rmse_fixed=m["rmse_fixed"],
                    load=[round(load, 2), round(os.getloadavg()[0], 2)],
                )
            )
        identical = all(
            (Path(tmp) / "first" / f).read_bytes() == (Path(tmp) / "second" / f).read_bytes()
            for f in ("trajectory.csv", "map.csv")
        )
    return dict(config=config, runs=runs, identical=identical)


def paired_timing(
    config: str, variants: dict[str, list[str]], segments: int | None, data: str | None, repeats: int
) -> dict:
    """Run each variant's compiled program ``repeats`` times, alternating their order every round
    (see the ``management`` table in the module docstring); all variants share one process and log."""
    import statistics

    from nanoslam_jax.app.config import load_config
    from nanoslam_jax.methods import run_filter
    from nanoslam_jax.app.filters import settings_from_config

    cfgs = {k: load_config(config, v) for k, v in variants.items()}
    seg = _segments(next(iter(cfgs.values())), data, segments)
    progs = {}
    for k, cfg in cfgs.items():
        static, params = settings_from_config(cfg, seg.k_max)
        run_filter(static, params, seg, cfg.seed, chunk=cfg.output.chunk)  # compiled and warmed up
        progs[k] = (static, params, cfg)
    times: dict[str, list[float]] = {k: [] for k in variants}
    load_before = os.getloadavg()[0]
    for i in range(repeats):
        for k in list(variants) if i % 2 == 0 else list(variants)[::-1]:
            static, params, cfg = progs[k]
            times[k].append(run_filter(static, params, seg, cfg.seed, chunk=cfg.output.chunk).run_s)
    base = list(variants)[-1]
    out = dict(
        config=config,
        repeats=repeats,
        scans=int(seg.time.shape[0]),
        base=base,
        variants={},
        load=[round(load_before, 2), round(os.getloadavg()[0], 2)],
    )
    for k, ts in times.items():
        ratios = [a / b for a, b in zip(ts, times[base])]
        out["variants"][k] = dict(
            overrides=variants[k],
            run_s=ts,
            best_s=min(ts),
            median_s=statistics.median(ts),
            ratio_best=min(ts) / min(times[base]),
            ratio_median=statistics.median(ratios),
        )
    return out


def data_timings(data: str | None) -> dict:
    """Seconds of the data pipeline's two steps (best of 5 after a warm-up); see the module docstring."""
    from nanoslam_jax.app.config import SimConfig, VehicleConfig, load_config, resolve_data_dir
    from nanoslam_jax.data import load_victoria_park, make_segments
    from nanoslam_jax.sim.park import simulate

    real = load_victoria_park(resolve_data_dir(load_config(None), data))
    steps = {
        "simulate the default log": lambda: simulate(SimConfig(), VehicleConfig()),
        "segments of the real log": lambda: make_segments(real, max_range=30.0),
    }
    out = {}
    for name, fn in steps.items():
        fn()
        times = []
        for _ in range(5):
            t0 = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t0)
        out[name] = min(times)
    return out


def _load(r: dict) -> str:
    return " / ".join(f"{x:.1f}" for x in r.get("load", ()))


def markdown(result: dict) -> str:
    """The Markdown tables of a benchmark result (as written by ``--json``)."""
    out = []
    if result.get("rows"):
        scans = sorted({r["scans"] for r in result["rows"]})
        out += [f"Scans per run: {', '.join(map(str, scans))}.", ""]
        head = (
            "| row | particles | devices | capacity | compile [s] | run [s] | ms/scan "
            "| peak RSS [MB] | landmarks | load before / after |"
        )
        out += [head, "|" + "---|" * (head.count("|") - 1)]
        for r in result["rows"]:
            out.append(
                f"| {r['name']} | {r['particles']} | {r['devices']} | {r['capacity']} | "
                f"{r['compile_s']:.1f} | {r['run_s']:.2f} | {r['ms_per_scan']:.3f} | "
                f"{r['peak_rss_mb']:.0f} | {r['landmarks']} | {_load(r)} |"
            )
    dt = result.get("data")
    if dt:
        if out:
            out.append("")
        out += ["| data step | best of 5 [s] | target [s] |", "|---|---|---|"]
        out += [f"| {k} | {v:.3f} | {DATA_TARGETS.get(k, float('nan')):g} |" for k, v in dt.items()]
    mg = result.get("management")
    if mg:
        if out:
            out.append("")
        out += [
            f"Landmark management's cost, paired: {mg['repeats']} alternating runs of each compiled program in "
            f"one process ({mg['scans']} scans; ratios against `{mg['base']}`):",
            "",
            "| setting | best [s] | median [s] | ratio of bests | median of per-run ratios | load before / after |",
            "|---|---|---|---|---|---|",
        ]
        for k, v in mg["variants"].items():
            out.append(
                f"| {k} | {v['best_s']:.2f} | {v['median_s']:.2f} | {v['ratio_best']:.3f} | "
                f"{v['ratio_median']:.3f} | {_load(mg)} |"
            )
    sr = result.get("second_run")
    if sr:
        if out:
            out.append("")
        out += [
            f"`nanoslam run {sr['config']}` twice in fresh processes, empty cache before the first "
            f"(outputs identical: {'yes' if sr['identical'] else '**no**'}):",
            "",
            "| run | compile_s [s] | JAX: trace [s] | lower [s] | compile or load [s] | cache hits | cache misses "
            "| run [s] | wall [s] | load before / after |",
            "|---|---|---|---|---|---|---|---|---|---|",
        ]
        for r in sr["runs"]:
            j = r["jax"]
            out.append(
                f"| {r['run']} | {r['compile_s']:.2f} | {j['trace_s']:.2f} | {j['lower_s']:.2f} | "
                f"{j['backend_s']:.2f} | {j['cache_hits']} | {j['cache_misses']} | {r['run_s']:.2f} | "
                f"{r['wall_s']:.1f} | {_load(r)} |"
            )
    return "\n".join(out)


def _single(name: str, args) -> dict | None:
    """Run one row (or the ``management`` table) in a fresh process without the persistent
    compilation cache (so its compile time is a cold compilation and its memory its own)."""
    cmd = [sys.executable, __file__, "--single", name, "--config", args.config, "--repeats", str(args.repeats)]
    cmd += ["--segments", str(args.segments)] if args.segments else []
    cmd += ["--data", args.data] if args.data else []
    env = os.environ.copy()
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    res = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if res.returncode != 0:
        print(f"{name}: failed\n{res.stderr[-2000:]}", file=sys.stderr)
        return None
    return json.loads(res.stdout.strip().splitlines()[-1])


def _commit() -> str:
    res = subprocess.run(
        ["git", "describe", "--always", "--dirty"], capture_output=True, text=True, cwd=Path(__file__).resolve().parent
    )
    return res.stdout.strip() or "unknown"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument(
        "--only", nargs="*", choices=list(ROWS) + [SECOND_RUN, DATA, MANAGEMENT], help="rows to run (default: all)"
    )
    p.add_argument("--config", default="configs/victoria_park_nano.yaml")
    p.add_argument("--segments", type=int, help="use only the first N segments (not for second-run)")
    p.add_argument("--data", help="log directory")
    p.add_argument("--json", help="also write the tables as JSON here (the docs' performance page reads it)")
    p.add_argument(
        "--repeats",
        type=int,
        default=1,
        help="runs of each row's compiled program; run [s] is the best (default 1; 3 for ratios "
        "between rows on a noisy VM)",
    )
    p.add_argument("--single", help=argparse.SUPPRESS)
    args = p.parse_args()

    if args.single == MANAGEMENT:
        print(
            json.dumps(paired_timing(args.config, MANAGEMENT_VARIANTS, args.segments, args.data, max(args.repeats, 5)))
        )
        return
    if args.single:
        print(json.dumps(run_one(args.single, ROWS[args.single], args.config, args.segments, args.data, args.repeats)))
        return

    wanted = args.only or list(ROWS) + [SECOND_RUN, DATA, MANAGEMENT]
    rows = []
    for name in [n for n in wanted if n in ROWS]:
        r = _single(name, args)
        if r is None:
            continue
        rows.append(r)
        print(f"{name}: {r['run_s']:.2f} s run, {r['compile_s']:.1f} s compile", file=sys.stderr, flush=True)
    result = dict(
        commit=_commit(),
        date=datetime.datetime.now().isoformat(timespec="minutes"),
        cores=len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
        command=" ".join(["python", "experiments/benchmark.py", *sys.argv[1:]]),
        rows=rows,
    )
    if MANAGEMENT in wanted:
        mg = _single(MANAGEMENT, args)
        if mg is not None:
            result["management"] = mg
    if DATA in wanted:
        result["data"] = data_timings(args.data)
    if SECOND_RUN in wanted:
        result["second_run"] = second_run(args.config, args.data)
    print(markdown(result))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
