"""NASRUKF with per-beam features on simulated indoor logs: what bounds its open targets
(docs/method/nasrukf-beams-results.md).

    .venv/bin/python experiments/nasrukf_bounds.py noise [--seeds 100-115] [--duration 60] [--slip 0.2]
    .venv/bin/python experiments/nasrukf_bounds.py random-walk [--seeds 200-203] [--duration 20]
        [--sigma-xy 0.05,0.3] [--sigma-phi 5,20,80]
    .venv/bin/python experiments/nasrukf_bounds.py table A.json[:LABEL] B.json[:LABEL]   # merged summary

``noise``: the bound of "adaptive better than non-adaptive with the process noise wrong by 3x".
No adaptive scheme can beat knowing the process noise, so for every seed ``s`` (``seed =
indoor.seed = s``) the config runs with the odometry noise configured

* 3 times too small (``small``: ``sigma_v`` 1/3 cm/s, ``sigma_omega`` 1/3 deg/s), adaptive and not;
* right (``oracle``: the simulator's 1 cm/s, 1 deg/s outside slip; exact with ``--slip 0``);
* right on average over slip (``oracle-rms``: the root mean square over the expected fraction of
  slip, ``sqrt(1 - f + f k^2)`` times that; only with slip);
* 3 times too large (``large``), adaptive and not.

Adaptive: ``noise.adaptive`` and ``nasrukf.adaptive_process`` (the config); non-adaptive: both off.
``--slip F`` sets ``indoor.slip_fraction`` (0: none; the simulator's default 0.2, episodes with
the odometry noise 5 times larger). Prints a row per seed (position RMSE cm / heading RMSE deg of
every variant, the adaptive runs' process-noise ratios), the medians, and the paired fractions of
seeds where one variant beats another. ``--json FILE`` also writes every run's metrics.

``random-walk``: ``model.motion: random_walk`` (no odometry) over a grid of its ``sigma_xy`` and
``sigma_phi_deg`` on tuning seeds, with the adaptive filter, and the odometry run for reference:
position and heading RMSE, and the largest heading error and where it occurs (turn rate there).
"""

from __future__ import annotations

import argparse
import json
import math
import time

import numpy as np

from _seeds import format_seeds, parse_seeds

from nanoslam_jax.app.config import load_config
from nanoslam_jax.app.experiment import execute
import jax

jax.config.update("jax_enable_x64", True)  # the library computes in float64

CONFIG = "configs/nasrukf_indoor.yaml"
#: The simulator's odometry noise outside slip: sigma_v (m/s), sigma_omega (deg/s), and the slip factor.
SIM_SIGMA_V, SIM_SIGMA_OMEGA_DEG, SLIP_FACTOR = 0.01, 1.0, 5.0
NON_ADAPTIVE = ["noise.adaptive=false", "nasrukf.adaptive_process=false"]


def _odometry(scale: float) -> list[str]:
    return [f"unicycle.sigma_v={SIM_SIGMA_V * scale}", f"unicycle.sigma_omega_deg={SIM_SIGMA_OMEGA_DEG * scale}"]


def noise_variants(slip: float) -> dict[str, list[str]]:
    """The variants of the ``noise`` study: name -> config overrides."""
    v = {
        "adaptive small": _odometry(1 / 3),
        "fixed small": [*_odometry(1 / 3), *NON_ADAPTIVE],
        "oracle": [*_odometry(1.0), *NON_ADAPTIVE],
    }
    if slip > 0:
        v["oracle-rms"] = [*_odometry(math.sqrt(1 - slip + slip * SLIP_FACTOR**2)), *NON_ADAPTIVE]
    v["adaptive large"] = _odometry(3.0)
    v["fixed large"] = [*_odometry(3.0), *NON_ADAPTIVE]
    return v


