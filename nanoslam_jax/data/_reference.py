"""Reference paths for a laser log: which scans have a reference pose, and that pose.

Three sources are read:

- a corrected CARMEN log (``.clf``/``.log``, optionally ``.gz``; e.g. what GMapping writes after
  processing the raw log): its scans are matched to the raw log's by identical ranges, in order;
  the reference pose is the corrected scan's laser pose. Its time stamps are not used.
- a CSV file with the header ``time,x,y,theta`` (s, m, m, rad), matched by time.
- a TUM file (``time x y z qx qy qz qw`` per line, ``#`` comments), the heading the yaw of the
  quaternion, matched by time.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from nanoslam_jax.data._carmen import _parse
from nanoslam_jax.data._laser_log import LaserOdomLog
from nanoslam_jax.data._loader import LogFormatError

__all__ = ["REFERENCE_TOLERANCE_S", "load_reference"]

#: A CSV or TUM pose matches a scan when their times differ by at most this (s).
REFERENCE_TOLERANCE_S = 0.02


def _from_carmen(path: Path, log: LaserOdomLog) -> tuple[np.ndarray, np.ndarray]:
    parsed = _parse(path)
    scans = [s for s in parsed.scans if s.laser is not None]
    if not scans:
        raise LogFormatError(f"{path}: no FLASER or ROBOTLASER1 lines; expected the corrected scans with their poses")
    raw = log.scans.ranges
    top = log.scans.max_range
    where: dict[bytes, list[int]] = {}
    for i, row in enumerate(raw):
        where.setdefault(row.tobytes(), []).append(i)
    index, poses, last = [], [], -1
    for s in scans:
        r = np.where(s.ranges >= top, top, s.ranges).astype(np.float64)
        if r.size != raw.shape[1]:
            raise LogFormatError(
                f"{path} line {s.line} ({s.kind}): {r.size} readings; expected {raw.shape[1]} as in {log.source}"
            )
        found = [i for i in where.get(r.tobytes(), []) if i > last]
        if not found:
            raise LogFormatError(
                f"{path} line {s.line} ({s.kind}): no scan of {log.source} after scan {last + 1} has the same ranges; "
                f"expected every corrected scan to match one raw scan, in order"
            )
        last = found[0]
        index.append(last)
        poses.append(s.laser)
    return np.array(index, dtype=np.int64), np.array(poses, dtype=np.float64)


def _read_table(path: Path) -> tuple[np.ndarray, np.ndarray, str]:
    """Rows of numbers with their 1-based lines; a CSV with a ``time,x,y,theta`` header or TUM."""
    text = path.read_text().splitlines()
    csv = path.suffix.lower() == ".csv"
    rows, lines = [], []
    header_seen = False
    for k, raw in enumerate(text):
        s = raw.strip()
        if not s or s.startswith("#"):
            continue
        if csv and not header_seen:
            names = [c.strip().lower() for c in s.split(",")]
            if names[:4] != ["time", "x", "y", "theta"]:
                raise LogFormatError(f"{path} line {k + 1}: expected the header time,x,y,theta, got {s!r}")
            header_seen = True
            continue
        tok = s.split(",") if csv else s.split()
        need = 4 if csv else 8
        if len(tok) < need:
            what = "time,x,y,theta" if csv else "time x y z qx qy qz qw"
            raise LogFormatError(f"{path} line {k + 1}: expected {need} values ({what}), got {len(tok)}")
        vals = []
        for j, v in enumerate(tok[:need]):
            try:
                f = float(v)
            except ValueError:
                f = math.nan
            if not math.isfinite(f):
                raise LogFormatError(f"{path} line {k + 1}, value {j + 1}: expected a finite number, got {v.strip()!r}")
            vals.append(f)
        rows.append(vals)
        lines.append(k + 1)
    if not rows:
        raise LogFormatError(f"{path}: no poses")
    return np.array(rows), np.array(lines), "csv" if csv else "tum"


def _from_table(path: Path, log: LaserOdomLog, tolerance_s: float) -> tuple[np.ndarray, np.ndarray]:
    rows, lines, kind = _read_table(path)
    if kind == "csv":
        poses = rows[:, 1:4]
    else:
        qx, qy, qz, qw = rows[:, 4], rows[:, 5], rows[:, 6], rows[:, 7]
        yaw = np.arctan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz))
        poses = np.stack([rows[:, 1], rows[:, 2], yaw], axis=1)
    t = rows[:, 0]
    order = np.argsort(t, kind="stable")
    t, poses, lines = t[order], poses[order], lines[order]
    st = log.scans.time
    j = np.clip(np.searchsorted(st, t), 1, max(st.size - 1, 1))
    lo = np.clip(j - 1, 0, st.size - 1)
    hi = np.clip(j, 0, st.size - 1)
    near = np.where(np.abs(st[lo] - t) <= np.abs(st[hi] - t), lo, hi)
    ok = np.abs(st[near] - t) <= tolerance_s
    if not ok.any():
        raise LogFormatError(
            f"{path}: no pose within {tolerance_s} s of a scan of {log.source} (poses {t[0]!r} to {t[-1]!r} s, scans "
            f"{st[0]!r} to {st[-1]!r} s)"
        )
    index, keep = np.unique(near[ok], return_index=True)  # one pose per scan: the first in time
    return index.astype(np.int64), poses[ok][keep]


def load_reference(
    path: str | os.PathLike, log: LaserOdomLog, tolerance_s: float = REFERENCE_TOLERANCE_S
) -> tuple[np.ndarray, np.ndarray]:
    """Reference poses for scans of ``log``.

    Args:
        path: a corrected CARMEN log (``.clf``/``.log``, optionally ``.gz``: matched by identical
            ranges, in order), a ``.csv`` file (header ``time,x,y,theta``) or a TUM file (any other
            name; ``time x y z qx qy qz qw``), the latter two matched to the nearest scan in time.
        log: the raw log the reference is for.
        tolerance_s: a CSV or TUM pose matches the nearest scan within this many seconds; poses
            farther from every scan are left out, and of several poses nearest one scan the first is kept.

    Returns:
        ``(scan_index, poses)``: ``(R,)`` increasing indices into ``log``'s scans and ``(R, 3)`` their
        reference poses ``(x, y, theta)`` of the laser (m, m, rad) in the reference's frame.

    Raises:
        FileNotFoundError: no such file.
        LogFormatError: a malformed file, or one that matches no scan (the message names the file and line).
    """
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"{p}: reference path file not found")
    name = p.name.lower().removesuffix(".gz")
    if name.endswith((".clf", ".log")):
        return _from_carmen(p, log)
    return _from_table(p, log, tolerance_s)
