"""Validation of the raw laser front end on the Victoria Park log (docs/frontend.md).

    .venv/bin/python experiments/detector_validation.py [--data DIR] [--config CONFIG] [--set detector.key=value ...]
        [--slam] [--seeds 16-31] [--slam-configs configs/victoria_park_nano.yaml ...] [--figure PATH]

Prints (1) how many of the dataset's own detections (measurements.dat) within 30 m ours find (a
match lies within 0.5 m in range and 1.5 deg in bearing; one-to-one per scan, nearest first), the
detections we add and what they are, and the diameter agreement; (2) with --slam, SLAM from our
detections against the same runs on measurements.dat, paired over the seeds.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from nanoslam_jax.config import load_config  # noqa: E402
from nanoslam_jax.data import load_laser, load_victoria_park  # noqa: E402
from nanoslam_jax.frontend import EDGE_NAMES, extract_features  # noqa: E402
from nanoslam_jax.models._angles import wrap_angle_np  # noqa: E402

MATCH_RANGE, MATCH_BEARING_DEG, WITHIN = 0.5, 1.5, 30.0


def match(ref: np.ndarray, ours: np.ndarray, d_range: float = MATCH_RANGE,
          d_bearing: float = np.deg2rad(MATCH_BEARING_DEG)) -> tuple[np.ndarray, np.ndarray]:
    """One-to-one matches between detections of the same scans (times equal to the millisecond):
    pairs within ``d_range`` and ``d_bearing``, taken nearest first (normalised distance).

    Args:
        ref, ours: ``(n, 4)`` rows ``time, range, bearing, diameter``.

    Returns:
        ``(i, j)``: matched row indices into ``ref`` and ``ours``.
    """
    key_r = np.round(ref[:, 0] * 1000).astype(np.int64)
    key_o = np.round(ours[:, 0] * 1000).astype(np.int64)
    order = np.argsort(key_o, kind="stable")
    lo = np.searchsorted(key_o[order], key_r, "left")
    hi = np.searchsorted(key_o[order], key_r, "right")
    cnt = hi - lo
    i = np.repeat(np.arange(ref.shape[0]), cnt)
    j = order[np.repeat(lo, cnt) + (np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt))]
    dr = np.abs(ref[i, 1] - ours[j, 1])
    db = np.abs(wrap_angle_np(ref[i, 2] - ours[j, 2]))
    ok = (dr <= d_range) & (db <= d_bearing)
    i, j = i[ok], j[ok]
    cost = (dr[ok] / d_range) ** 2 + (db[ok] / d_bearing) ** 2
    o = np.argsort(cost, kind="stable")
    used_i, used_j = np.zeros(ref.shape[0], bool), np.zeros(ours.shape[0], bool)
    mi, mj = [], []
    for a, b in zip(i[o], j[o]):  # greedy over candidate pairs (a few per detection)
        if not used_i[a] and not used_j[b]:
            used_i[a] = used_j[b] = True
            mi.append(a)
            mj.append(b)
    return np.asarray(mi, dtype=np.int64), np.asarray(mj, dtype=np.int64)


def detection_table(ref: np.ndarray, feats, within: float = WITHIN) -> dict:
    """Recall of the dataset's detections, what we add, diameter agreement (all within ``within`` m)."""
    ours = feats.tree_table()
    # compare on the scans both have
    common = np.intersect1d(np.round(ref[:, 0] * 1000), np.round(ours[:, 0] * 1000))
    rsel = np.isin(np.round(ref[:, 0] * 1000), common) & (ref[:, 1] < within)
    osel = np.isin(np.round(ours[:, 0] * 1000), common) & (ours[:, 1] < within)
    r, o = ref[rsel], ours[osel]
    mi, mj = match(r, o)
    extra = np.ones(o.shape[0], bool)
    extra[mj] = False
    dd = o[mj, 3] - r[mi, 3]
    return dict(ref=r.shape[0], ours=o.shape[0], matched=mi.size, recall=mi.size / max(r.shape[0], 1),
                extra=int(extra.sum()), extra_rows=np.flatnonzero(osel)[extra], missed_rows=np.flatnonzero(rsel)[
                    np.setdiff1d(np.arange(r.shape[0]), mi)],
                diam_bias=float(np.median(dd)), diam_mad=float(np.median(np.abs(dd - np.median(dd)))),
                diam_abs=float(np.median(np.abs(dd))), range_bias=float(np.median(o[mj, 1] - r[mi, 1])),
                bearing_bias_deg=float(np.rad2deg(np.median(wrap_angle_np(o[mj, 2] - r[mi, 2])))),
                scans=common.size)


