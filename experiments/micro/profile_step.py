"""Where a filter step's time goes: the XLA operations of a mid-log stretch, summed by source.

Runs the config over the scans before ``--start`` (not timed), compiles the filter's scan over
the stretch ``--start`` .. ``--start + --scans`` from that state, calls it once to warm up, then
once under ``jax.profiler.trace``; every XLA operation the trace records (leaf operations only:
loops and conditionals are not counted twice) is attributed to the project function its
HLO metadata names (the innermost frame in ``nanoslam_jax``), and to its ``op_name`` path
(which loop, branch and ``vmap`` it runs in: ``cond/branch_k_fun/while/body`` below the particles'
``vmap`` is an iterative proposal inside the row-bucket switch). Prints both tables. With
``--callers``, an operation of a small helper (matrix algebra, trigonometry, the models) is named
by its call chain up to the function that called it, and a third table adds the helpers' time
to those calling functions.

    python experiments/micro/profile_step.py --particles 1000 --start 1500 --scans 100
    python experiments/micro/profile_step.py --particles 10 --set filter.method=ufastslam --top 15
    python experiments/micro/profile_step.py --particles 1000 --callers   # helpers by their callers

One device (``filter.split_devices: never``), so the table is the step's work, not the
devices' overlap. The trace and the compiled HLO stay in ``--keep DIR`` when given.
"""

from __future__ import annotations

import argparse
import collections
import glob
import gzip
import json
import os
import re
import tempfile
import time

#: Trace events that contain other events (not counted, so nothing is counted twice).
_CONTAINERS = ("cond", "while", "call", "ThunkExecutor", "$")


def _sections(hlo: list[str]) -> dict[str, dict[int, str]]:
    """The numbered tables at the head of an HLO module's text (FileNames, FunctionNames,
    FileLocations, StackFrames)."""
    out = {}
    for name in ("FileNames", "FunctionNames", "FileLocations", "StackFrames"):
        if name not in hlo:
            continue
        table = {}
        for line in hlo[hlo.index(name) + 1 :]:
            m = re.match(r"^(\d+) (.*)$", line)
            if not m:
                break
            table[int(m.group(1))] = m.group(2)
        out[name] = table
    return out


#: Project modules of small helpers (matrix algebra, trigonometry, the models): with
#: ``--callers`` an operation in one of them is also attributed to the function that called it.
_HELPERS = ("_linalg.py", "_trig.py", "models/")