def run_one(sets: list[str]) -> dict:
    """One run of the config with ``sets``: its metrics (``ok`` False and ``error`` if it failed)."""
    cfg = load_config(CONFIG, [*sets, "output.progress=false"])
    t0 = time.perf_counter()
    try:
        res = execute(cfg, progress=False)
        m = {k: v for k, v in res.metrics.items() if isinstance(v, (int, float, str, bool))}
        m["ok"] = bool(m.get("finite"))
        err = _heading_errors(res)
        if err is not None:
            m["heading_max_deg"], m["heading_max_t"] = err
    except Exception as e:  # a failed run is reported, never dropped
        m = {"ok": False, "error": f"{type(e).__name__}: {e}"}
    m["wall_s"] = time.perf_counter() - t0
    return m


def _heading_errors(res) -> tuple[float, float] | None:
    """The largest heading error of a run (deg) and its time (s)."""
    from nanoslam_jax.eval.metrics import heading_errors

    truth = res.log.raw.truth_poses
    if truth is None or not np.all(np.isfinite(res.trajectory)):
        return None
    t, e = heading_errors(res.times, res.trajectory[:, 2], truth)
    i = int(np.argmax(np.abs(e)))
    return float(np.abs(e[i])), float(np.asarray(t)[i])


def _cell(m: dict, key: str, scale: float, digits: int) -> str:
    return f"{m[key] * scale:.{digits}f}" if m.get("ok") and key in m else "fail"


def _value(m: dict, key: str) -> float:
    return float(m[key]) if m.get("ok") and key in m else math.inf


def summary(runs: dict[str, list[dict]]) -> None:
    """Median position / heading RMSE of each variant (and the worst), and each adaptive run and
    the oracles against the fixed runs, paired over the seeds (a failed run counts as infinite)."""
    names = list(runs)
    print("\n| variant | position RMSE (cm), median [worst] | heading RMSE (deg), median [worst] | runs |")
    print("|---|---:|---:|---:|")
    for n in names:
        p = np.array([_value(m, "rmse_fixed") for m in runs[n]]) * 100
        h = np.array([_value(m, "rmse_heading_deg") for m in runs[n]])
        print(f"| {n} | {np.median(p):.2f} [{p.max():.2f}] | {np.median(h):.3f} [{h.max():.3f}] | {len(p)} |")
    base = {n.split(" (")[0]: n for n in reversed(names)}  # a variant's name without its file's label
    pairs = []
    for a in names:
        if a.startswith("adaptive"):
            pairs += [(a, "fixed small" if "small" in a else "fixed large"), (a, "oracle")]
        elif a.startswith("oracle"):
            pairs += [(a, "fixed small"), (a, "fixed large")]
    pairs = [(a, base[b]) for a, b in pairs if b in base]
    print("\n| paired over seeds | better on position | better on heading | median position ratio |")
    print("|---|---:|---:|---:|")
    for a, b in pairs:
        if [m["seed"] for m in runs[a]] != [m["seed"] for m in runs[b]]:
            continue
        pa, pb = (np.array([_value(m, "rmse_fixed") for m in runs[x]]) for x in (a, b))
        ha, hb = (np.array([_value(m, "rmse_heading_deg") for m in runs[x]]) for x in (a, b))
        k = len(pa)
        print(
            f"| {a} vs {b} | {int(np.sum(pa < pb))}/{k} ({100 * np.mean(pa < pb):.0f} %) | "
            f"{int(np.sum(ha < hb))}/{k} ({100 * np.mean(ha < hb):.0f} %) | {np.median(pa / pb):.2f} |"
        )


def noise_study(args) -> dict:
    seeds = args.seeds
    variants = noise_variants(args.slip)
    if args.variants:
        variants = {k: variants[k] for k in args.variants.split(",")}
    common = [f"indoor.duration={args.duration}", f"indoor.slip_fraction={args.slip}", *args.set]
    runs: dict[str, list[dict]] = {v: [] for v in variants}
    names = list(variants)
    print(f"position RMSE (cm) / heading RMSE (deg); slip fraction {args.slip}, {args.duration:.0f} s logs\n")
    print("| seed | " + " | ".join(names) + " | Q ratio (v, omega), adaptive small | ... large |")
    print("|---|" + "---:|" * len(names) + "---|---|")
    for s in seeds:
        for name in names:
            m = run_one([*common, *variants[name], f"seed={s}", f"indoor.seed={s}"])
            m["seed"] = s
            runs[name].append(m)
        q = [
            f"{_cell(runs[a][-1], 'process_noise_ratio_0', 1, 2)}, {_cell(runs[a][-1], 'process_noise_ratio_1', 1, 2)}"
            if a in runs
            else "-"
            for a in ("adaptive small", "adaptive large")
        ]
        cells = [
            f"{_cell(runs[n][-1], 'rmse_fixed', 100, 2)} / {_cell(runs[n][-1], 'rmse_heading_deg', 1, 3)}"
            for n in names
        ]
        print(f"| {s} | " + " | ".join(cells) + f" | {q[0]} | {q[1]} |", flush=True)
    summary(runs)
    return runs


