"""Sweep throughput benchmark: prints Markdown tables.

    python experiments/sweep_benchmark.py                       # both tables (about 8 minutes on 2 cores)
    python experiments/sweep_benchmark.py --only throughput     # batched programs against sequential runs
    python experiments/sweep_benchmark.py --only multicore      # one device, JAX devices, pinned processes
    python experiments/sweep_benchmark.py --only ceiling        # what any batch could gain at most

The workload: 64 configurations (random samples of gate, new-landmark threshold, range and
bearing noise) of NANO-SLAM with 10 particles over the first 500 segments of the Victoria Park
log, float64.

1. *Throughput*: the 64 configurations as one vmapped batch of the sweep program
   (``batch_program``, ``vectorize='vmap'``), as one ``lax.map`` batch (``vectorize='map'``) and,
   on several cores, as the sweep's default (the vmapped batch split over
   ``SWEEP_DEVICES_PER_CORE`` JAX CPU devices per core) against 64 sequential calls of the
   single-run program (``single_program``, the same computation without the batch axis), all
   compiled once beforehand, timed ``--repeat`` times (best shown); configurations per second
   after compilation, and how far the batch members' poses are from the same runs alone. The
   sequential runs and the one-device batches run interleaved in a process with one JAX device
   (as a single 10-particle run has); the split batch runs in a second process that exposes the
   devices, since exposing several devices slows single-device programs.
2. *Multi-core* (each in fresh processes, through ``run_sweep`` end to end, compile included,
   no compilation cache, ``--vectorize`` as given): ``single``: one process, one device, the whole
   batch; ``devices``: one process with four JAX CPU devices per core (``jax_num_cpu_devices``;
   ``SWEEP_DEVICES_PER_CORE``), each batch split over them (``shard_map``); ``processes``: one process pinned to each core
   (``os.sched_setaffinity``), half the batch each. "cores busy" is the CPU time of all the
   mode's processes over its wall time.
3. *Ceiling* (not part of the default run): the most any batching of these runs could gain on
   this machine. The single-run program at 10 particles and at the counts of
   ``--ceiling-particles`` (default 1, 40, 80, 160) runs on each of the first
   ``--ceiling-configs`` configurations, the counts alternated, three times (the median counts),
   in a process pinned to one core (``os.sched_setaffinity`` before JAX starts); the 10-particle
   runs run again in an unpinned process. A batch of configurations evaluates the same
   per-particle arithmetic as one run with as many particles (a vmapped batch computes the same
   numbers) plus its per-configuration work, so on one core it costs no less per particle than
   the cheapest particle count measured here (the pinned process also times that batch of the
   same configurations at 10 particles, for comparison), and C cores at best divide that by C. The
   printed ceiling is C times the ratio of the 10-particle runs' time to the cheapest time per
   10 particles.

Every part compiles afresh (no persistent compilation cache), so the compile times are cold ones.

The package's defaults (``run.parallel: auto`` = devices, ``run.vectorize: auto`` = vmap)
are the fastest modes this benchmark measured on a 2-core machine; see ``AUTO_PARALLEL`` in
``nanoslam_jax/app/sweep/_runner.py`` and ``AUTO_VECTORIZE`` in ``nanoslam_jax/app/sweep/_plan.py``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
import jax

jax.config.update("jax_enable_x64", True)  # the library computes in float64

WORKLOAD = dict(n=64, particles=10, segments=500)


def sweep_dict(config: str, n: int, particles: int, segments: int, batch: int) -> dict:
    """The benchmark's sweep: ``n`` random configurations, one seed."""
    return {
        "name": "bench",
        "base": os.path.abspath(config),
        "set": [f"filter.n_particles={particles}"],
        "segments": segments,
        "seeds": [0],
        "random": {
            "n": n,
            "seed": 0,
            "params": {
                "filter.gate": {"low": 4.0, "high": 9.0},
                "filter.new_landmark": {"low": 13.0, "high": 20.0},
                "noise.sigma_r": {"low": 0.5, "high": 2.0, "log": True},
                "noise.sigma_beta_deg": {"low": 1.5, "high": 6.0},
            },
        },
        "run": {"batch": batch, "compile_cache": False, "fail_on_overflow": False},
        "plots": False,
    }