def parse_seeds(text: str) -> list[int]:
    """``"16-31"`` or ``"1,2,5"`` as a list of seeds."""
    out = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out += list(range(int(lo), int(hi or lo) + 1))
    return out


def slam_table(config: str, data: str, detected: str, seeds: list[int], overrides: list[str]) -> dict:
    """Run ``config`` on the dataset's detections (``data``) and on ours (``detected``, a directory
    ``nanoslam detect`` wrote) for every seed; print one row per seed and the paired summary."""
    from nanoslam_jax.experiment import execute

    rows = []
    for seed in seeds:
        row = [seed]
        for directory in (data, detected):
            cfg = load_config(config, [f"seed={seed}", "output.plots=false"] + overrides)
            t = time.perf_counter()
            m = execute(cfg, directory, progress=False).metrics
            row += [m["rmse_fixed"], m["rmse_aligned"], m.get("n_confirmed", m.get("n_landmarks", 0)),
                    time.perf_counter() - t]
        rows.append(row)
        print(f"| {seed} | {row[1]:.2f} | {row[5]:.2f} | {row[2]:.2f} | {row[6]:.2f} | {row[3]} | {row[7]} | "
              f"{row[4]:.0f} / {row[8]:.0f} s |", flush=True)
    a = np.asarray(rows, dtype=float)
    out = {}
    for name, i, j in (("rmse_fixed", 1, 5), ("rmse_aligned", 2, 6)):
        f, o = a[:, i], a[:, j]
        q = lambda v: f"{np.median(v):.2f} [{np.percentile(v, 25):.2f}, {np.percentile(v, 75):.2f}] worst {v.max():.2f}"  # noqa: E731
        ratio = np.median(o) / np.median(f)
        out[name] = ratio
        print(f"{name}: dataset {q(f)}; ours {q(o)}; medians ours/dataset {ratio:.3f}; ours better in "
              f"{int((o < f).sum())} of {len(f)} seeds; median paired ratio {np.median(o / f):.3f}")
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", default=str(ROOT.parent / "shared" / "data" / "victoria_park"))
    p.add_argument("--config", default=None, help="config whose detector section is used (default: defaults)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config key (detector.* for the detector; others apply to the SLAM runs)")
    p.add_argument("--slam", nargs="*", metavar="CONFIG",
                   help="also run SLAM from both detection sets with these configs "
                        "(default: configs/victoria_park_nano.yaml)")
    p.add_argument("--seeds", default="16-31", help="seeds of the SLAM runs, e.g. 16-31 or 0,1,2")
    p.add_argument("--out", default=None, help="directory for the detected log (default: a temporary one)")
    args = p.parse_args(argv)
    cfg = load_config(args.config, args.overrides)
    scans = load_laser(args.data)
    t = time.perf_counter()
    feats = extract_features(scans, cfg.detector)
    t = time.perf_counter() - t
    ref = load_victoria_park(args.data).detections
    res = detection_table(ref, feats)
    print(f"features of {scans.n_scans} scans in {t:.2f} s")
    print(f"| within {WITHIN:.0f} m | dataset | ours | matched | recall | added | diameter ours - dataset (median, "
          f"MAD, median abs) | range bias | bearing bias |")
    print(f"| {res['scans']} scans | {res['ref']} | {res['ours']} | {res['matched']} | {res['recall']:.4f} | "
          f"{res['extra']} | {res['diam_bias']:+.3f} / {res['diam_mad']:.3f} / {res['diam_abs']:.3f} m | "
          f"{res['range_bias']:+.3f} m | {res['bearing_bias_deg']:+.3f} deg |")
    if args.slam is not None:
        import tempfile

        from nanoslam_jax.frontend import detect_log

        detected = args.out or tempfile.mkdtemp(prefix="detected-")
        detect_log(args.data, detected, cfg.detector)
        slam_overrides = [o for o in args.overrides if not o.startswith("detector.")]
        for config in args.slam or ["configs/victoria_park_nano.yaml"]:
            print(f"\nSLAM, {config}, seeds {args.seeds}: measurements.dat against ours ({detected})")
            print("| seed | rmse_fixed dataset | ours | rmse_aligned dataset | ours | trees mapped dataset | ours | "
                  "run time |")
            print("|---|---|---|---|---|---|---|---|")
            slam_table(config, args.data, detected, parse_seeds(args.seeds), slam_overrides)
    return 0


if __name__ == "__main__":
    sys.exit(main())