def random_walk_study(args) -> dict:
    seeds = args.seeds
    xs = [float(v) for v in args.sigma_xy.split(",")]
    ps = [float(v) for v in args.sigma_phi.split(",")]
    common = [f"indoor.duration={args.duration}", *args.set]
    variants: dict[str, list[str]] = {"unicycle (odometry)": []}
    for sx in xs:
        for sp in ps:
            variants[f"random_walk {sx:g} m/sqrt(s), {sp:g} deg/sqrt(s)"] = [
                "model.motion=random_walk",
                f"random_walk.sigma_xy={sx}",
                f"random_walk.sigma_phi_deg={sp}",
            ]
    runs: dict[str, list[dict]] = {v: [] for v in variants}
    print(
        f"{args.duration:.0f} s logs, seeds {format_seeds(args.seeds)}; position RMSE (cm) / heading RMSE (deg) / largest heading"
    )
    print("error (deg) at t (s)\n")
    print("| variant | " + " | ".join(str(s) for s in seeds) + " |")
    print("|---|" + "---:|" * len(seeds))
    for name, sets in variants.items():
        cells = []
        for s in seeds:
            m = run_one([*common, *sets, f"seed={s}", f"indoor.seed={s}"])
            m["seed"] = s
            runs[name].append(m)
            cells.append(
                f"{_cell(m, 'rmse_fixed', 100, 1)} / {_cell(m, 'rmse_heading_deg', 1, 2)} / "
                f"{_cell(m, 'heading_max_deg', 1, 1)} at {_cell(m, 'heading_max_t', 1, 1)}"
            )
        print(f"| {name} | " + " | ".join(cells) + " |", flush=True)
    return runs


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="study", required=True)
    n = sub.add_parser("noise", help="adaptive, wrong and right process noise, paired over seeds")
    n.add_argument("--seeds", type=parse_seeds, default="100-115")
    n.add_argument("--duration", type=float, default=60.0)
    n.add_argument("--slip", type=float, default=0.2, help="indoor.slip_fraction (0: no slip)")
    n.add_argument("--variants", help="comma-separated subset of the variants (default: all)")
    r = sub.add_parser("random-walk", help="model.motion random_walk over its sigmas on tuning seeds")
    r.add_argument("--seeds", type=parse_seeds, default="200-203")
    r.add_argument("--duration", type=float, default=20.0)
    r.add_argument("--sigma-xy", default="0.05,0.3")
    r.add_argument("--sigma-phi", default="5,20,80")
    for p in (n, r):
        p.add_argument("--set", action="append", default=[], help="config override key=value")
        p.add_argument("--json", help="write every run's metrics to this file")
    t = sub.add_parser("table", help="the summary of noise studies' --json files, their variants merged")
    t.add_argument("files", nargs="+", metavar="FILE[:LABEL]", help="LABEL is appended to the file's variant names")
    args = ap.parse_args(argv)
    if args.study == "table":
        merged: dict[str, list[dict]] = {}
        for spec in args.files:
            path, _, label = spec.partition(":")
            with open(path) as f:
                merged.update({f"{k} ({label})" if label else k: v for k, v in json.load(f).items()})
        summary(merged)
        return 0
    runs = noise_study(args) if args.study == "noise" else random_walk_study(args)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(runs, f, indent=1, default=str)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
