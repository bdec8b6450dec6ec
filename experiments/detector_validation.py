"""Validation of the raw laser front end on the Victoria Park log (docs/frontend.md).

    .venv/bin/python experiments/detector_validation.py [--data DIR] [--config CONFIG] [--set detector.key=value ...]
        [--slam [CONFIG ...]] [--seeds 16-31] [--control] [--ablate DIR] [--figure PATH]

Prints (1) how many of the dataset's own detections (measurements.dat) within 30 m ours find (a
match lies within 0.5 m in range and 1.5 deg in bearing; one-to-one per scan, nearest first), the
detections we add and what they are, and the diameter agreement; (2) with --slam, SLAM from our
detections against the same runs on measurements.dat, paired over the seeds (with --control, also on
measurements.dat with 1 mm of range noise: how far the medians move from a change that cannot matter;
with --ablate, also on logs that isolate what differs: ours without the detections we add, the dataset's
without those we miss, and the dataset's with our range and bearing where we match it).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _seeds import format_seeds, parse_seeds  # noqa: E402

from nanoslam_jax.app.config import load_config  # noqa: E402
from nanoslam_jax.data import load_laser, load_victoria_park  # noqa: E402
from nanoslam_jax.frontend import extract_features  # noqa: E402
from nanoslam_jax.lib._angles import wrap_angle_np  # noqa: E402
import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)  # the library computes in float64

MATCH_RANGE, MATCH_BEARING_DEG, WITHIN = 0.5, 1.5, 30.0


def match(
    ref: np.ndarray, ours: np.ndarray, d_range: float = MATCH_RANGE, d_bearing: float = np.deg2rad(MATCH_BEARING_DEG)
) -> tuple[np.ndarray, np.ndarray]:
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
    both_r = np.isin(np.round(ref[:, 0] * 1000), common)
    both_o = np.isin(np.round(ours[:, 0] * 1000), common)
    # match on all ranges, so that a pair straddling the 30 m limit is neither missed nor added
    ai, aj = match(ref[both_r], ours[both_o])
    ri, oj = np.flatnonzero(both_r)[ai], np.flatnonzero(both_o)[aj]
    rsel = both_r & (ref[:, 1] < within)
    osel = both_o & (ours[:, 1] < within)
    found = np.zeros(ref.shape[0], bool)
    found[ri] = True
    used = np.zeros(ours.shape[0], bool)
    used[oj] = True
    keep = rsel[ri]
    mi, mj = ri[keep], oj[keep]
    r, o = ref[rsel], ours[osel]
    dd = ours[mj, 3] - ref[mi, 3]
    extra_rows = np.flatnonzero(osel & ~used)
    return dict(
        ref=r.shape[0],
        ours=o.shape[0],
        matched=mi.size,
        recall=mi.size / max(r.shape[0], 1),
        extra=extra_rows.size,
        extra_rows=extra_rows,
        missed_rows=np.flatnonzero(rsel & ~found),
        diam_bias=float(np.median(dd)),
        diam_mad=float(np.median(np.abs(dd - np.median(dd)))),
        diam_abs=float(np.median(np.abs(dd))),
        range_bias=float(np.median(ours[mj, 1] - ref[mi, 1])),
        bearing_bias_deg=float(np.rad2deg(np.median(wrap_angle_np(ours[mj, 2] - ref[mi, 2])))),
        scans=common.size,
    )


EXTRA_KINDS = (
    "near a dataset detection (range or bearing off)",
    "wide (diameter > 1 m)",
    "a neighbour within 3 m (the dataset drops one)",
    "one return (a thin pole or a stray return)",
    "other: an isolated trunk of 2 or more returns",
)


def classify_extras(ref: np.ndarray, ours: np.ndarray, rows: np.ndarray, beams: np.ndarray) -> np.ndarray:
    """What each added detection ``ours[rows]`` is (an index into :data:`EXTRA_KINDS`): next to a
    dataset detection of its scan (within 1.5 m, outside the match window); wider than the dataset's
    1 m limit; beside another of our trees within 3 m (the dataset's detector drops one of two trees
    closer than 3 m); one return (``beams``: returns per tree); or other."""
    kind = np.where(beams[rows] == 1, 3, 4)
    key_r = np.round(ref[:, 0] * 1000).astype(np.int64)
    key_o = np.round(ours[:, 0] * 1000).astype(np.int64)
    xy_r = ref[:, 1:2] * np.hstack([np.cos(ref[:, 2:3]), np.sin(ref[:, 2:3])])
    xy_o = ours[:, 1:2] * np.hstack([np.cos(ours[:, 2:3]), np.sin(ours[:, 2:3])])
    for n, k in enumerate(rows):
        same_r = key_r == key_o[k]
        same_o = (key_o == key_o[k]) & (np.arange(ours.shape[0]) != k)
        d_ref = np.hypot(*(xy_r[same_r] - xy_o[k]).T)
        d_our = np.hypot(*(xy_o[same_o] - xy_o[k]).T) - 0.5 * (ours[same_o, 3] + ours[k, 3])
        if d_ref.size and d_ref.min() < 1.5:
            kind[n] = 0
        elif ours[k, 3] > 1.0:
            kind[n] = 1
        elif d_our.size and d_our.min() < 3.0:
            kind[n] = 2
    return kind


def extras_figure(path: str, scans, feats, ref: np.ndarray, rows: np.ndarray, kinds: np.ndarray) -> None:
    """One scan per kind of added detection: its returns, our trees, the dataset's."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ours = feats.tree_table()
    fig, axes = plt.subplots(2, 3, figsize=(15, 9.5))
    for ax in axes.ravel()[len(EXTRA_KINDS) :]:
        ax.set_visible(False)
    for ax, kind in zip(axes.ravel(), range(len(EXTRA_KINDS))):
        pick = rows[kinds == kind]
        if pick.size == 0:
            ax.set_visible(False)
            continue
        k = pick[pick.size // 2]
        scan = int(np.argmin(np.abs(scans.time - ours[k, 0])))
        r = scans.ranges[scan]
        ok = r < 75
        ax.plot(
            r[ok] * np.cos(scans.angles[ok]), r[ok] * np.sin(scans.angles[ok]), ".", color="0.5", ms=3, label="returns"
        )
        rr = ref[np.abs(ref[:, 0] - ours[k, 0]) < 5e-4]
        ax.plot(
            rr[:, 1] * np.cos(rr[:, 2]), rr[:, 1] * np.sin(rr[:, 2]), "bo", mfc="none", ms=9, label="measurements.dat"
        )
        oo = ours[np.abs(ours[:, 0] - ours[k, 0]) < 5e-4]
        ax.plot(oo[:, 1] * np.cos(oo[:, 2]), oo[:, 1] * np.sin(oo[:, 2]), "g+", ms=9, label="ours")
        ax.plot(
            ours[k, 1] * np.cos(ours[k, 2]),
            ours[k, 1] * np.sin(ours[k, 2]),
            "rs",
            mfc="none",
            ms=14,
            label="added: " + EXTRA_KINDS[kind],
        )
        cx, cy = ours[k, 1] * np.cos(ours[k, 2]), ours[k, 1] * np.sin(ours[k, 2])
        ax.set_xlim(cx - 8, cx + 8)
        ax.set_ylim(cy - 8, cy + 8)
        ax.set_aspect("equal")
        ax.set_title(f"scan {scan} (t = {scans.time[scan]:.2f} s)")
        ax.legend(fontsize=7, loc="upper left")
        ax.set_xlabel("x ahead (m)")
        ax.set_ylabel("y left (m)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def control_log(data: str, out: str, sigma: float = 0.001, seed: int = 0) -> str:
    """Write ``data``'s log with ``sigma`` (m) of Gaussian noise added to every detection's range: a
    change no detector could matter by, to show how far SLAM's medians move from it alone."""
    import shutil

    from nanoslam_jax.data import RawLog, write_victoria_park

    raw = load_victoria_park(data)
    det = raw.detections.copy()
    det[:, 1] += np.random.default_rng(seed).normal(0.0, sigma, det.shape[0])
    write_victoria_park(out, RawLog(dr=raw.dr, detections=det, gps=raw.gps))
    for name in ("inputs.dat", "gps.dat"):
        shutil.copyfile(Path(data) / name, Path(out) / name)
    return out


def ablation_logs(data: str, detected: str, out: str) -> dict:
    """Write logs between the dataset's detections and ours (matched one-to-one over all ranges), each
    differing from one of them in one respect; return label -> directory.

    * ours, matched only: our detections without those we add;
    * dataset, matched only: the dataset's without those we miss;
    * dataset, our range and bearing: the dataset's detections, range and bearing ours where we match.
    """
    import shutil

    from nanoslam_jax.data import RawLog, write_victoria_park

    ds = load_victoria_park(data)
    ref, ours = ds.detections, load_victoria_park(detected).detections
    i, j = match(ref, ours)
    ours_rb = ref.copy()
    ours_rb[i, 1:3] = ours[j, 1:3]
    variants = {
        "ours, matched only (the detections we add dropped)": ("ours_matched", ours[np.sort(j)]),
        "measurements.dat, matched only (those we miss dropped)": ("dataset_matched", ref[np.sort(i)]),
        "measurements.dat, our range and bearing where matched": ("dataset_our_rb", ours_rb),
    }
    logs = {}
    for label, (name, det) in variants.items():
        directory = Path(out) / name
        write_victoria_park(directory, RawLog(dr=ds.dr, detections=det[np.lexsort((det[:, 2], det[:, 0]))], gps=ds.gps))
        for f in ("inputs.dat", "gps.dat"):
            shutil.copyfile(Path(data) / f, directory / f)
        logs[label] = str(directory)
    return logs


def slam_table(config: str, logs: dict, seeds: list[int], overrides: list[str]) -> dict:
    """Run ``config`` for every seed on each log of ``logs`` (label -> directory; the first is the
    reference); print each run and a paired summary table against the first."""
    from nanoslam_jax.app.experiment import execute

    res = {}
    for label, directory in logs.items():
        rows = []
        for seed in seeds:
            cfg = load_config(config, [f"seed={seed}", "output.plots=false"] + overrides)
            t = time.perf_counter()
            m = execute(cfg, directory, progress=False).metrics
            rows.append([seed, m["rmse_fixed"], m["rmse_aligned"], m.get("n_confirmed", m.get("n_landmarks", 0))])
            print(
                f"  {label}, seed {seed}: rmse_fixed {m['rmse_fixed']:.2f}, rmse_aligned {m['rmse_aligned']:.2f}, "
                f"{rows[-1][3]} trees, {time.perf_counter() - t:.0f} s",
                flush=True,
            )
        res[label] = np.asarray(rows, dtype=float)

    def q(v):
        return f"{np.median(v):.2f} [{np.percentile(v, 25):.2f}, {np.percentile(v, 75):.2f}], worst {v.max():.2f}"

    base = next(iter(res.values()))
    print(
        "| detections | rmse_fixed median [IQR], worst (m) | rmse_aligned median [IQR], worst (m) | medians / "
        "the first's (fixed, aligned) | better than the first (seeds, fixed) | confirmed trees (median) |"
    )
    print("|---|---|---|---|---|---|")
    for label, a in res.items():
        print(
            f"| {label} | {q(a[:, 1])} | {q(a[:, 2])} | {np.median(a[:, 1]) / np.median(base[:, 1]):.3f}, "
            f"{np.median(a[:, 2]) / np.median(base[:, 2]):.3f} | {int((a[:, 1] < base[:, 1]).sum())} of "
            f"{len(a)} | {np.median(a[:, 3]):.0f} |"
        )
    return res


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", default=str(ROOT.parent / "shared" / "data" / "victoria_park"))
    p.add_argument("--config", default=None, help="config whose detector section is used (default: defaults)")
    p.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a config key (detector.* for the detector; others apply to the SLAM runs)",
    )
    p.add_argument(
        "--slam",
        nargs="*",
        metavar="CONFIG",
        help="also run SLAM from both detection sets with these configs (default: configs/victoria_park_nano.yaml)",
    )
    p.add_argument("--seeds", type=parse_seeds, default="16-31", help="seeds of the SLAM runs, e.g. 16-31 or 0,1,2")
    p.add_argument("--out", default=None, help="directory for the detected log (default: a temporary one)")
    p.add_argument(
        "--control",
        action="store_true",
        help="with --slam: also run on measurements.dat with 1 mm of noise added to the ranges",
    )
    p.add_argument(
        "--ablate",
        default=None,
        metavar="DIR",
        help="with --slam: also write logs that isolate what differs (detections added, missed, "
        "range and bearing) under DIR and run on them",
    )
    p.add_argument("--figure", default=None, help="draw examples of the added detections to this image file")
    args = p.parse_args(argv)
    cfg = load_config(args.config, args.overrides)
    scans = load_laser(args.data)
    t = time.perf_counter()
    feats = extract_features(scans, cfg.detector)
    t = time.perf_counter() - t
    ref = load_victoria_park(args.data).detections
    res = detection_table(ref, feats)
    print(f"features of {scans.n_scans} scans in {t:.2f} s")
    print(
        f"| within {WITHIN:.0f} m | dataset | ours | matched | recall | added | diameter ours - dataset (median, "
        f"MAD, median abs) | range bias | bearing bias |"
    )
    print(
        f"| {res['scans']} scans | {res['ref']} | {res['ours']} | {res['matched']} | {res['recall']:.4f} | "
        f"{res['extra']} | {res['diam_bias']:+.3f} / {res['diam_mad']:.3f} / {res['diam_abs']:.3f} m | "
        f"{res['range_bias']:+.3f} m | {res['bearing_bias_deg']:+.3f} deg |"
    )
    ours = feats.tree_table()
    kinds = classify_extras(ref, ours, res["extra_rows"], feats.trees.last_beam - feats.trees.first_beam + 1)
    print("\n| added detection (within 30 m) | count | share of added |")
    print("|---|---|---|")
    for k, name in enumerate(EXTRA_KINDS):
        print(f"| {name} | {int((kinds == k).sum())} | {(kinds == k).mean():.1%} |")
    d = ours[res["extra_rows"], 3]
    print(f"added: diameter median {np.median(d):.2f} m, range median {np.median(ours[res['extra_rows'], 1]):.1f} m")
    if args.figure:
        extras_figure(args.figure, scans, feats, ref, res["extra_rows"], kinds)
        print(f"figure: {args.figure}")
    if args.slam is not None:
        import tempfile

        from nanoslam_jax.frontend import detect_log

        detected = args.out or tempfile.mkdtemp(prefix="detected-")
        detect_log(args.data, detected, cfg.detector)
        slam_overrides = [o for o in args.overrides if not o.startswith("detector.")]
        logs = {"measurements.dat": args.data, "ours (nanoslam detect)": detected}
        if args.control:
            logs["control: measurements.dat, ranges + N(0, 1 mm)"] = control_log(
                args.data, tempfile.mkdtemp(prefix="control-")
            )
        if args.ablate:
            logs.update(ablation_logs(args.data, detected, args.ablate))
        for config in args.slam or ["configs/victoria_park_nano.yaml"]:
            print(f"\nSLAM, {config}, seeds {format_seeds(args.seeds)}")
            slam_table(config, logs, args.seeds, slam_overrides)
    return 0


if __name__ == "__main__":
    sys.exit(main())
