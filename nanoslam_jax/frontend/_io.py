"""Running the front end over a whole log in chunks of scans (with progress), writing a detected log
(``measurements.dat``, ``inputs.dat``, ``gps.dat``) and ``features.csv``."""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Literal, cast

import numpy as np

from nanoslam_jax.frontend._settings import DetectorConfig
from nanoslam_jax.data import (
    LaserScans,
    RawLog,
    load_laser,
    load_victoria_park,
    write_victoria_park,
)
from nanoslam_jax.frontend._extract import extract_features
from nanoslam_jax.frontend._types import EDGE_NAMES, Features

__all__ = ["FEATURE_COLUMNS", "concatenate_features", "detect_log", "extract_features_chunked", "write_features_csv"]

#: Columns of ``features.csv``; a row holds one feature, the columns its kind does not use are empty.
FEATURE_COLUMNS = (
    "kind",
    "scan",
    "time",
    "first_beam",
    "last_beam",
    "x",
    "y",
    "x_end",
    "y_end",
    "alpha",
    "rho",
    "radius",
    "range",
    "bearing",
    "diameter",
    "angle",
    "length",
    "rms",
    "n",
    "beyond",
)


def concatenate_features(parts: list[Features]) -> Features:
    """Features of consecutive chunks of scans joined into those of the whole log (scan and return
    indices offset)."""
    scan_off = np.cumsum([0] + [p.time.size for p in parts])[:-1]
    point_off = np.cumsum([0] + [p.points.r.size for p in parts])[:-1]
    tables = {}
    for name in Features._fields[1:]:
        cls = type(getattr(parts[0], name))
        cols = {}
        for field in cls._fields:
            arrays = []
            for p, so, po in zip(parts, scan_off, point_off):
                a = getattr(getattr(p, name), field)
                if field == "scan":
                    a = a + so
                elif name == "clusters" and field in ("start", "end"):
                    a = a + po
                arrays.append(a)
            cols[field] = np.concatenate(arrays)
        tables[name] = cls(**cols)
    return Features(time=np.concatenate([p.time for p in parts]), **tables)


def extract_features_chunked(
    scans: LaserScans,
    cfg: DetectorConfig | None = None,
    chunk: int = 1000,
    progress: Callable[[int, int], None] | None = None,
) -> Features:
    """:func:`extract_features` over chunks of ``chunk`` scans (the same features: none crosses a scan),
    calling ``progress(done, total)`` after each."""
    parts = []
    for lo in range(0, scans.n_scans, chunk):
        parts.append(extract_features(scans.select(slice(lo, lo + chunk)), cfg))
        if progress is not None:
            progress(min(lo + chunk, scans.n_scans), scans.n_scans)
    if not parts:
        return extract_features(scans, cfg)
    return concatenate_features(parts)


