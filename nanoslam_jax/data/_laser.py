"""Reading raw laser scans: ``LASER.txt`` (ASCII, metres, seconds) and ``aa3_lsr2.mat`` (the original
MATLAB file: ``LASER`` in cm, ``TLsr`` in ms).

``LASER.txt`` is a whitespace-separated stream of numbers, ``1 + beams`` per scan: the scan time
(s) and the ranges (m) of the beams at bearings ``0, 0.5, ..., 180`` deg (90 deg straight ahead).
Line breaks carry no meaning: one scan per line and one stream without breaks read the same.
Ranges at or above the scanner's maximum (80 m for the Victoria Park SICK; the log writes 81.91)
mean no return.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.io
from jaxtyping import Bool, Float

from nanoslam_jax.data._loader import _MAT_T0_MS, LogFormatError

__all__ = ["LASER_FILES", "NO_RETURN", "LaserScans", "fan_angles", "find_laser_file", "load_laser", "write_laser"]

#: File names a log directory may hold raw scans under, in order of preference.
LASER_FILES = ("LASER.txt", "aa3_lsr2.mat")
#: Beams of the Victoria Park scanner (0 to 180 deg in 0.5 deg steps).
VICTORIA_PARK_BEAMS = 361
#: Ranges at or above this (m) are no returns (the SICK of the Victoria Park log).
VICTORIA_PARK_MAX_RANGE = 80.0
#: The range the Victoria Park log writes for a beam without a return (m).
NO_RETURN = 81.91


@dataclass(frozen=True)
class LaserScans:
    """Raw laser scans of one log, as fixed-shape host arrays.

    Attributes:
        time: ``(S,)`` scan times (s), on the clock of the log's other files, non-decreasing.
        ranges: ``(S, B)`` ranges (m); values ``>= max_range`` are no returns.
        angles: ``(B,)`` beam bearings in the **vehicle frame** (rad): 0 straight ahead, left
            positive, increasing with the beam index (the file's bearing minus pi/2).
        max_range: ranges at or above this are no returns (m).
        source: the file the scans came from ("" when built in memory).
    """

    time: Float[np.ndarray, " S"]
    ranges: Float[np.ndarray, "S B"]
    angles: Float[np.ndarray, " B"]
    max_range: float = VICTORIA_PARK_MAX_RANGE
    source: str = ""

    def __post_init__(self):
        time = np.asarray(self.time, dtype=np.float64)
        ranges = np.asarray(self.ranges, dtype=np.float64)
        angles = np.asarray(self.angles, dtype=np.float64)
        if time.ndim != 1 or ranges.ndim != 2 or angles.ndim != 1:
            raise ValueError(
                f"LaserScans: expected time (S,), ranges (S, B), angles (B,); got shapes "
                f"{time.shape}, {ranges.shape}, {angles.shape}"
            )
        if ranges.shape != (time.shape[0], angles.shape[0]):
            raise ValueError(
                f"LaserScans: ranges must have shape (len(time), len(angles)) = "
                f"({time.shape[0]}, {angles.shape[0]}), got {ranges.shape}"
            )
        if angles.shape[0] >= 2 and not np.all(np.diff(angles) > 0):
            raise ValueError("LaserScans: beam angles must be strictly increasing")
        if not self.max_range > 0:
            raise ValueError(f"LaserScans: max_range must be > 0, got {self.max_range}")
        object.__setattr__(self, "time", time)
        object.__setattr__(self, "ranges", ranges)
        object.__setattr__(self, "angles", angles)

    @property
    def n_scans(self) -> int:
        return int(self.ranges.shape[0])

    @property
    def n_beams(self) -> int:
        return int(self.ranges.shape[1])

    @property
    def valid(self) -> Bool[np.ndarray, "S B"]:
        """Which beams returned (range below ``max_range``)."""
        return self.ranges < self.max_range

    def select(self, index) -> "LaserScans":
        """The scans picked by ``index`` (a slice, integer array or boolean mask)."""
        return LaserScans(self.time[index], self.ranges[index], self.angles, self.max_range, self.source)


def fan_angles(n_beams: int, fov_deg: float = 180.0) -> Float[np.ndarray, " B"]:
    """Beam bearings (vehicle frame, rad) of a scanner sweeping ``fov_deg`` symmetrically about
    straight ahead in ``n_beams`` equal steps, from right (negative) to left."""
    return np.deg2rad(np.linspace(-fov_deg / 2, fov_deg / 2, n_beams))


def _locate_token(text: str, index: int) -> tuple[int, str]:
    """The 1-based line of the ``index``-th (0-based) whitespace-separated token and the token."""
    for k, m in enumerate(re.finditer(r"\S+", text)):
        if k == index:
            return text.count("\n", 0, m.start()) + 1, m.group()
    return text.count("\n") + 1, ""


def _read_ascii(path: Path, n_beams: int) -> tuple[np.ndarray, np.ndarray, Callable[[int], int]]:
    """Times, ranges and a map from a number's 0-based index to its 1-based line."""
    per_scan = n_beams + 1
    try:
        text = path.read_text()
    except UnicodeDecodeError as e:
        raise LogFormatError(f"{path}: not a text file ({e.reason} at byte {e.start})") from None
    tokens = text.split()
    try:
        values = np.array(tokens, dtype=np.float64)
    except ValueError:
        # Find the first token that is not a number; report its position in the stream and its line.
        for k, tok in enumerate(tokens):
            try:
                float(tok)
            except ValueError:
                line, _ = _locate_token(text, k)
                scan, col = divmod(k, per_scan)
                what = "the scan time" if col == 0 else f"the range of beam {col - 1}"
                raise LogFormatError(
                    f"{path} line {line}, number {k + 1} (scan {scan + 1}, {what}): expected a number, got {tok!r}"
                ) from None
        raise
    if values.size == 0:
        raise LogFormatError(f"{path}: no data; expected scans of {per_scan} numbers (time and {n_beams} ranges)")
    if values.size % per_scan:
        counts = [(k + 1, len(row.split())) for k, row in enumerate(text.split("\n")) if row.strip()]
        if len(counts) > 1 and sum(n == per_scan for _, n in counts) * 2 > len(counts):  # one scan per line
            line, n = next((k, n) for k, n in counts if n != per_scan)
            raise LogFormatError(
                f"{path} line {line}: expected {per_scan} numbers on a scan's line (the time and {n_beams} "
                f"ranges), got {n}"
            )
        whole, extra = divmod(values.size, per_scan)
        line, tok = _locate_token(text, whole * per_scan)
        raise LogFormatError(
            f"{path}: expected a multiple of {per_scan} numbers (per scan: the time and {n_beams} ranges), "
            f"got {values.size}: {whole} whole scans and {extra} numbers left over, starting at number "
            f"{whole * per_scan + 1} (line {line}, {tok!r})"
        )
    table = values.reshape(-1, per_scan)
    bad = np.flatnonzero(~np.isfinite(table).all(axis=1))
    if bad.size:
        s = int(bad[0])
        c = int(np.flatnonzero(~np.isfinite(table[s]))[0])
        line, tok = _locate_token(text, s * per_scan + c)
        raise LogFormatError(
            f"{path} line {line}, number {s * per_scan + c + 1} (scan {s + 1}): expected a finite number, got {tok!r}"
        )
    return table[:, 0], table[:, 1:], (lambda k: _locate_token(text, k)[0])


def _read_mat(path: Path) -> tuple[np.ndarray, np.ndarray, None]:
    """Times (s) and ranges (m) of an ``aa3_lsr2.mat`` file."""
    try:
        contents = scipy.io.loadmat(str(path))
    except Exception as e:  # scipy raises several types for corrupt files
        raise LogFormatError(f"{path}: not a readable MATLAB file ({e})") from None
    missing = [n for n in ("LASER", "TLsr") if n not in contents]
    if missing:
        raise LogFormatError(
            f"{path}: expected variables LASER (ranges, cm) and TLsr (times, ms); missing {', '.join(missing)}"
        )
    ranges = np.asarray(contents["LASER"], dtype=np.float64)
    t = np.asarray(contents["TLsr"], dtype=np.float64).ravel()
    if ranges.ndim != 2 or ranges.shape[0] != t.size:
        raise LogFormatError(
            f"{path}: expected LASER of shape (scans, beams) with one TLsr entry per scan, got "
            f"LASER {ranges.shape} and TLsr of {t.size}"
        )
    if t.size == 0:
        raise LogFormatError(f"{path}: no scans in LASER / TLsr")
    bad = np.flatnonzero(~(np.isfinite(ranges).all(axis=1) & np.isfinite(t)))
    if bad.size:
        raise LogFormatError(f"{path} row {bad[0] + 1}: expected finite LASER and TLsr values")
    return (t - _MAT_T0_MS) / 1000.0, ranges / 100.0, None


def find_laser_file(directory: str | os.PathLike) -> Path | None:
    """The raw-scan file of a log directory (``LASER.txt``, else ``aa3_lsr2.mat``), or None."""
    directory = Path(directory)
    for name in LASER_FILES:
        if (directory / name).is_file():
            return directory / name
    return None


def load_laser(
    path: str | os.PathLike,
    n_beams: int = VICTORIA_PARK_BEAMS,
    fov_deg: float = 180.0,
    max_range: float = VICTORIA_PARK_MAX_RANGE,
) -> LaserScans:
    """Read the raw scans of a log.

    Args:
        path: a ``LASER.txt`` file (any ``.txt``/``.dat`` name), an ``aa3_lsr2.mat`` file (any
            ``.mat`` name), or a log directory holding one of them (``LASER.txt`` preferred).
        n_beams: beams per scan of an ASCII file (a ``.mat`` file's ``LASER`` gives its own).
        fov_deg: the field of view the beams span, symmetric about straight ahead (deg).
        max_range: ranges at or above this are no returns (m).

    Returns:
        The scans: times in s on the log's clock (a ``.mat`` file's ms converted as for the other
        MATLAB files), ranges in m, beam bearings in the vehicle frame.

    Raises:
        FileNotFoundError: no such file, or a directory without a raw-scan file.
        LogFormatError: a malformed file; the message names the file and the position (number
            and line for ASCII, row for MATLAB) and what was expected.
    """
    path = Path(path)
    if path.is_dir():
        found = find_laser_file(path)
        if found is None:
            raise FileNotFoundError(f"{path}: no raw laser scans; expected {' or '.join(LASER_FILES)} in the directory")
        path = found
    if not path.is_file():
        raise FileNotFoundError(f"{path}: raw laser scan file not found")
    if path.suffix.lower() == ".mat":
        time, ranges, line_of = _read_mat(path)
    else:
        time, ranges, line_of = _read_ascii(path, n_beams)
    bad = np.flatnonzero(np.diff(time) < 0)
    if bad.size:
        s = int(bad[0]) + 1
        where = (
            f" line {line_of(s * (ranges.shape[1] + 1))}, number {s * (ranges.shape[1] + 1) + 1}"
            if line_of
            else f" row {s + 1}"
        )
        raise LogFormatError(
            f"{path}{where} (scan {s + 1}): scan times must be non-decreasing, got {time[s]!r} after {time[s - 1]!r}"
        )
    negative = np.argwhere(ranges < 0)
    if negative.size:
        s, b = (int(v) for v in negative[0])
        k = s * (ranges.shape[1] + 1) + 1 + b
        where = f" line {line_of(k)}, number {k + 1}" if line_of else f" row {s + 1}"
        raise LogFormatError(f"{path}{where} (scan {s + 1}, beam {b}): expected a range >= 0, got {ranges[s, b]!r}")
    return LaserScans(
        time=time,
        ranges=ranges,
        angles=fan_angles(ranges.shape[1], fov_deg),
        max_range=float(max_range),
        source=str(path),
    )


def write_laser(path: str | os.PathLike, scans: LaserScans) -> None:
    """Write scans as ``LASER.txt``: one scan per line, the time (s) then the ranges (m, mm resolution)
    at file bearings increasing from the right (``0 .. fov``, straight ahead at ``fov / 2``); no return
    as :data:`NO_RETURN`. :func:`load_laser` reads it back.

    Args:
        path: the file to write.
        scans: the scans (ranges at or beyond ``scans.max_range`` are written as no return).
    """
    r = np.where(scans.ranges >= scans.max_range, NO_RETURN, scans.ranges)
    np.savetxt(path, np.concatenate([scans.time[:, None], r], axis=1), fmt=["%.6f"] + ["%.3f"] * r.shape[1])
