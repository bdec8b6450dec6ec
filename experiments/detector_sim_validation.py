"""Validation of the tree detector on simulated raw scans against their truth (docs/simulate_laser.md).

    .venv/bin/python experiments/detector_sim_validation.py [--seeds 100-107] [--duration 240]
        [--config CONFIG] [--set detector.key=value ...] [--set sim.key=value ...]

For every seed, a simulated log with raw scans (:func:`nanoslam_jax.sim.laser.simulate_laser`:
trees, walls, fences and bushes, with the sim section's range noise, dropouts and spurious returns)
goes through the detector (:func:`nanoslam_jax.frontend.detect_trees`, the config's detector section)
and through a naive baseline (clusters by range jumps, diameter from the angular width). Printed per
seed and pooled:

* recall: the share of trees hit by 3 or more beams with the centre within 30 m that a detection
  matches (within 0.5 m in range and 1.5 deg in bearing of the centre; one-to-one per scan, nearest
  first, against every tree the scan hit); and the same over those of them wholly inside the field of
  view (the edge of the fan does not cut their outline);
* precision: the share of detections within 30 m that match a tree;
* the median absolute diameter error of the matched detections within 30 m, and of the targets found;
* what the false detections lie on (the object the beam at their bearing returned from) and why the
  missed trees were missed (occluded, at the edge of the field of view, beside other returns).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "experiments"))

from _seeds import parse_seeds  # noqa: E402
from detector_validation import match  # noqa: E402

from nanoslam_jax.app.config import load_config  # noqa: E402
from nanoslam_jax.data import LaserScans  # noqa: E402
from nanoslam_jax.frontend import detect_trees  # noqa: E402
from nanoslam_jax.sim.laser import KIND_BUSH, KIND_FENCE, KIND_TREE, KIND_WALL, simulate_laser  # noqa: E402
import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)  # the library computes in float64

WITHIN, MIN_BEAMS = 30.0, 3
FALSE_KINDS = ("tree (centre off)", "wall", "fence", "bush", "no surface: a spurious return")
MISS_KINDS = (
    "occluded (fewer beams hit than cross it)",
    "at the edge of the field of view",
    "another return within 2 m of its surface",
    "3-5 beams",
    "other",
)


def naive_trees(scans: LaserScans, jump: float = 0.3, max_diameter: float = 1.2) -> np.ndarray:
    """The naive baseline: a cluster is a run of returns with range steps below ``jump`` (m); a tree is a
    cluster of 2 or more returns whose angular width times its mean range is at most ``max_diameter``.

    Returns:
        ``(M, 4)`` rows ``time, range to the centre, bearing, diameter``.
    """
    r, a = scans.ranges, scans.angles
    n_s, n_b = r.shape
    valid = r < scans.max_range
    step = np.abs(np.diff(r, axis=1)) > jump
    brk = np.ones((n_s, n_b), bool)  # a beam starts a new cluster
    brk[:, 1:] = step | ~valid[:, 1:] | ~valid[:, :-1]
    label = np.cumsum(brk.ravel()) - 1
    v = valid.ravel()
    lab, rr = label[v], r.ravel()[v]
    aa = np.broadcast_to(a, (n_s, n_b)).ravel()[v]
    ss = np.repeat(np.arange(n_s), n_b)[v]
    uniq, first, count = np.unique(lab, return_index=True, return_counts=True)
    mean_r = np.bincount(np.searchsorted(uniq, lab), rr) / count
    min_r = np.minimum.reduceat(rr, first)
    mean_a = np.bincount(np.searchsorted(uniq, lab), aa) / count
    width = count * (a[1] - a[0]) * mean_r
    keep = (count >= 2) & (width <= max_diameter)
    return np.stack([scans.time[ss[first]][keep], (min_r + width / 2)[keep], mean_a[keep], width[keep]], axis=1)


def evaluate(log, det: np.ndarray) -> dict:
    """Recall, precision, diameter error and failure modes of detections ``det`` on a simulated log."""
    truth = log.truth
    seen = truth[:, 2] >= 1
    ref = truth[seen][:, [0, 4, 5, 6]]
    rows = np.flatnonzero(seen)
    ri, dj = match(ref, det)
    target = (truth[:, 2] >= MIN_BEAMS) & (truth[:, 4] <= WITHIN)
    half_width = np.arcsin(np.minimum(truth[:, 6] / 2 / truth[:, 4], 1.0))
    in_view = np.abs(truth[:, 5]) + half_width <= log.scans.angles[-1]
    found = np.zeros(truth.shape[0], bool)
    found[rows[ri]] = True
    used = np.zeros(det.shape[0], bool)
    used[dj] = True
    near = det[:, 1] <= WITHIN
    dd = np.abs(det[dj, 3] - ref[ri, 3])[near[dj]]
    dd_range = ref[ri, 1][near[dj]]
    dd_target = np.abs(det[dj, 3] - ref[ri, 3])[target[rows[ri]]]

    scans = log.scans
    s_of = np.searchsorted(scans.time, det[:, 0])
    # false detections: what the beam at the detection's bearing returned from
    false = np.flatnonzero(near & ~used)
    da = scans.angles[1] - scans.angles[0]
    beam = np.clip(np.round((det[false, 2] - scans.angles[0]) / da).astype(int), 0, scans.n_beams - 1)
    k = log.kind[s_of[false], beam]
    false_kind = np.select([k == KIND_TREE, k == KIND_WALL, k == KIND_FENCE, k == KIND_BUSH], [0, 1, 2, 3], 4)
    # missed trees
    missed = np.flatnonzero(target & ~found)
    ms = np.searchsorted(scans.time, truth[missed, 0])
    half_fov = scans.angles[-1]
    edge = np.abs(truth[missed, 5]) > half_fov - np.deg2rad(3.0)
    occl = truth[missed, 2] < truth[missed, 3]
    # another return (not of this tree) within 2 m of the trunk's surface
    xs = scans.ranges[ms] * np.cos(scans.angles)[None]
    ys = scans.ranges[ms] * np.sin(scans.angles)[None]
    cx = truth[missed, 4] * np.cos(truth[missed, 5])
    cy = truth[missed, 4] * np.sin(truth[missed, 5])
    other = ~((log.kind[ms] == KIND_TREE) & (log.object_id[ms] == truth[missed, 1:2].astype(int)))
    gap = np.hypot(xs - cx[:, None], ys - cy[:, None]) - truth[missed, 6:7] / 2
    crowded = np.any(other & (scans.ranges[ms] < scans.max_range) & (gap < 2.0), axis=1)
    few = truth[missed, 2] <= 5
    miss_kind = np.select([occl, edge, crowded, few], [0, 1, 2, 3], 4)
    return {
        "targets": int(target.sum()),
        "found": int((target & found).sum()),
        "dets": int(near.sum()),
        "whole": int((target & in_view).sum()),
        "whole_found": int((target & in_view & found).sum()),
        "true": int((near & used).sum()),
        "diam": dd,
        "diam_range": dd_range,
        "diam_target": dd_target,
        "false_kind": np.bincount(false_kind, minlength=len(FALSE_KINDS)),
        "miss_kind": np.bincount(miss_kind, minlength=len(MISS_KINDS)),
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seeds", type=parse_seeds, default="100-107", help="simulation seeds (e.g. 100-107 or 1,5,9)")
    p.add_argument("--duration", type=float, default=240.0, help="seconds driven per log (sim.duration)")
    p.add_argument("--config", help="YAML config whose detector and sim sections are used")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    args = p.parse_args(argv)
    cfg = load_config(args.config, [f"sim.duration={args.duration}"] + args.overrides)
    s = cfg.sim
    print(
        f"simulated raw logs: {args.duration:g} s, {s.n_trees} trees, {s.laser_walls} walls, {s.laser_fences} "
        f"fences, {s.laser_bushes} bushes, range noise {s.laser_range_noise * 100:g} cm, dropouts "
        f"{s.laser_dropout * 100:g} %, spurious {s.laser_spurious * 100:g} %; targets: trees hit by >= {MIN_BEAMS} "
        f"beams within {WITHIN:g} m\n"
    )
    print(
        "| seed | scans | targets | recall | recall in view | precision | diam. err. (cm) | naive recall "
        "| naive precision | naive diam. err. (cm) | sim (s) | detect (s) |"
    )
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    pooled = {"ours": [], "naive": []}
    for seed in args.seeds:
        t0 = time.perf_counter()
        log = simulate_laser(dataclasses.replace(s, seed=seed), cfg.vehicle)
        t1 = time.perf_counter()
        ours = evaluate(log, detect_trees(log.scans, cfg.detector))
        t2 = time.perf_counter()
        naive = evaluate(log, naive_trees(log.scans))
        pooled["ours"].append(ours)
        pooled["naive"].append(naive)
        print(
            f"| {seed} | {log.scans.n_scans} | {ours['targets']} | {ours['found'] / ours['targets']:.3f} | "
            f"{ours['whole_found'] / ours['whole']:.3f} | "
            f"{ours['true'] / max(ours['dets'], 1):.3f} | {np.median(ours['diam']) * 100:.1f} | "
            f"{naive['found'] / naive['targets']:.3f} | {naive['true'] / max(naive['dets'], 1):.3f} | "
            f"{np.median(naive['diam']) * 100:.1f} | {t1 - t0:.1f} | {t2 - t1:.1f} |",
            flush=True,
        )
    print()
    print(
        "| detector | targets | recall | recall in view | precision | diam. err. median (cm) "
        "| diam. err. p90 (cm) | diam. err. median, targets found (cm) |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for name, runs in pooled.items():
        tg, fd = sum(r["targets"] for r in runs), sum(r["found"] for r in runs)
        dt, tr = sum(r["dets"] for r in runs), sum(r["true"] for r in runs)
        dd = np.concatenate([r["diam"] for r in runs])
        wh, wf = sum(r["whole"] for r in runs), sum(r["whole_found"] for r in runs)
        dt_found = np.concatenate([r["diam_target"] for r in runs])
        print(
            f"| {name} | {tg} | {fd / tg:.3f} | {wf / wh:.3f} | {tr / max(dt, 1):.3f} | {np.median(dd) * 100:.2f} | "
            f"{np.percentile(dd, 90) * 100:.1f} | {np.median(dt_found) * 100:.2f} |"
        )
    print("\n| detector | median diameter error (cm), centre at 0-10 m | 10-20 m | 20-30 m |")
    print("|---|---:|---:|---:|")
    for name, runs in pooled.items():
        dd = np.concatenate([r["diam"] for r in runs])
        rr = np.concatenate([r["diam_range"] for r in runs])
        cells = [np.median(dd[(rr >= lo) & (rr < lo + 10)]) * 100 for lo in (0, 10, 20)]
        print(f"| {name} | " + " | ".join(f"{c:.1f}" for c in cells) + " |")
    for name, runs in pooled.items():
        fk = sum(r["false_kind"] for r in runs)
        mk = sum(r["miss_kind"] for r in runs)
        print(
            f"\n{name}: false detections within {WITHIN:g} m ({int(fk.sum())}), by what the beam at their bearing hit:"
        )
        for label, n in zip(FALSE_KINDS, fk):
            print(f"  {label}: {int(n)}")
        print(f"{name}: missed trees ({int(mk.sum())}), first reason that applies:")
        for label, n in zip(MISS_KINDS, mk):
            print(f"  {label}: {int(n)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
