"""Two settings of the filter step compared back to back in one process (A/B).

On a machine whose speed drifts (a shared VM), two separate benchmark runs can differ by more
than the change being measured. Here both programs are compiled in one process and called
alternately over the same mid-log stretch from the same filter state, so a slow period hits
both; the table gives the minimum and the median of the repeats, and the ratio B / A of each round
(A and B called back to back) with a sign test over the rounds: on this VM a change of less
than about 5 % shows only there, if at all.

    python experiments/micro/ab_step.py --particles 1000 --b filter.row_buckets=always --a filter.row_buckets=never
    python experiments/micro/ab_step.py --particles 100 --b filter.split_devices=always --a filter.split_devices=never \
        --devices 2 --start 1000 --scans 300 --repeat 5
    python experiments/micro/ab_step.py --particles 1000 --a-rev HEAD~1 --start 1500 --scans 200 --repeat 6

``--start 0`` times the log from its first scan (the state a run starts from, seed 0); any other
start runs setting A's config over the scans before it first (below).

``--a-rev REV`` compares code instead of settings: setting A runs the filter step of git revision
REV (its ``filter/_step.py``, ``_rows.py`` where it has one, ``_prior.py``, ``_landmarks.py``,
``_management.py``, ``_association.py`` and ``_state.py``; the rest of the package is the working
tree's), setting B the working tree's. A starts from the same state, converted field by field to
the revision's state types (``NamedTuple``s; a revision whose state has other fields needs its own
conversion in :func:`state_for`). The state at ``--start`` comes from running setting A's config over
the scans before it (on one device, working tree). The largest difference between the two
programs' outputs (final state and per-scan records) is printed too, and again with the final
maps' inactive slots ignored (what an inactive slot holds is never read, so a change that leaves
them differently is still exact), with the number of resamplings in the stretch.
"""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import subprocess
import sys
import time
import types


def step_at_revision(rev: str):
    """``filter_step`` of git revision ``rev`` and the revision's ``_state`` module: its filter
    step, row work, prior, landmark, management, association and state modules loaded under other
    names, everything else the working tree's."""
    import nanoslam_jax.filter  # noqa: F401  (the package the modules' relative imports resolve in)

    mods = {"_state": "_ab_state", "_prior": "_ab_prior", "_landmarks": "_ab_landmarks",
            "_association": "_ab_association", "_management": "_ab_management", "_rows": "_ab_rows",
            "_step": "_ab_step"}
    sources = {}
    for name in mods:
        path = f"nanoslam_jax/filter/{name}.py"
        shown = subprocess.run(["git", "show", f"{rev}:{path}"], capture_output=True, text=True)
        if shown.returncode == 0:
            sources[name] = shown.stdout
        elif name != "_rows":  # the row work has its own module since the split of _step.py
            raise SystemExit(f"--a-rev {rev}: git show {rev}:{path} failed: {shown.stderr.strip()}")
    mods = {name: alias for name, alias in mods.items() if name in sources}
    for name, alias in mods.items():
        path = f"nanoslam_jax/filter/{name}.py"
        src = sources[name]
        for other, other_alias in mods.items():
            src = src.replace(f"from .{other} import", f"from .{other_alias} import")
        module = types.ModuleType(f"nanoslam_jax.filter.{alias}")
        module.__package__ = "nanoslam_jax.filter"
        sys.modules[module.__name__] = module
        exec(compile(src, f"{rev}:{path}", "exec"), module.__dict__)
    return sys.modules["nanoslam_jax.filter._ab_step"].filter_step, sys.modules["nanoslam_jax.filter._ab_state"]


