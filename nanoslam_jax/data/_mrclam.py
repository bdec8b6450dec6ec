"""The UTIAS Multi-Robot Cooperative Localization and Mapping dataset (MRCLAM; Leung et al., IJRR 2011).

A dataset directory (e.g. ``MRCLAM_Dataset1``) holds, as whitespace-separated ASCII with ``#``
comment lines:

* ``Barcodes.dat``: ``subject barcode``; subjects 1-5 are the robots, 6 and up the landmarks;
* ``Landmark_Groundtruth.dat``: ``subject x y sd_x sd_y``, the surveyed landmarks (m, Vicon frame);
* ``RobotN_Odometry.dat``: ``time v omega``, UNIX time (s), forward speed (m/s), turn rate (rad/s);
* ``RobotN_Measurement.dat``: ``time barcode range bearing``, range (m) and bearing (rad, 0
  straight ahead, left positive) to the barcode seen.

:func:`load_mrclam` reads one robot's files as a :class:`~nanoslam_jax.data.RawLog` whose ``dr``
rows are the unicycle controls ``(time, v, omega)``. :func:`unicycle_poses` integrates them exactly
and :func:`dead_reckoning_map` projects every sighting from the dead-reckoned path, the simple
baseline a SLAM map of this log is read against.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path
from typing import Literal, NamedTuple

import numpy as np
from jaxtyping import Float, Int

from nanoslam_jax.lib._angles import wrap_angle_np
from nanoslam_jax.data._loader import LogFormatError, LogWarning, _data_rows, _parse_table, _Table, _validate
from nanoslam_jax.data._types import RawLog

__all__ = [
    "MRCLAM_ROBOTS",
    "MRCLAM_FIRST_LANDMARK",
    "load_mrclam",
    "unicycle_poses",
    "SightingMap",
    "dead_reckoning_map",
]

#: The robot numbers of an MRCLAM dataset (subjects 1-5 of ``Barcodes.dat``).
MRCLAM_ROBOTS = (1, 2, 3, 4, 5)
#: The first landmark subject: landmark subject ``s`` gets the landmark id ``s - MRCLAM_FIRST_LANDMARK``
#: (subjects 6-20 of dataset 1 are the ids 0-14).
MRCLAM_FIRST_LANDMARK = 6

_BARCODES = _Table("Barcodes.dat", ("subject", "barcode"), None, "barcode")
_LANDMARKS = _Table("Landmark_Groundtruth.dat", ("subject", "x", "y", "sd_x", "sd_y"), None, "landmark")
_EXPECTED_FILES = "Barcodes.dat, Landmark_Groundtruth.dat and RobotN_Odometry.dat, RobotN_Measurement.dat for N = 1..5"


def _odometry_table(robot: int) -> _Table:
    return _Table(f"Robot{robot}_Odometry.dat", ("time", "v", "omega"), None, "odometry")


def _measurement_table(robot: int) -> _Table:
    return _Table(f"Robot{robot}_Measurement.dat", ("time", "barcode", "range", "bearing"), None, "measurement")


def _read(
    directory: Path, table: _Table, allow_empty: bool = False
) -> tuple[Float[np.ndarray, "n columns"], np.ndarray, Path]:
    """Parse and validate (finite numbers, ranges >= 0) one file; returns the rows, their 1-based
    line numbers and the path. Without data rows: an error, or no rows with ``allow_empty``."""
    path = directory / table.name
    if not path.is_file():
        raise FileNotFoundError(f"{path}: not found; an MRCLAM dataset directory holds {_EXPECTED_FILES}")
    if allow_empty and not _data_rows(path)[0]:
        return np.zeros((0, len(table.columns))), np.zeros(0, dtype=np.int64), path
    data, lines = _parse_table(path, table)
    _validate(data, table, path, lines)
    return data, lines, path


def _integer_column(
    data: np.ndarray, column: int, table: _Table, path: Path, lines: np.ndarray, lo: int = 0, note: str = ""
) -> Int[np.ndarray, " n"]:
    """Column ``column`` of ``data`` as integers; raises naming the line of the first value that is
    not a whole number >= ``lo`` (``note``: why, for the message)."""
    values = data[:, column]
    bad = np.flatnonzero((values != np.round(values)) | (values < lo))
    if bad.size:
        i = bad[0]
        raise LogFormatError(
            f"{path} line {lines[i]}: expected a whole number >= {lo}{note} in column "
            f"'{table.columns[column]}', got {float(values[i]):g}"
        )
    return values.astype(np.int64)


def _unique_column(values: np.ndarray, table: _Table, column: int, path: Path, lines: np.ndarray) -> None:
    """Raise naming both lines when a value of ``values`` appears twice."""
    unique, counts = np.unique(values, return_counts=True)
    if np.any(counts > 1):
        value = unique[np.argmax(counts > 1)]
        rows = np.flatnonzero(values == value)
        raise LogFormatError(
            f"{path} line {lines[rows[1]]}: {table.columns[column]} {value} appears again "
            f"(first on line {lines[rows[0]]}); expected each {table.columns[column]} once"
        )


def _barcode_subjects(directory: Path) -> dict[int, int]:
    """``Barcodes.dat`` as a ``barcode -> subject`` mapping."""
    data, lines, path = _read(directory, _BARCODES)
    subjects = _integer_column(data, 0, _BARCODES, path, lines, lo=1)
    barcodes = _integer_column(data, 1, _BARCODES, path, lines)
    _unique_column(subjects, _BARCODES, 0, path, lines)
    _unique_column(barcodes, _BARCODES, 1, path, lines)
    return dict(zip(barcodes.tolist(), subjects.tolist()))


def _surveyed_landmarks(directory: Path) -> tuple[Float[np.ndarray, "l 2"], Int[np.ndarray, " l"]]:
    """``Landmark_Groundtruth.dat`` as ``(xy, landmark ids)``, in file order."""
    data, lines, path = _read(directory, _LANDMARKS)
    subjects = _integer_column(
        data, 0, _LANDMARKS, path, lines, lo=MRCLAM_FIRST_LANDMARK, note=" (a landmark; subjects 1-5 are the robots)"
    )
    _unique_column(subjects, _LANDMARKS, 0, path, lines)
    return data[:, 1:3].copy(), subjects - MRCLAM_FIRST_LANDMARK


def load_mrclam(
    directory: str | os.PathLike, robot: int = 1, *, unknown_barcodes: Literal["drop", "error"] = "drop"
) -> RawLog:
    """Load one robot's log of an MRCLAM dataset directory.

    * **Clock.** Times are seconds since ``t0``, the robot's first odometry time; its odometry and
      measurement files share the UNIX clock, so both are shifted by the same ``t0``.
    * **Odometry** ``time v omega`` becomes ``dr`` rows ``(time, v, omega)``, the controls of the
      ``unicycle`` motion model, each held until the next sample. Times must not decrease; of rows
      sharing a time only the last (in file order) is kept: the earlier ones would hold for no time.
    * **Measurements** ``time barcode range bearing`` become ``detections`` rows ``(time, range,
      bearing, 0)`` (no diameter; the bearing, 0 straight ahead and left positive as in the file,
      wrapped to ``(-pi, pi]``), sorted by time with a stable sort, so that rows of equal time keep
      their file order and form one scan. Barcodes are mapped to subjects with ``Barcodes.dat``;
      sightings of the robots (subjects 1-5) are dropped; a landmark subject ``s`` (6-20 in
      dataset 1) is the landmark id ``s - 6`` (0-14) of ``detection_ids``. Measurements before
      the first odometry sample are dropped (there is no pose for them).
    * **Map truth.** ``Landmark_Groundtruth.dat`` becomes ``truth_landmarks`` ``(L, 2)`` in the
      Vicon frame (not the frame of the dead-reckoned path, which starts at the origin), with their
      ids in ``landmark_ids``, in file order; the surveyed standard deviations are not kept.
    * There is no GPS (``gps`` is empty, ``(0, 3)``) and no true path.

    Args:
        directory: the dataset directory (the folder holding ``Barcodes.dat`` and the robots' files).
        robot: which robot's log, 1-5.
        unknown_barcodes: what to do with a measurement of a barcode that ``Barcodes.dat`` does not
            list (a misread barcode): ``"drop"`` it (a :class:`~nanoslam_jax.data.LogWarning` says
            how many, of which barcodes), or raise an ``"error"`` naming the line.

    Returns:
        The log, its ``source`` the directory and the robot.

    Raises:
        FileNotFoundError: the directory or one of its files is missing.
        LogFormatError: a file is malformed (the message names the file, the line and what was
            expected): not the expected number of numeric columns, a non-finite value, a negative
            range, a barcode or subject that is not a whole number or appears twice in
            ``Barcodes.dat`` / ``Landmark_Groundtruth.dat``, a robot in the landmark file, an
            unknown barcode with ``unknown_barcodes="error"``, odometry times that decrease, or no
            odometry rows (a measurement file without rows is an empty log of sightings).
        ValueError: ``robot`` is not one of 1-5, or ``unknown_barcodes`` is not one of the above.
    """
    if isinstance(robot, bool) or not isinstance(robot, (int, np.integer)) or int(robot) not in MRCLAM_ROBOTS:
        raise ValueError(f"robot: expected one of {', '.join(map(str, MRCLAM_ROBOTS))}, got {robot!r}")
    if unknown_barcodes not in ("drop", "error"):
        raise ValueError(f"unknown_barcodes: expected 'drop' or 'error', got {unknown_barcodes!r}")
    robot = int(robot)
    directory = Path(directory)
    if not directory.is_dir():
        raise FileNotFoundError(
            f"{directory}: MRCLAM dataset directory not found; expected a directory holding {_EXPECTED_FILES}"
        )
    subject_of = _barcode_subjects(directory)
    truth_xy, truth_ids = _surveyed_landmarks(directory)

    odo, odo_lines, odo_path = _read(directory, _odometry_table(robot))
    back = np.flatnonzero(np.diff(odo[:, 0]) < 0)
    if back.size:
        i = back[0] + 1
        raise LogFormatError(
            f"{odo_path} line {odo_lines[i]}: odometry times must be non-decreasing, got {float(odo[i, 0])!r} "
            f"after {float(odo[i - 1, 0])!r} (line {odo_lines[i - 1]})"
        )
    odo = odo[np.append(odo[1:, 0] != odo[:-1, 0], True)]  # the last row of each run of equal times
    t0 = odo[0, 0]
    dr = np.column_stack([odo[:, 0] - t0, odo[:, 1:3]])

    table = _measurement_table(robot)
    meas, lines, path = _read(directory, table, allow_empty=True)
    barcodes = _integer_column(meas, 1, table, path, lines)
    subjects = np.array([subject_of.get(b, -1) for b in barcodes.tolist()], dtype=np.int64)
    unknown = np.flatnonzero(subjects < 0)
    if unknown.size and unknown_barcodes == "error":
        i = unknown[0]
        raise LogFormatError(
            f"{path} line {lines[i]}: barcode {barcodes[i]} is not listed in "
            f"{directory / _BARCODES.name}; expected one of {sorted(subject_of)}"
        )
    if unknown.size:
        seen, counts = np.unique(barcodes[unknown], return_counts=True)
        listed = ", ".join(f"{b} ({c}x)" for b, c in zip(seen.tolist(), counts.tolist()))
        warnings.warn(
            f"{path}: {unknown.size} sighting(s) of barcodes not listed in {directory / _BARCODES.name} "
            f"dropped: barcode {listed}",
            LogWarning,
            stacklevel=2,
        )
    keep = (subjects >= MRCLAM_FIRST_LANDMARK) & (meas[:, 0] >= t0)
    meas, ids = meas[keep], subjects[keep] - MRCLAM_FIRST_LANDMARK
    order = np.argsort(meas[:, 0], kind="stable")
    meas, ids = meas[order], ids[order]
    detections = np.column_stack([meas[:, 0] - t0, meas[:, 2], wrap_angle_np(meas[:, 3]), np.zeros(len(meas))])
    return RawLog(
        dr=dr,
        detections=detections,
        gps=np.zeros((0, 3)),
        truth_landmarks=truth_xy,
        source=f"{directory} (robot {robot})",
        detection_ids=ids,
        landmark_ids=truth_ids,
    )


def unicycle_poses(
    dr: Float[np.ndarray, "n 3"], times: Float[np.ndarray, " m"], start: tuple[float, float, float] = (0.0, 0.0, 0.0)
) -> Float[np.ndarray, "m 3"]:
    """Dead reckoning of a unicycle: the poses ``(x, y, phi)`` at ``times``, integrated exactly.

    Sample ``i`` holds its controls ``(v_i, omega_i)`` over ``[t_i, t_{i+1})`` (the last one for
    ever), over which the robot follows a circular arc (a straight line when ``omega_i = 0``):
    ``phi(t) = phi_i + omega_i tau`` and ``p(t) = p_i + v_i tau sinc(omega_i tau / 2)
    (cos, sin)(phi_i + omega_i tau / 2)`` with ``tau = t - t_i`` and ``sinc(x) = sin(x) / x``.
    Times before the first sample give ``start``.

    Args:
        dr: ``(n, 3)`` odometry rows ``time, v, omega`` (s, m/s, rad/s), strictly increasing time.
        times: ``(m,)`` query times (s), any order.
        start: the pose at the first sample time.

    Returns:
        ``(m, 3)`` poses, the heading wrapped to ``(-pi, pi]``.

    Raises:
        ValueError: ``dr`` is not a non-empty ``(n, 3)`` array with strictly increasing time.
    """
    dr = np.asarray(dr, dtype=float)
    if dr.ndim != 2 or dr.shape[1] != 3 or dr.shape[0] == 0:
        raise ValueError(f"dr must be a non-empty (n, 3) array of time, v, omega, got shape {dr.shape}")
    t, v, w = dr.T
    if np.any(np.diff(t) <= 0):
        raise ValueError("dr times must be strictly increasing")

    def arc(phi, v, w, tau):
        """Displacement and heading change over ``tau`` from heading ``phi``."""
        chord = v * tau * np.sinc(w * tau / (2 * np.pi))  # np.sinc(x) = sin(pi x) / (pi x)
        mid = phi + 0.5 * w * tau
        return chord * np.cos(mid), chord * np.sin(mid), w * tau

    x0, y0, phi0 = (float(s) for s in start)
    dt = np.diff(t)
    phi = phi0 + np.concatenate([[0.0], np.cumsum(w[:-1] * dt)])  # heading at each sample, unwrapped
    dx, dy, _ = arc(phi[:-1], v[:-1], w[:-1], dt)
    x = x0 + np.concatenate([[0.0], np.cumsum(dx)])
    y = y0 + np.concatenate([[0.0], np.cumsum(dy)])

    times = np.asarray(times, dtype=float).reshape(-1)
    i = np.clip(np.searchsorted(t, times, side="right") - 1, 0, t.size - 1)
    tau = np.maximum(times - t[i], 0.0)
    ddx, ddy, ddphi = arc(phi[i], v[i], w[i], tau)
    return np.column_stack([x[i] + ddx, y[i] + ddy, wrap_angle_np(phi[i] + ddphi)])


class SightingMap(NamedTuple):
    """A map from sightings with known landmark ids (:func:`dead_reckoning_map`).

    Attributes:
        ids: ``(K,)`` the landmark ids seen, increasing.
        xy: ``(K, 2)`` the mean projected position of each.
        counts: ``(K,)`` how many sightings each mean averages.
    """

    ids: Int[np.ndarray, " k"]
    xy: Float[np.ndarray, "k 2"]
    counts: Int[np.ndarray, " k"]


def dead_reckoning_map(raw: RawLog) -> SightingMap:
    """The dead-reckoning map of a log with unicycle controls and known landmark ids: every
    sighting projected from the dead-reckoned pose at its time (:func:`unicycle_poses` from the
    origin) and averaged per landmark id; detections of unknown id (-1) are left out. A baseline: a
    SLAM map of the log should be far better.

    Args:
        raw: the log (``dr`` rows ``time, v, omega``; ``detections`` rows ``time, range, bearing,
            ...``, the bearing in the robot frame; ``detection_ids`` set).

    Returns:
        The :class:`SightingMap`, in the frame of the dead-reckoned path.

    Raises:
        ValueError: the log has no ``detection_ids``.
    """
    if raw.detection_ids is None:
        raise ValueError(f"log {raw.source!r} has no detection_ids: the dead-reckoning map needs known landmark ids")
    ids = np.asarray(raw.detection_ids, dtype=np.int64)
    det = np.asarray(raw.detections, dtype=float)[ids >= 0]
    return sighting_map(unicycle_poses(raw.dr, det[:, 0]), det[:, 1], det[:, 2], ids[ids >= 0])


def sighting_map(poses: np.ndarray, ranges: np.ndarray, bearings: np.ndarray, ids: np.ndarray) -> SightingMap:
    """Range-bearing sightings of known landmark ids projected from the poses they were taken at,
    averaged per id: the map a path alone gives.

    Args:
        poses: ``(n, 3)`` the sensor's pose ``(x, y, phi)`` at each sighting.
        ranges: ``(n,)`` the range of each sighting (m).
        bearings: ``(n,)`` its bearing in the sensor frame (rad).
        ids: ``(n,)`` its landmark id (every one known).

    Returns:
        The :class:`SightingMap`, in the frame of the poses.
    """
    pose = np.asarray(poses, dtype=float).reshape(-1, 3)
    heading = pose[:, 2] + np.asarray(bearings, dtype=float)
    r = np.asarray(ranges, dtype=float)[:, None]
    points = pose[:, :2] + r * np.column_stack([np.cos(heading), np.sin(heading)])
    seen, which, counts = np.unique(np.asarray(ids, dtype=np.int64), return_inverse=True, return_counts=True)
    xy = np.column_stack([np.bincount(which, points[:, k], seen.size) for k in range(2)]) / counts[:, None]
    return SightingMap(seen, xy, counts)
