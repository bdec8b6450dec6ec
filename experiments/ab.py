"""Two revisions of the code compared on the same runs, paired (A/B): speed and outputs.

    python experiments/ab.py HEAD~3                                # A = HEAD~3, B = the working tree
    python experiments/ab.py v0.4 main --particles 10 100 1000 --rounds 4
    python experiments/ab.py HEAD~1 --config configs/victoria_park_fastslam1.yaml --set data.t_end=300
    python experiments/ab.py v0.4 main --particles 10 100 --rounds 1 --compile-rounds 6   # first-run compile

Revision A (and B, when given) is checked out with ``git worktree add --detach`` into a temporary
directory; without B, B is the working tree as it stands. Each run is ``nanoslam run CONFIG --set
filter.n_particles=N`` in a fresh process whose ``PYTHONPATH`` is that tree, so any layout of the
package works, however it was refactored. Each tree has its own persistent compilation cache per
particle count (a temporary directory, empty at first): the first round compiles, later rounds
load. Rounds alternate the order (A B, B A, ...) so that a machine whose speed drifts slows both
alike. With ``--compile-rounds K`` the first-run compile is measured K times, each run starting
from an empty cache, also in alternating order.

The table gives, per particle count, the median run time of each revision (``run_s`` of
``metrics.json``: the filter after compilation), the ratio of the medians B / A and the median of
the per-round ratios, the median first-run compile time (``compile_s``) of each and the median of
the compile rounds' ratios B / A, and the largest difference between
the two revisions' trajectories and maps (``trajectory.csv`` to 1e-6, ``map.csv`` to 9 digits;
0 means identical outputs at that precision).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _worktree(rev: str, into: Path) -> Path:
    """A detached worktree of ``rev`` at ``into``."""
    subprocess.run(
        ["git", "-C", str(ROOT), "worktree", "add", "--detach", "--force", str(into), rev],
        check=True,
        capture_output=True,
        text=True,
    )
    return into


def _run(tree: Path, cache: Path, config: str, particles: int, extra: list[str], out: Path, data: str | None) -> dict:
    """One ``nanoslam run`` with ``tree``'s package; returns its metrics and outputs."""
    env = {**os.environ, "PYTHONPATH": str(tree), "NANOSLAM_CACHE_DIR": str(cache)}
    cmd = [
        sys.executable,
        "-P",  # no current directory first on sys.path: the package comes from PYTHONPATH, the tree
        "-m",
        "nanoslam_jax.app.cli" if (tree / "nanoslam_jax" / "app" / "cli.py").is_file() else "nanoslam_jax.cli",
        "run",
        str(tree / config),
        "--out",
        str(out),
        "--quiet",
        "--set",
        f"filter.n_particles={particles}",
        "--set",
        "output.plots=false",
        *extra,
    ]
    if data:
        cmd += ["--data", data]
    # run from the project root, where the default data directories are found
    res = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
    if res.returncode != 0:
        raise SystemExit(f"{tree}: `{' '.join(cmd)}` failed:\n{res.stderr[-3000:]}")
    metrics = json.loads((out / "metrics.json").read_text())
    traj = np.loadtxt(out / "trajectory.csv", delimiter=",", skiprows=1, ndmin=2)
    lm = out / "map.csv"
    landmarks = np.loadtxt(lm, delimiter=",", skiprows=1, ndmin=2) if lm.is_file() else np.zeros((0, 2))
    shutil.rmtree(out)
    return {
        "run_s": float(metrics["run_s"]),
        "compile_s": float(metrics.get("compile_s", np.nan)),
        "trajectory": traj[:, 1:4],
        "map": landmarks[:, :2],
    }


def _difference(a: np.ndarray, b: np.ndarray) -> float:
    if a.shape != b.shape:
        return float("inf")
    return float(np.max(np.abs(a - b), initial=0.0))