def state_for(state_module, state):
    """``state`` (the working tree's types) as the filter state of ``state_module`` (a revision's
    ``_state``), field by field."""
    lm = state_module.LandmarkMap(**state.particles.landmarks._asdict())
    particles = state_module.Particles(**state.particles._replace(landmarks=lm)._asdict())
    return state_module.FilterState(**state._replace(particles=particles)._asdict())


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
    p.add_argument("--a-rev", help="setting A runs the filter step of this git revision (see above)")
    args = p.parse_args()

    import jax
    import jax.numpy as jnp

    if args.devices > 1:
        jax.config.update("jax_num_cpu_devices", args.devices)
    import numpy as np
    from scipy.stats import binomtest

    import nanoslam_jax  # noqa: F401  (float64)
    from nanoslam_jax.config import load_config
    from nanoslam_jax.experiment import load_log
    from nanoslam_jax.filter import (LandmarkMap, filter_step, initial_state, make_proposal, run_filter,
                                     settings_from_config)
    from nanoslam_jax.filter._scan import segment_priors

    base = [f"filter.n_particles={args.particles}"]
    cfgs = {k: load_config(args.config, base + list(v)) for k, v in (("A", args.a), ("B", args.b))}
    seg = load_log(cfgs["A"], args.data).segments
    settings = {k: settings_from_config(c, seg.k_max) for k, c in cfgs.items()}
    n = seg.time.shape[0]
    if not (0 <= args.start and 1 <= args.scans and args.start + args.scans <= n):
        raise SystemExit(f"--start {args.start} --scans {args.scans}: the stretch must lie in the log's {n} "
                         f"segments (--start at least 0, --scans at least 1, --start + --scans at most {n})")
    static_a, params_a = settings["A"]
    static_1 = dataclasses.replace(static_a, devices=1)
    if args.start == 0:  # the state run_filter starts from (seed 0)
        state = initial_state(static_1, params_a, jax.random.key(0))
    else:
        before = type(seg)(*(a[:args.start] for a in seg))
        state = run_filter(static_1, params_a, before, 0, chunk=args.start).state
    stretch = jax.tree.map(jax.numpy.asarray, type(seg)(*(a[args.start:args.start + args.scans] for a in seg)))

    steps, starts = {"A": filter_step, "B": filter_step}, {"A": state, "B": state}
    if args.a_rev:
        steps["A"], state_module = step_at_revision(args.a_rev)
        starts["A"] = state_for(state_module, state)
    programs, outputs = {}, {}
    for k, (static, params) in settings.items():
        proposal = make_proposal(static, params)

        def scan(st, sg, pr, static=static, proposal=proposal, step=steps[k]):
            # A step that takes the segments' shared priors gets them computed before the scan,
            # as filter_scan does (revisions before f7f1244 propagate the prior in the step).
            if "rel_prior" in inspect.signature(step).parameters:
                rel = segment_priors(static, pr, sg)
                return jax.lax.scan(lambda c, x: step(static, pr, proposal, c, x[0], True, x[1]), st, (sg, rel))
            return jax.lax.scan(lambda c, x: step(static, pr, proposal, c, x), st, sg)

        t0 = time.perf_counter()
        programs[k] = jax.jit(scan).lower(starts[k], stretch, params).compile()
        print(f"{k}: compiled in {time.perf_counter() - t0:.1f} s ({static.row_buckets=}, {static.devices=})", flush=True)
        outputs[k] = jax.block_until_ready(programs[k](starts[k], stretch, params))

    def largest_difference(outs) -> float:
        diffs = [float(np.max(np.abs(np.asarray(a, float) - np.asarray(b, float)), initial=0.0))
                 for a, b in zip(*(jax.tree.leaves(o) for o in outs))
                 if not jax.dtypes.issubdtype(a.dtype, jax.dtypes.prng_key)]
        return max(diffs)

    def active_slots_only(out):
        # The final maps with every inactive slot set to the empty map's values: what an inactive
        # slot holds is never read (a landmark placed in it writes every field).
        # The maps as dicts of their fields: A's and B's map types are different classes.
        final, records = out
        lm = final.particles.landmarks
        empty = LandmarkMap.empty(lm.active.shape[-1], lm.active.shape[:-1])._asdict()
        keep = lambda a, e: jnp.where(lm.active.reshape(lm.active.shape + (1,) * (a.ndim - lm.active.ndim)), a, e)  # noqa: E731
        maps = {f: keep(a, empty[f]) for f, a in lm._asdict().items()}
        return final._replace(particles=final.particles._replace(landmarks=None)), maps, records

    # A's and B's states are NamedTuples of the same fields (state_for): their leaves line up.
    whole = largest_difference(list(outputs.values()))
    print(f"largest difference between the outputs of A and B: {whole:.3g} "
          f"(inactive map slots ignored: "
          f"{largest_difference([active_slots_only(o) for o in outputs.values()]):.3g})")

    print(f"resamplings in the stretch: {int(np.sum(outputs['B'][1].resampled))}")

    times = {k: [] for k in programs}
    for _ in range(args.repeat):
        for k, prog in programs.items():
            t0 = time.perf_counter()
            jax.block_until_ready(prog(starts[k], stretch, settings[k][1]))
            times[k].append(1e3 * (time.perf_counter() - t0) / args.scans)

    print(f"\n{args.particles} particles, scans {args.start}-{args.start + args.scans}, {args.repeat} alternated repeats\n")
    print("| setting | overrides | min ms/scan | median ms/scan | all |")
    print("|---|---|---|---|---|")
    for k, v in times.items():
        over = " ".join(args.a if k == "A" else args.b) or "(config)"
        print(f"| {k} | {over} | {min(v):.3f} | {float(np.median(v)):.3f} | {' / '.join(f'{x:.2f}' for x in v)} |")
    # Paired by round (A then B, back to back): the drift between rounds cancels in each ratio.
    ratio = np.asarray(times["B"]) / np.asarray(times["A"])
    # The sign test counts only the rounds that differ (a tie favours neither setting).
    faster, slower = int(np.sum(ratio < 1.0)), int(np.sum(ratio > 1.0))
    p = f"{binomtest(faster, faster + slower).pvalue:.2g}" if faster + slower else "n/a (all rounds tied)"
    print(f"\nB / A per round: median {float(np.median(ratio)):.3f}, range {ratio.min():.3f}-{ratio.max():.3f}; "
          f"B faster in {faster}, slower in {slower} of {len(ratio)} rounds (two-sided sign test p = {p})")


if __name__ == "__main__":
    main()