def workload(args, particles: int):
    """The benchmark's configurations with ``particles`` particles each.

    Returns:
        The sweep's points, the log's segments as JAX arrays, and each point's ``(static, params)``.
    """
    import jax

    import nanoslam_jax  # noqa: F401  (float64 before any array exists)
    from nanoslam_jax.app.filters import settings_from_config
    from nanoslam_jax.app.sweep import expand, load_log_data, sweep_from_dict

    spec = sweep_from_dict(
        sweep_dict(args.config, args.configs, particles, args.segments, args.configs), source="benchmark"
    )
    points, _, _ = expand(spec)
    log = load_log_data(points[0].config, args.data, spec.segments)
    seg = jax.tree.map(jax.numpy.asarray, log.segments)
    return points, seg, [settings_from_config(p.config, log.segments.k_max) for p in points]


def throughput(args) -> dict:
    """One part of the throughput comparison, after compilation (run in a fresh process).

    ``args.split_devices`` 0: this process has one JAX device (as a single run of 10 particles
    has): the sequential single runs, the vmapped batch and the ``lax.map`` batch, interleaved.
    ``args.split_devices`` N > 1: this process exposes N JAX CPU devices: the vmapped batch split
    over them, and one untimed pass of the single runs for the pose differences. The two parts run
    in separate processes because exposing several devices slows single-device programs
    (measured: 16 sequential runs took 2.7-3.0 s with one device exposed, 3.5 s with 4 and
    4.2-4.4 s with 8), which would flatter the split batch.
    """
    import jax

    split = args.split_devices
    if split > 1:
        jax.config.update("jax_num_cpu_devices", split)
    import numpy as np

    from nanoslam_jax.methods import row_buckets
    from nanoslam_jax.app.sweep import batch_program, single_program

    points, seg, plist = workload(args, args.particles)
    static = plist[0][0]
    params = [p for _, p in plist]
    stacked = jax.tree.map(lambda *a: jax.numpy.stack(a), *params)
    seeds = jax.numpy.zeros(len(params), dtype=int)

    def for_call(runs_per_device):  # the static settings of a call carrying this many runs per device
        # As the sweep runner does: a vmapped call carries configs x particles, enough for the
        # proposal's row buckets (filter.row_buckets: auto); one config at a time does not.
        return dataclasses.replace(
            static, row_buckets=row_buckets(points[0].config.filter.row_buckets, static.n_particles * runs_per_device)
        )

    def pose_diff(out, seq):
        return max(
            float(np.max(np.abs(np.asarray(out.best_pose[i]) - np.asarray(seq[i].best_pose))))
            for i in range(len(params))
        )

    t0 = time.perf_counter()
    single = single_program.lower(static, params[0], seeds[0], seg).compile()
    single_compile = time.perf_counter() - t0
    jax.block_until_ready(single(params[0], seeds[0], seg))  # warm
    res = dict(
        configs=len(params),
        particles=static.n_particles,
        segments=int(seg.time.shape[0]),
        cpu_count=len(os.sched_getaffinity(0)),
        single_compile_s=single_compile,
    )
    if split > 1:
        ndev = len(jax.devices())
        if len(params) % ndev:
            raise SystemExit(f"{len(params)} configurations do not split over {ndev} devices")
        t0 = time.perf_counter()
        sharded = batch_program.lower(for_call(len(params) // ndev), "vmap", ndev, stacked, seeds, seg).compile()
        res["shard_compile_s"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        seq = [jax.block_until_ready(single(p, s, seg)) for p, s in zip(params, seeds)]
        res["sequential_here_s"] = time.perf_counter() - t0  # for reference only (slowed by the devices)
        shard_t = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            out_shard = jax.block_until_ready(sharded(stacked, seeds, seg))
            shard_t.append(time.perf_counter() - t0)
        res.update(
            devices=ndev,
            sharded_s=min(shard_t),
            repeats=dict(sharded=shard_t),
            max_abs_pose_diff_sharded=pose_diff(out_shard, seq),
        )
        return res

    t0 = time.perf_counter()
    batched = batch_program.lower(for_call(len(params)), "vmap", 1, stacked, seeds, seg).compile()
    res["batch_compile_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    mapped = batch_program.lower(static, "map", 1, stacked, seeds, seg).compile()
    res["map_compile_s"] = time.perf_counter() - t0
    seq_t, vmap_t, map_t = [], [], []
    for _ in range(args.repeat):  # interleaved, so a burst of load on the machine hits all three
        t0 = time.perf_counter()
        seq = [jax.block_until_ready(single(p, s, seg)) for p, s in zip(params, seeds)]
        seq_t.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        out = jax.block_until_ready(batched(stacked, seeds, seg))
        vmap_t.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        out_map = jax.block_until_ready(mapped(stacked, seeds, seg))
        map_t.append(time.perf_counter() - t0)
    res.update(
        sequential_s=min(seq_t),
        vmapped_s=min(vmap_t),
        mapped_s=min(map_t),
        repeats=dict(sequential=seq_t, vmapped=vmap_t, mapped=map_t),
        max_abs_pose_diff=pose_diff(out, seq),
        max_abs_pose_diff_map=pose_diff(out_map, seq),
    )
    return res


def multicore_one(args) -> dict:
    """One mode of the multi-core comparison, end to end through run_sweep (run in a fresh process)."""
    mode = args.worker
    if mode == "devices":
        import jax

        from nanoslam_jax.app._devices import SWEEP_DEVICES_PER_CORE

        jax.config.update("jax_num_cpu_devices", 2 * SWEEP_DEVICES_PER_CORE)
    import csv

    import nanoslam_jax  # noqa: F401
    from nanoslam_jax.app.sweep import SweepOverrides, run_sweep, sweep_from_dict

    spec = sweep_from_dict(
        sweep_dict(args.config, args.configs, args.particles, args.segments, args.configs), source="benchmark"
    )
    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        run_sweep(
            spec,
            os.path.join(d, "s"),
            data_dir=args.data,
            progress=False,
            overrides=SweepOverrides(parallel=mode, workers=2, vectorize=args.vectorize),
        )
        wall = time.perf_counter() - t0
        rows = list(csv.DictReader(open(os.path.join(d, "s", "results.csv"))))
    compile_s = max(float(r["compile_s"]) for r in rows)
    return dict(
        mode=mode,
        vectorize=args.vectorize,
        configs=len(rows),
        wall_s=wall,
        compile_s=compile_s,
        ok=sum(r["status"] == "ok" for r in rows),
    )


def ceiling_one(args) -> dict:
    """The single-run program at each particle count of ``args.ceiling_particles`` and, pinned, the
    vmapped batch of the same configurations at 10 particles (run in a fresh process)."""
    pinned = args.ceiling_worker == "pinned"
    if pinned:
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # before JAX starts its threads
    import jax
    import numpy as np

    from nanoslam_jax.methods import row_buckets
    from nanoslam_jax.app.sweep import batch_program, single_program

    C = args.ceiling_configs
    counts = sorted({10, *args.ceiling_particles}) if pinned else [10]
    seed = jax.numpy.zeros((), dtype=int)
    calls, buckets = {}, {}  # name -> list of one zero-argument call per configuration (or one for the batch)
    for n in counts:
        points, seg, settings = workload(args, n)
        static = settings[0][0]  # one config at a time: the static settings of a single run of n particles
        prog = single_program.lower(static, settings[0][1], seed, seg).compile()
        calls[str(n)] = [lambda prog=prog, p=p, seg=seg: prog(p, seed, seg) for _, p in settings[:C]]
        buckets[str(n)] = list(static.row_buckets)
        if pinned and n == 10:  # the same configurations as one vmapped batch, as the sweep computes them
            batch_static = dataclasses.replace(
                static, row_buckets=row_buckets(points[0].config.filter.row_buckets, static.n_particles * C)
            )
            stacked = jax.tree.map(lambda *a: jax.numpy.stack(a), *[p for _, p in settings[:C]])
            seeds = jax.numpy.zeros(C, dtype=int)
            batch = batch_program.lower(batch_static, "vmap", 1, stacked, seeds, seg).compile()
            calls["batch"] = [lambda: batch(stacked, seeds, seg)]
            buckets["batch"] = list(batch_static.row_buckets)
    for cs in calls.values():
        jax.block_until_ready(cs[0]())  # warm
    times = {k: np.zeros((3, len(cs))) for k, cs in calls.items()}
    for rep in range(3):  # alternated, so a burst of load on the machine hits every kind of run
        for c in range(C):
            for k, cs in calls.items():
                if c < len(cs):
                    t0 = time.perf_counter()
                    jax.block_until_ready(cs[c]())
                    times[k][rep, c] = time.perf_counter() - t0
    return dict(
        mode=args.ceiling_worker,
        configs=C,
        cores=len(os.sched_getaffinity(0)),
        runs={
            k: dict(
                sum_of_medians_s=float(np.median(t, axis=0).sum()),
                row_buckets=buckets[k],
                sums_s=t.sum(axis=1).tolist(),
            )
            for k, t in times.items()
        },
    )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--only", choices=["throughput", "multicore", "ceiling"])
    p.add_argument("--config", default="configs/victoria_park_nano.yaml", help="base config")
    p.add_argument("--data", help="log directory")
    p.add_argument("--configs", type=int, default=WORKLOAD["n"])
    p.add_argument("--particles", type=int, default=WORKLOAD["particles"])
    p.add_argument("--segments", type=int, default=WORKLOAD["segments"])
    p.add_argument("--repeat", type=int, default=3, help="timed repetitions of the throughput runs (best is shown)")
    p.add_argument("--modes", nargs="*", default=["single", "devices", "processes"])
    p.add_argument(
        "--vectorize", default="vmap", choices=["vmap", "map"], help="batch computation of the multi-core runs"
    )
    p.add_argument(
        "--ceiling-particles",
        type=int,
        nargs="+",
        default=[1, 40, 80, 160],
        help="particle counts of the ceiling's single runs (10 is always included)",
    )
    p.add_argument(
        "--ceiling-configs", type=int, help="configurations the ceiling's runs cover (default: the first 16)"
    )
    p.add_argument("--json", help="also write the measurements here")
    p.add_argument("--worker", help=argparse.SUPPRESS)
    p.add_argument("--throughput-worker", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--split-devices", type=int, default=0, help=argparse.SUPPRESS)
    p.add_argument("--ceiling-worker", choices=["pinned", "free"], help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.ceiling_configs is None:
        args.ceiling_configs = min(16, args.configs)
    elif not 1 <= args.ceiling_configs <= args.configs:
        p.error(f"--ceiling-configs must be between 1 and --configs ({args.configs}), not {args.ceiling_configs}")

    if args.worker:
        print(json.dumps(multicore_one(args)))
        return
    if args.throughput_worker:
        print(json.dumps(throughput(args)))
        return
    if args.ceiling_worker:
        print(json.dumps(ceiling_one(args)))
        return

    common = [
        "--config",
        args.config,
        "--configs",
        str(args.configs),
        "--particles",
        str(args.particles),
        "--segments",
        str(args.segments),
        "--vectorize",
        args.vectorize,
        "--repeat",
        str(args.repeat),
    ] + (["--data", args.data] if args.data else [])
    results: dict = {}
    if args.only in (None, "throughput"):
        from nanoslam_jax.app._devices import SWEEP_DEVICES_PER_CORE

        cores = len(os.sched_getaffinity(0))
        parts = {}
        for split in [0] + ([cores * SWEEP_DEVICES_PER_CORE] if cores > 1 else []):
            res = subprocess.run(
                [sys.executable, __file__, "--throughput-worker", "--split-devices", str(split), *common],
                capture_output=True,
                text=True,
            )
            if res.returncode:
                sys.exit(f"throughput run failed:\n{res.stderr[-3000:]}")
            parts[split] = json.loads(res.stdout.strip().splitlines()[-1])
        t = dict(parts[0])
        t["repeats"] = dict(parts[0]["repeats"])
        for split, part in parts.items():
            if split:
                t.update({k: v for k, v in part.items() if k not in ("repeats", "single_compile_s")})
                t["repeats"].update(part["repeats"])
        results["throughput"] = t
        print(
            f"\nThroughput: {t['configs']} configurations x {t['particles']} particles x {t['segments']} segments "
            f"(NANO, Victoria Park), {t['cpu_count']} CPU cores, after compilation, best of {args.repeat}\n"
        )
        print("| execution | compile [s] | run [s] | configs/s | speed-up |")
        print("|---|---|---|---|---|")
        seq_rate, vm_rate = t["configs"] / t["sequential_s"], t["configs"] / t["vmapped_s"]
        print(
            f"| {t['configs']} sequential calls of the single-run program (one device) | {t['single_compile_s']:.1f} | "
            f"{t['sequential_s']:.2f} | {seq_rate:.2f} | 1.00 |"
        )
        print(
            f"| one vmapped batch of {t['configs']} | {t['batch_compile_s']:.1f} | {t['vmapped_s']:.2f} | "
            f"{vm_rate:.2f} | {vm_rate / seq_rate:.2f} |"
        )
        map_rate = t["configs"] / t["mapped_s"]
        print(
            f"| one batch of {t['configs']} with lax.map (vectorize: map) | {t['map_compile_s']:.1f} | "
            f"{t['mapped_s']:.2f} | {map_rate:.2f} | {map_rate / seq_rate:.2f} |"
        )
        if t.get("sharded_s"):
            sh_rate = t["configs"] / t["sharded_s"]
            print(
                f"| one vmapped batch of {t['configs']} split over {t['devices']} JAX devices (the sweep's default; "
                f"its own process) | {t['shard_compile_s']:.1f} | {t['sharded_s']:.2f} | {sh_rate:.2f} | {sh_rate / seq_rate:.2f} |"
            )
        print(
            f"\nlargest difference between a batch member's reported poses and the same run alone: "
            f"vmap {t['max_abs_pose_diff']:.2e} m, map {t['max_abs_pose_diff_map']:.2e} m"
            + (f", split {t['max_abs_pose_diff_sharded']:.2e} m" if t.get("sharded_s") else "")
        )
        if t.get("sequential_here_s"):
            print(
                f"(the {t['configs']} sequential runs in the split batch's process, with {t['devices']} devices exposed: "
                f"{t['sequential_here_s']:.2f} s, one pass)"
            )
        print(
            "all timings [s]: "
            + "; ".join(f"{k} " + ", ".join(f"{x:.2f}" for x in v) for k, v in t["repeats"].items()),
            flush=True,
        )
    if args.only in (None, "multicore"):
        rows = []
        for mode in args.modes:
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            res = subprocess.run([sys.executable, __file__, "--worker", mode, *common], capture_output=True, text=True)
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            if res.returncode:
                print(f"{mode}: failed\n{res.stderr[-3000:]}", file=sys.stderr)
                continue
            rows.append(json.loads(res.stdout.strip().splitlines()[-1]))
            # CPU time of the mode's processes (workers included): cores kept busy = cpu / wall.
            rows[-1]["cpu_s"] = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
            print(f"{mode}: {rows[-1]['wall_s']:.1f} s", file=sys.stderr, flush=True)
        results["multicore"] = rows
        print(
            f"\nMulti-core: the same {args.configs}-configuration sweep through run_sweep (vectorize: "
            f"{args.vectorize}), fresh processes, no compilation cache\n"
        )
        print(
            "| mode | wall incl. compile [s] | compile [s] | wall - compile [s] | configs/s after compile | "
            "CPU [s] | cores busy | ok |"
        )
        print("|---|---|---|---|---|---|---|---|")
        for r in rows:
            run = r["wall_s"] - r["compile_s"]
            print(
                f"| {r['mode']} | {r['wall_s']:.1f} | {r['compile_s']:.1f} | {run:.1f} | {r['configs'] / run:.2f} | "
                f"{r['cpu_s']:.1f} | {r['cpu_s'] / r['wall_s']:.2f} | {r['ok']}/{r['configs']} |"
            )
    if args.only == "ceiling":
        parts = {}
        for mode in ("pinned", "free"):
            res = subprocess.run(
                [
                    sys.executable,
                    __file__,
                    "--ceiling-worker",
                    mode,
                    "--ceiling-configs",
                    str(args.ceiling_configs),
                    "--ceiling-particles",
                    *map(str, args.ceiling_particles),
                    *common,
                ],
                capture_output=True,
                text=True,
            )
            if res.returncode:
                sys.exit(f"ceiling run ({mode}) failed:\n{res.stderr[-3000:]}")
            parts[mode] = json.loads(res.stdout.strip().splitlines()[-1])
        results["ceiling"] = parts
        pinned, free = parts["pinned"]["runs"], parts["free"]["runs"]
        alone = pinned["10"]["sum_of_medians_s"]
        print(
            f"\nCeiling: the single-run program on the first {args.ceiling_configs} configurations x "
            f"{args.segments} segments, median of 3 alternated runs each, summed\n"
        )
        print("| runs | row buckets | run time [s] | per 10 particles [s] | per-particle cost vs 10 alone |")
        print("|---|---|---|---|---|")
        per10 = {}
        for n, r in sorted(((k, r) for k, r in pinned.items() if k != "batch"), key=lambda kv: int(kv[0])):
            per10[n] = r["sum_of_medians_s"] * 10 / int(n)
            print(
                f"| {n} particle{'s' if n != '1' else ''}, one core | {tuple(r['row_buckets']) or '-'} | {r['sum_of_medians_s']:.2f} | "
                f"{per10[n]:.2f} | {per10[n] / alone:.2f} |"
            )
        b = pinned["batch"]
        print(
            f"| the {args.ceiling_configs} configurations x 10 particles as one vmapped batch, one core | "
            f"{tuple(b['row_buckets']) or '-'} | {b['sum_of_medians_s']:.2f} | {b['sum_of_medians_s']:.2f} | "
            f"{b['sum_of_medians_s'] / alone:.2f} |"
        )
        per10["batch"] = b["sum_of_medians_s"]  # counted too, should a batch ever beat every single run
        f10 = free["10"]["sum_of_medians_s"]
        print(
            f"| 10 particles, unpinned ({parts['free']['cores']} cores, as the throughput table's sequential runs) "
            f"| - | {f10:.2f} | {f10:.2f} | {f10 / alone:.2f} |"
        )
        best, cores = min(per10, key=per10.get), parts["free"]["cores"]
        label = "the vmapped batch" if best == "batch" else f"{best} particles per run"
        print(
            f"\ncheapest per particle: {label}; {cores} cores at most divide that by {cores}, so no "
            f"batch of 10-particle runs can be more than {cores * alone / per10[best]:.2f}x faster than the same "
            f"runs one after another on one core, or {cores * f10 / per10[best]:.2f}x than the unpinned sequential runs"
        )
        print(
            "all sums [s]: "
            + "; ".join(
                f"{mode} {n} " + ", ".join(f"{x:.2f}" for x in r["sums_s"])
                for mode, part in parts.items()
                for n, r in part["runs"].items()
            ),
            flush=True,
        )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=2)


if __name__ == "__main__":
    main()
