"""Reading and writing Victoria Park-format logs (docs/data.md; conventions in docs/method/victoria-park.md).

A log directory holds the ASCII files ``inputs.dat`` (``time speed steering``),
``measurements.dat`` (``time range bearing diameter``, bearing in ``[0, pi]`` with ``pi/2``
straight ahead) and ``gps.dat`` (``time x y``), or, for dead reckoning and GPS, the original
MATLAB files ``aa3_dr.mat`` and ``aa3_gpsx.mat``. Simulated logs may add ``truth_poses.dat``
(``time x y phi``), ``truth_landmarks.dat`` (``x y``) and ``truth_diameters.dat`` (``diameter``).

Every format problem raises :class:`LogFormatError` naming the file, the 1-based line (or row of
a MATLAB variable) and what was expected.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, Optional

import numpy as np
import scipy.io
from jaxtyping import Float

from nanoslam_jax.lib._angles import wrap_angle_np
from nanoslam_jax.data._types import RawLog

__all__ = ["LogFormatError", "LogWarning", "load_victoria_park", "write_victoria_park"]

# Clock of the original MATLAB files: t_s = (t_ms - _MAT_T0_MS) / 1000 (one clock for all sensors).
_MAT_T0_MS = 20967.0
# gps.dat frame: (x, y) = R(-33 deg) (Lo_m + 67, La_m + 39).
_GPS_ROTATION_DEG = -33.0
_GPS_OFFSET_LO, _GPS_OFFSET_LA = 67.0, 39.0
# measurements.dat bearings lie in [0, pi] (the laser's 180 deg fan) to within this (rad).
_BEARING_TOLERANCE = 0.01
# Digits written by write_victoria_park: round trips at 1e-9.
_WRITE_FMT = "%.9f"


class LogFormatError(ValueError):
    """A malformed log file; the message names the file, the line (or row) and what was expected."""


class LogWarning(UserWarning):
    """Rows of a log file that were read but not used, or read other than as written; the message
    names the file, how many rows and why."""


@dataclass(frozen=True)
class _Table:
    """An ASCII log file: its name, column names and the ordering rule on its first column.

    Attributes:
        name: file name inside the log directory.
        columns: column names, in file order.
        order: rule on the time column: ``"increasing"`` (strictly), ``"non-decreasing"`` or
            ``None`` (no time column).
        what: what the file holds, for messages.
    """

    name: str
    columns: tuple[str, ...]
    order: Optional[Literal["increasing", "non-decreasing"]]
    what: str


_INPUTS = _Table("inputs.dat", ("time", "speed", "steering"), "increasing", "dead-reckoning")
_MEASUREMENTS = _Table("measurements.dat", ("time", "range", "bearing", "diameter"), "non-decreasing", "detection")
_GPS = _Table("gps.dat", ("time", "x", "y"), "increasing", "GPS")
_TRUTH_POSES = _Table("truth_poses.dat", ("time", "x", "y", "phi"), "increasing", "true pose")
_TRUTH_LANDMARKS = _Table("truth_landmarks.dat", ("x", "y"), None, "true landmark")
_TRUTH_DIAMETERS = _Table("truth_diameters.dat", ("diameter",), None, "true diameter")

# The original MATLAB files (times in ms); columns are variable names.
_DR_MAT = _Table("aa3_dr.mat", ("time", "speed", "steering"), "increasing", "dead-reckoning")
_GPS_MAT = _Table("aa3_gpsx.mat", ("timeGps", "Lo_m", "La_m"), "increasing", "GPS")
_EXPECTED_FILES = (
    f"{_INPUTS.name}, {_MEASUREMENTS.name} and {_GPS.name} "
    f"(or {_DR_MAT.name}, {_GPS_MAT.name} and {_MEASUREMENTS.name})"
)


# --------------------------------------------------------------------------- parsing


def _data_rows(path: Path) -> tuple[list[str], list[int]]:
    """The data lines of a text file and their 1-based line numbers.

    Blank lines and comments (from ``#`` to the end of the line) are skipped.

    Args:
        path: the file to read.
    """
    try:
        text = path.read_text()
    except UnicodeDecodeError as e:
        raise LogFormatError(f"{path}: not a text file ({e.reason} at byte {e.start})") from None
    rows, numbers = [], []
    for number, line in enumerate(text.splitlines(), 1):
        row = line.split("#", 1)[0].strip()
        if row:
            rows.append(row)
            numbers.append(number)
    return rows, numbers


def _parse_rows_slowly(
    path: Path, table: _Table, rows: list[str], numbers: list[int]
) -> Float[np.ndarray, "n columns"]:
    """Parse rows one by one; raise on the first bad one (the fall-back of :func:`_parse_table`).

    Args:
        path: the file, for messages.
        table: what the file should hold.
        rows: its data lines.
        numbers: their 1-based line numbers.
    """
    expected = f"{len(table.columns)} numeric columns ({' '.join(table.columns)})"
    values = []
    for row, number in zip(rows, numbers):
        tokens = row.split()
        if len(tokens) != len(table.columns):
            raise LogFormatError(f"{path} line {number}: expected {expected}, got {len(tokens)}")
        for token, column in zip(tokens, table.columns):
            try:
                values.append(float(token))
            except ValueError:
                raise LogFormatError(
                    f"{path} line {number}: expected {expected}, got non-numeric {token!r} in column '{column}'"
                ) from None
    return np.asarray(values, dtype=np.float64).reshape(len(rows), len(table.columns))


def _parse_table(path: Path, table: _Table) -> tuple[Float[np.ndarray, "n columns"], np.ndarray]:
    """Read a whitespace-separated numeric file; numpy first, a line-by-line diagnosis on failure.

    Args:
        path: the file to read.
        table: what the file should hold.

    Returns:
        ``(data, line_numbers)``: the ``(n, columns)`` values and the 1-based line of each row.
    """
    rows, numbers = _data_rows(path)
    if not rows:
        raise LogFormatError(f"{path}: no data rows; expected lines of {' '.join(table.columns)}")
    try:
        data = np.loadtxt(rows, dtype=np.float64, ndmin=2, comments=None)
    except ValueError:
        data = None
    if data is None or data.shape[1] != len(table.columns):
        data = _parse_rows_slowly(path, table, rows, numbers)
    return data, np.asarray(numbers)


def _validate(
    data: Float[np.ndarray, "n columns"], table: _Table, path: Path, numbers: np.ndarray, unit: str = "line"
) -> None:
    """Check finiteness, time order and (for detections) non-negative ranges.

    Args:
        data: the parsed ``(n, columns)`` values.
        table: what they should be.
        path: their file, for messages.
        numbers: the 1-based line (or row) of each data row.
        unit: ``"line"`` for text files, ``"row"`` for MATLAB variables.
    """
    bad = np.flatnonzero(~np.isfinite(data).all(axis=1))
    if bad.size:
        i = bad[0]
        j = int(np.flatnonzero(~np.isfinite(data[i]))[0])
        raise LogFormatError(
            f"{path} {unit} {numbers[i]}: expected finite numbers, "
            f"got {float(data[i, j])} in column '{table.columns[j]}'"
        )
    if table.order is not None:
        step = np.diff(data[:, 0])
        bad = np.flatnonzero(step <= 0 if table.order == "increasing" else step < 0)
        if bad.size:
            i = bad[0] + 1
            rule = "strictly increasing" if table.order == "increasing" else "non-decreasing"
            raise LogFormatError(
                f"{path} {unit} {numbers[i]}: {table.what} times must be {rule}, got {float(data[i, 0])!r} "
                f"after {float(data[i - 1, 0])!r} ({unit} {numbers[i - 1]})"
            )
    if "range" in table.columns:
        bad = np.flatnonzero(data[:, table.columns.index("range")] < 0)
        if bad.size:
            i = bad[0]
            raise LogFormatError(
                f"{path} {unit} {numbers[i]}: expected a range >= 0, got {float(data[i, table.columns.index('range')])}"
            )


def _check_bearings(bearing: np.ndarray, path: Path, numbers: np.ndarray) -> None:
    """Raise naming the first line whose bearing is outside ``[0, pi]`` (by more than
    :data:`_BEARING_TOLERANCE`): the file's bearings are radians, ``pi/2`` straight ahead."""
    bad = np.flatnonzero((bearing < -_BEARING_TOLERANCE) | (bearing > np.pi + _BEARING_TOLERANCE))
    if bad.size:
        i = bad[0]
        raise LogFormatError(
            f"{path} line {numbers[i]}: expected a bearing in radians in [0, pi] (pi/2 straight ahead), "
            f"got {float(bearing[i])!r} in column 'bearing' ({bad.size} of {bearing.size} rows outside; "
            "a file in degrees, or with 0 straight ahead, must be converted)"
        )


def _read_ascii(path: Path, table: _Table) -> Float[np.ndarray, "n columns"]:
    """Parse and validate one ASCII log file.

    Args:
        path: the file.
        table: what it should hold.
    """
    data, numbers = _parse_table(path, table)
    _validate(data, table, path, numbers)
    return data


def _read_mat(path: Path, table: _Table) -> Float[np.ndarray, "n columns"]:
    """Read equal-length vectors from a MATLAB file as the columns of a validated table.

    Args:
        path: the ``.mat`` file.
        table: the variables to read (``table.columns``, time first, in ms) and their order rule.
    """
    try:
        contents = scipy.io.loadmat(str(path))
    except Exception as e:  # scipy raises several types for corrupt files
        raise LogFormatError(f"{path}: not a readable MATLAB file ({e})") from None
    names = table.columns
    missing = [n for n in names if n not in contents]
    if missing:
        raise LogFormatError(f"{path}: expected variables {', '.join(names)}; missing {', '.join(missing)}")
    columns = [np.asarray(contents[n], dtype=np.float64).ravel() for n in names]
    lengths = {n: c.size for n, c in zip(names, columns)}
    if len(set(lengths.values())) != 1:
        raise LogFormatError(f"{path}: expected variables {', '.join(names)} of equal length, got {lengths}")
    if columns[0].size == 0:
        raise LogFormatError(f"{path}: no data rows; expected non-empty {', '.join(names)}")
    data = np.stack(columns, axis=1)
    _validate(data, table, path, np.arange(1, data.shape[0] + 1), unit="row")
    data[:, 0] = (data[:, 0] - _MAT_T0_MS) / 1000.0
    return data


def _read_gps_mat(path: Path) -> Float[np.ndarray, "n 3"]:
    """``aa3_gpsx.mat`` as ``time_s, x, y`` rows in the frame of ``gps.dat``.

    Args:
        path: the ``.mat`` file.
    """
    t, lo, la = _read_mat(path, _GPS_MAT).T
    c, s = math.cos(math.radians(_GPS_ROTATION_DEG)), math.sin(math.radians(_GPS_ROTATION_DEG))
    lo, la = lo + _GPS_OFFSET_LO, la + _GPS_OFFSET_LA
    return np.stack([t, c * lo - s * la, s * lo + c * la], axis=1)


# --------------------------------------------------------------------------- public API


def _find_file(directory: Path, candidates: list[str], format: str) -> Path:
    """The first of ``candidates`` present in ``directory``; raises when none is.

    Args:
        directory: the log directory.
        candidates: file names, in order of preference.
        format: the requested format, for the message.
    """
    for name in candidates:
        if (directory / name).is_file():
            return directory / name
    raise FileNotFoundError(
        f"{directory}: {' or '.join(candidates)} not found (format={format!r}); "
        f"a Victoria Park log directory holds {_EXPECTED_FILES}"
    )


def load_victoria_park(
    directory: str | os.PathLike, format: Literal["auto", "ascii", "mat"] = "auto", detections: bool = True
) -> RawLog:
    """Load a Victoria Park-format log directory.

    Detection bearings are converted to the vehicle frame (file bearing minus pi/2, wrapped to
    (-pi, pi]). Times of the MATLAB files are converted to seconds on the ASCII files' clock and
    their GPS to the frame of ``gps.dat``.

    Args:
        directory: the log directory.
        format: ``"ascii"``: ``inputs.dat``, ``measurements.dat``, ``gps.dat``; ``"mat"``:
            ``aa3_dr.mat``, ``aa3_gpsx.mat`` and ``measurements.dat`` (detections exist only as
            ASCII); ``"auto"``: per stream, the ASCII file when present, else the MATLAB one.
        detections: read ``measurements.dat``; False: leave the detections empty (``(0, 4)``), for a
            caller that detects the trees in the raw scans itself.

    Returns:
        The log; ``truth_poses`` / ``truth_landmarks`` / ``truth_diameters`` are set when
        ``truth_poses.dat`` / ``truth_landmarks.dat`` / ``truth_diameters.dat`` exist.

    Raises:
        FileNotFoundError: the directory or a needed file is missing (the message names it and
            the files a log directory holds).
        LogFormatError: a file is malformed (the message names the file, line and expectation), e.g. a
            detection bearing outside [0, pi] (radians, within 0.01).
        ValueError: ``format`` is not one of the above.
    """
    if format not in ("auto", "ascii", "mat"):
        raise ValueError(f"format: expected 'auto', 'ascii' or 'mat', got {format!r}")
    directory = Path(directory)
    if not directory.is_dir():
        raise FileNotFoundError(f"{directory}: log directory not found; expected a directory holding {_EXPECTED_FILES}")
    dr_files = {"ascii": _INPUTS.name, "mat": _DR_MAT.name}
    gps_files = {"ascii": _GPS.name, "mat": _GPS_MAT.name}
    preferred = ["ascii", "mat"] if format == "auto" else [format]
    dr_path = _find_file(directory, [dr_files[f] for f in preferred], format)
    gps_path = _find_file(directory, [gps_files[f] for f in preferred], format)
    det_path = _find_file(directory, [_MEASUREMENTS.name], format) if detections else None

    dr = _read_mat(dr_path, _DR_MAT) if dr_path.suffix == ".mat" else _read_ascii(dr_path, _INPUTS)
    gps = _read_gps_mat(gps_path) if gps_path.suffix == ".mat" else _read_ascii(gps_path, _GPS)
    if det_path is None:
        det = np.zeros((0, len(_MEASUREMENTS.columns)))
    else:
        det, numbers = _parse_table(det_path, _MEASUREMENTS)
        _validate(det, _MEASUREMENTS, det_path, numbers)
        _check_bearings(det[:, 2], det_path, numbers)
        det[:, 2] = wrap_angle_np(det[:, 2] - np.pi / 2)

    truth = {}
    for key, table in (
        ("truth_poses", _TRUTH_POSES),
        ("truth_landmarks", _TRUTH_LANDMARKS),
        ("truth_diameters", _TRUTH_DIAMETERS),
    ):
        if (directory / table.name).is_file():
            truth[key] = _read_ascii(directory / table.name, table)
    if "truth_diameters" in truth:
        truth["truth_diameters"] = truth["truth_diameters"][:, 0]
    return RawLog(dr=dr, detections=det, gps=gps, source=str(directory), **truth)


def _as_table(data: np.ndarray, table: _Table) -> Float[np.ndarray, "n columns"]:
    """``data`` as a float64 ``(n, columns)`` array (a copy); raises on a wrong shape.

    Args:
        data: the values to write.
        table: the file they go to.
    """
    data = np.array(data, dtype=np.float64)
    if data.ndim != 2 or data.shape[1] != len(table.columns):
        raise ValueError(
            f"{table.name}: expected an (n, {len(table.columns)}) array "
            f"({' '.join(table.columns)}), got shape {data.shape}"
        )
    return data


def write_victoria_park(directory: str | os.PathLike, raw: RawLog) -> None:
    """Write a log in the ASCII format that :func:`load_victoria_park` reads back.

    Writes ``inputs.dat``, ``measurements.dat`` (bearing + pi/2, the file convention) and
    ``gps.dat``, plus ``truth_poses.dat`` / ``truth_landmarks.dat`` / ``truth_diameters.dat`` when
    ``raw`` has them;
    values carry 9 decimals so a round trip is exact to 1e-9. Existing files of those names are
    overwritten; other files in the directory are left alone.

    Args:
        directory: the log directory (created if needed).
        raw: the log; detection bearings in the vehicle frame.

    Raises:
        ValueError: an array of ``raw`` has the wrong shape.
    """
    directory = Path(directory)
    detections = _as_table(raw.detections, _MEASUREMENTS)
    detections[:, 2] += np.pi / 2
    tables = [
        (_INPUTS, raw.dr),
        (_MEASUREMENTS, detections),
        (_GPS, raw.gps),
        (_TRUTH_POSES, raw.truth_poses),
        (_TRUTH_LANDMARKS, raw.truth_landmarks),
        (_TRUTH_DIAMETERS, None if raw.truth_diameters is None else np.reshape(raw.truth_diameters, (-1, 1))),
    ]
    arrays = [(table, _as_table(data, table)) for table, data in tables if data is not None]
    directory.mkdir(parents=True, exist_ok=True)
    for table, data in arrays:
        np.savetxt(directory / table.name, data, fmt=_WRITE_FMT)