def write_features_csv(path: str | os.PathLike, feats: Features) -> int:
    """Write every line segment, circle, corner, break point and tree of ``feats`` to a CSV file
    (:data:`FEATURE_COLUMNS`), ordered by scan; returns the number of rows."""
    t = feats.time
    blocks = []  # (scan, kind order, text rows)

    def add(kind, order, scan, cols):
        n = scan.size
        if n == 0:
            return
        cells = []
        for c in FEATURE_COLUMNS[1:]:
            v = cols.get(c)
            if v is None:
                cells.append(np.full(n, "", dtype=object))
            elif np.issubdtype(np.asarray(v).dtype, np.floating):
                cells.append(np.char.mod("%.6f", v))
            else:
                cells.append(np.asarray(v).astype(str))
        rows = np.full(n, kind, dtype=object)
        for cell in cells:
            rows = rows + "," + cell.astype(object)
        blocks.append((scan, np.full(n, order), rows))

    L = feats.lines
    add(
        "line",
        0,
        L.scan,
        dict(
            scan=L.scan,
            time=t[L.scan],
            first_beam=L.first_beam,
            last_beam=L.last_beam,
            x=L.x0,
            y=L.y0,
            x_end=L.x1,
            y_end=L.y1,
            alpha=L.alpha,
            rho=L.rho,
            length=L.length,
            rms=L.rms,
            n=L.n,
        ),
    )
    C = feats.circles
    add(
        "circle",
        1,
        C.scan,
        dict(
            scan=C.scan,
            time=t[C.scan],
            first_beam=C.first_beam,
            last_beam=C.last_beam,
            x=C.cx,
            y=C.cy,
            radius=C.radius,
            rms=C.rms,
            n=C.n,
        ),
    )
    Q = feats.corners
    add(
        "corner",
        2,
        Q.scan,
        dict(scan=Q.scan, time=t[Q.scan], first_beam=Q.beam, last_beam=Q.beam, x=Q.x, y=Q.y, angle=Q.angle),
    )
    B = feats.breakpoints
    add(
        "breakpoint",
        3,
        B.scan,
        dict(
            scan=B.scan,
            time=t[B.scan],
            first_beam=B.beam,
            last_beam=B.beam,
            x=B.x,
            y=B.y,
            beyond=np.asarray(EDGE_NAMES, dtype=object)[B.beyond],
        ),
    )
    T = feats.trees
    add(
        "tree",
        4,
        T.scan,
        dict(
            scan=T.scan,
            time=T.time,
            first_beam=T.first_beam,
            last_beam=T.last_beam,
            x=T.range * np.cos(T.bearing),
            y=T.range * np.sin(T.bearing),
            radius=T.diameter / 2,
            range=T.range,
            bearing=T.bearing,
            diameter=T.diameter,
        ),
    )
    path = Path(path)
    with path.open("w") as fh:
        fh.write(",".join(FEATURE_COLUMNS) + "\n")
        if blocks:
            scan = np.concatenate([b[0] for b in blocks])
            order = np.concatenate([b[1] for b in blocks])
            rows = np.concatenate([b[2] for b in blocks])
            idx = np.lexsort((order, scan))
            fh.write("\n".join(rows[idx].tolist()) + "\n")
            return int(rows.size)
    return 0


def detect_log(
    data_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    cfg: DetectorConfig | None = None,
    progress: Callable[[int, int], None] | None = None,
    fmt: str = "auto",
) -> tuple[RawLog, Features]:
    """Detect the trees in a log's raw scans and write a complete log.

    Writes ``measurements.dat`` (the trees, in the dataset's format: ``time range bearing diameter``,
    bearing in ``[0, pi]`` with ``pi/2`` ahead), copies ``inputs.dat`` and ``gps.dat`` (written from
    ``aa3_dr.mat`` / ``aa3_gpsx.mat`` where the log has only those) and writes ``features.csv``.

    Args:
        data_dir: the log directory (raw scans: ``LASER.txt`` or ``aa3_lsr2.mat``).
        out_dir: where to write (created; the files named above are overwritten).
        cfg: the detector settings.
        progress: called as ``progress(scans_done, scans_total)``.
        fmt: the log's dead-reckoning and GPS format (``auto``, ``ascii``, ``mat``).

    Returns:
        ``(raw, features)``: the log with its new detections, and all features.
    """
    if fmt not in ("auto", "ascii", "mat"):
        raise ValueError(f"data.format: detection reads a Victoria Park log ('auto', 'ascii' or 'mat'), got {fmt!r}")
    data_dir, out_dir = Path(data_dir), Path(out_dir)
    scans = load_laser(data_dir)
    raw = load_victoria_park(data_dir, cast(Literal["auto", "ascii", "mat"], fmt), detections=False)
    feats = extract_features_chunked(scans, cfg, progress=progress)
    raw = RawLog(dr=raw.dr, detections=feats.tree_table(), gps=raw.gps, source=str(data_dir))
    out_dir.mkdir(parents=True, exist_ok=True)
    write_victoria_park(out_dir, raw)
    for name in ("inputs.dat", "gps.dat"):  # the originals, byte for byte, where the log has them
        if (data_dir / name).is_file() and (data_dir / name).resolve() != (out_dir / name).resolve():
            shutil.copyfile(data_dir / name, out_dir / name)
    write_features_csv(out_dir / "features.csv", feats)
    return raw, feats