def _compile_rounds(trees: dict, first: dict, args: argparse.Namespace, n: int, extra: list[str], tmp: Path) -> dict:
    """First-run compile times of each tree: round 0's, then ``--compile-rounds - 1`` more runs, each
    from an empty cache, in alternating order (B A, A B, ...)."""
    compiles = {k: [first[k]["compile_s"]] for k in trees}
    for r in range(1, args.compile_rounds):
        for k in ("B", "A") if r % 2 == 1 else ("A", "B"):
            cache = tmp / f"fresh-{k}-{n}-{r}"
            res = _run(trees[k], cache, args.config, n, extra, tmp / f"out-{k}", args.data)
            compiles[k].append(res["compile_s"])
            shutil.rmtree(cache, ignore_errors=True)
    return compiles


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("a", help="revision A (anything `git worktree add` takes)")
    p.add_argument("b", nargs="?", help="revision B (default: the working tree)")
    p.add_argument("--config", default="configs/victoria_park_nano.yaml", help="the run config, relative to a tree")
    p.add_argument("--particles", type=int, nargs="+", default=[10, 100, 1000])
    p.add_argument("--rounds", type=int, default=3, help="timed runs of each revision per particle count")
    p.add_argument(
        "--compile-rounds", type=int, default=1, help="first runs from an empty cache per revision and particle count"
    )
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a config override for both")
    p.add_argument("--data", help="the log directory (--data of `nanoslam run`)")
    p.add_argument("--json", help="also write the table here")
    args = p.parse_args()
    if args.rounds < 1:
        p.error("--rounds: expected at least 1")
    if args.compile_rounds < 1:
        p.error("--compile-rounds: expected at least 1")
    extra = [x for kv in args.set for x in ("--set", kv)]
    with tempfile.TemporaryDirectory(prefix="nanoslam-ab-") as tmp_name:
        tmp = Path(tmp_name)
        trees = {"A": _worktree(args.a, tmp / "a"), "B": _worktree(args.b, tmp / "b") if args.b else ROOT}
        rows = []
        try:
            for n in args.particles:
                caches = {k: tmp / f"cache-{k}-{n}" for k in trees}
                times: dict[str, list[float]] = {"A": [], "B": []}
                first: dict[str, dict] = {}
                for r in range(args.rounds + 1):  # round 0 compiles (into each tree's cache) and is not timed
                    for k in ("A", "B") if r % 2 == 0 else ("B", "A"):
                        res = _run(trees[k], caches[k], args.config, n, extra, tmp / f"out-{k}", args.data)
                        if r == 0:
                            first[k] = res
                        else:
                            times[k].append(res["run_s"])
                compiles = _compile_rounds(trees, first, args, n, extra, tmp)
                a, b = np.array(times["A"]), np.array(times["B"])
                ca, cb = np.array(compiles["A"]), np.array(compiles["B"])
                row = {
                    "particles": n,
                    "a_run_s": float(np.median(a)),
                    "b_run_s": float(np.median(b)),
                    "ratio_of_medians": float(np.median(b) / np.median(a)),
                    "median_round_ratio": float(np.median(b / a)),
                    "a_compile_s": float(np.median(ca)),
                    "b_compile_s": float(np.median(cb)),
                    "compile_round_ratio": float(np.median(cb / ca)),
                    "trajectory_diff": _difference(first["A"]["trajectory"], first["B"]["trajectory"]),
                    "map_diff": _difference(first["A"]["map"], first["B"]["map"]),
                }
                rows.append(row)
                print(f"N={n}: A {row['a_run_s']:.2f} s, B {row['b_run_s']:.2f} s", file=sys.stderr, flush=True)
        finally:
            for k in ("A", "B"):
                if trees[k] != ROOT:
                    subprocess.run(
                        ["git", "-C", str(ROOT), "worktree", "remove", "--force", str(trees[k])], capture_output=True
                    )
    label_b = args.b or "working tree"
    print(
        f"A = {args.a}, B = {label_b}; {args.config}, {args.rounds} timed rounds and "
        f"{args.compile_rounds} compile rounds each, alternating\n"
    )
    print(
        "| particles | A run (s) | B run (s) | B / A (medians) | B / A (median of rounds) | A compile (s) "
        "| B compile (s) | compile B / A (median of rounds) | largest difference: trajectory, map |"
    )
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---|")
    for row in rows:
        print(
            f"| {row['particles']} | {row['a_run_s']:.2f} | {row['b_run_s']:.2f} | {row['ratio_of_medians']:.3f} "
            f"| {row['median_round_ratio']:.3f} | {row['a_compile_s']:.1f} | {row['b_compile_s']:.1f} "
            f"| {row['compile_round_ratio']:.3f} "
            f"| {row['trajectory_diff']:.3g}, {row['map_diff']:.3g} |"
        )
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