def _attribution(hlo_text: str, callers: bool = False) -> tuple[dict[str, str], dict[str, str]]:
    """Each HLO instruction's project function (``file:function``) and ``op_name`` path.

    With ``callers``, an instruction whose innermost project frame is a helper (:data:`_HELPERS`)
    is named by the chain of frames up to the first one outside them, innermost first
    (``_linalg.py:mm < proposals/_natural_gradient.py:expected_grad_hess.<locals>.at_point``).
    Call chains are only complete when the program was traced with
    ``JAX_TRACEBACK_IN_LOCATIONS_LIMIT=-1`` (``main`` sets it).
    """
    lines = hlo_text.split("\n")
    t = _sections(lines)
    files = {k: v.strip('"') for k, v in t.get("FileNames", {}).items()}
    funcs = {k: v.strip('"') for k, v in t.get("FunctionNames", {}).items()}
    locs = {}
    for k, v in t.get("FileLocations", {}).items():
        d = dict(re.findall(r"(\w+)=(\d+)", v))
        path = files.get(int(d["file_name_id"]), "?")
        locs[k] = (
            path.split("nanoslam_jax/")[-1] if "nanoslam_jax/" in path else None,
            funcs.get(int(d["function_name_id"]), "?"),
        )
    frames = {k: dict(re.findall(r"(\w+)=(\d+)", v)) for k, v in t.get("StackFrames", {}).items()}
    where, path = {}, {}
    for line in lines:
        m = re.match(r"^\s*(?:ROOT )?%?([\w.\-]+) = ", line)
        if not m:
            continue
        name = m.group(1)
        op = re.search(r'op_name="([^"]+)"', line)
        if op:
            path[name] = "/".join(op.group(1).split("/")[1:-1]) or "(top level)"
        fid = re.search(r"stack_frame_id=(\d+)", line)
        fid = int(fid.group(1)) if fid else None
        chain, seen = [], set()
        while fid in frames and fid not in seen:  # innermost frame first, then its callers
            seen.add(fid)
            file, func = locs.get(int(frames[fid]["file_location_id"]), (None, "?"))
            if file is not None:
                chain.append(f"{file}:{func}")
                if not callers or not file.startswith(_HELPERS):
                    break
            # The printed parent is one past the parent's row (0: no parent).
            fid = int(frames[fid].get("parent_frame_id", 0)) - 1
        if chain:
            # Consecutive frames of one function (a helper calling itself on parts) named once.
            where[name] = " < ".join(f for i, f in enumerate(chain) if i == 0 or f != chain[i - 1])
    return where, path


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", default="configs/victoria_park_nano.yaml")
    p.add_argument("--data", help="log directory")
    p.add_argument("--particles", type=int, default=1000)
    p.add_argument("--set", dest="overrides", action="append", default=[], help="config override key=value")
    p.add_argument("--start", type=int, default=1500, help="first scan of the profiled stretch")
    p.add_argument("--scans", type=int, default=100, help="scans in the profiled stretch")
    p.add_argument("--top", type=int, default=25, help="rows per table")
    p.add_argument("--keep", help="keep the trace and hlo.txt in this directory")
    p.add_argument(
        "--callers",
        action="store_true",
        help="name an operation of a small helper (matrix algebra, trigonometry, the models) "
        "by its call chain up to the project function that called it",
    )
    args = p.parse_args()
    if args.start < 1:
        p.error("--start: at least 1 (the stretch starts from the state a run over the scans before it reached)")

    # Whole call chains in the HLO metadata (JAX keeps the innermost 10 frames by default,
    # mostly its own); must be set before JAX is imported.
    os.environ.setdefault("JAX_TRACEBACK_IN_LOCATIONS_LIMIT", "-1")
    import jax

    jax.config.update("jax_enable_x64", True)  # the library computes in float64
    from nanoslam_jax.app.config import load_config
    from nanoslam_jax.app.experiment import load_log
    from nanoslam_jax.methods import run_filter
    from nanoslam_jax.app.filters import settings_from_config
    from nanoslam_jax.methods._scan import filter_scan

    cfg = load_config(
        args.config, [f"filter.n_particles={args.particles}", "filter.split_devices=never", *args.overrides]
    )
    seg = load_log(cfg, args.data).segments
    static, params = settings_from_config(cfg, seg.k_max)
    part = lambda a, b: type(seg)(*(x[a:b] for x in seg))  # noqa: E731
    state = run_filter(static, params, part(0, args.start), 0, chunk=args.start).state  # the stretch's start
    stretch = jax.tree.map(jax.numpy.asarray, part(args.start, args.start + args.scans))
    valid = jax.numpy.ones(stretch.time.shape[0], bool)
    program = (
        jax.jit(lambda pr, st, sg, v: filter_scan(static, pr, sg, None, st, v))
        .lower(params, state, stretch, valid)
        .compile()
    )
    jax.block_until_ready(program(params, state, stretch, valid))
    out = args.keep or tempfile.mkdtemp(prefix="nanoslam_profile_")
    os.makedirs(out, exist_ok=True)
    hlo = program.as_text()
    with open(os.path.join(out, "hlo.txt"), "w") as f:
        f.write(hlo)
    t0 = time.perf_counter()
    with jax.profiler.trace(os.path.join(out, "trace"), create_perfetto_trace=True):
        jax.block_until_ready(program(params, state, stretch, valid))
    wall = time.perf_counter() - t0

    trace = sorted(glob.glob(os.path.join(out, "trace", "**", "perfetto_trace.json.gz"), recursive=True))[-1]
    with gzip.open(trace) as f:
        events = json.load(f)
    events = events["traceEvents"] if isinstance(events, dict) else events
    where, path = _attribution(hlo, args.callers)
    by_where, by_path, by_caller, total = collections.Counter(), collections.Counter(), collections.Counter(), 0.0
    for e in events:
        name = e.get("name", "")
        if e.get("ph") != "X" or name.startswith(_CONTAINERS) or " " in name:
            continue
        d = e.get("dur", 0) / 1e3
        total += d
        by_where[where.get(name, "(no source)")] += d
        by_caller[where.get(name, "(no source)").split(" < ")[-1]] += d
        by_path[path.get(name, "(no op_name)")] += d

    print(
        f"\n{cfg.name}: {static.method.name}, {args.particles} particles, scans {args.start}-{args.start + args.scans}, "
        f"one device: {wall:.2f} s under the profiler, {total:.0f} ms in leaf operations\n"
    )
    tables = [("project function", by_where), ("op_name path", by_path)]
    if args.callers:  # the helpers' time added to the functions that called them
        tables.insert(1, ("calling function", by_caller))
    for title, table in tables:
        print(f"| {title} | ms | share |\n|---|---|---|")
        for k, v in table.most_common(args.top):
            print(f"| `{k}` | {v:.1f} | {100 * v / total:.1f} % |")
        print()
    if args.keep:
        print(f"trace and hlo.txt in {out}")


if __name__ == "__main__":
    main()
