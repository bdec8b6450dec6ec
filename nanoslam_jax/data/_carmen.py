"""Reading CARMEN logs (``.clf`` / ``.log``, optionally gzipped): laser scans with odometry.

A CARMEN log is a text file of one message per line, the message type first. The lines read:

- ``FLASER n r_1 .. r_n x y theta odom_x odom_y odom_theta ipc_timestamp ipc_hostname logger_timestamp``:
  a front laser scan, with the laser's pose and the robot's odometry pose.
- ``ROBOTLASER1 laser_type start_angle fov angular_res max_range accuracy remission_mode n r_1 .. r_n
  n_rem rem_1 .. laser_x laser_y laser_theta robot_x robot_y robot_theta tv rv forward_safety
  side_safety turn_axis ipc_timestamp ipc_hostname logger_timestamp``: a scan with its own beam
  angles and range limit and both poses.
- ``RAWLASER1`` .. ``RAWLASER4 laser_type start_angle fov angular_res max_range accuracy
  remission_mode n r_1 .. r_n n_rem rem_1 .. ipc_timestamp ipc_hostname logger_timestamp``: a scan
  without a pose; the odometry pose at its time is interpolated from the ``ODOM`` lines.
- ``ODOM x y theta tv rv accel ipc_timestamp ipc_hostname logger_timestamp``: the odometry pose.

Comment lines (``#``), ``PARAM`` lines and every other message type are skipped and counted.
Angles in the file are radians, ranges metres, ``ipc_timestamp`` seconds (the time used).
"""

from __future__ import annotations

import gzip
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np

from nanoslam_jax.data._laser import LaserScans
from nanoslam_jax.data._laser_log import LaserOdomLog
from nanoslam_jax.data._loader import LogFormatError

__all__ = [
    "CARMEN_SUFFIXES",
    "CarmenCounts",
    "MOUNT_TOL_M",
    "MOUNT_TOL_RAD",
    "SICK_NO_RETURN",
    "beam_convention",
    "find_carmen_file",
    "load_carmen",
    "read_carmen",
]

#: File names a CARMEN log may have (each optionally followed by ``.gz``).
CARMEN_SUFFIXES = (".clf", ".log")
#: Readings at or above this are no returns where the line states no maximum range (m; the SICK's 80 m).
SICK_NO_RETURN = 80.0
#: How much the laser's mounting (robot pose^-1 * laser pose) may vary between scan lines (m, rad).
MOUNT_TOL_M = 0.01
MOUNT_TOL_RAD = 0.01
_RAWLASER = ("RAWLASER1", "RAWLASER2", "RAWLASER3", "RAWLASER4")
_SCAN_TYPES = ("FLASER", "ROBOTLASER1", *_RAWLASER)


@dataclass(frozen=True)
class CarmenCounts:
    """What :func:`read_carmen` found in a file besides the scans.

    Attributes:
        lines: the file's lines (blank ones included).
        scans: scan lines read (``FLASER``, ``ROBOTLASER1``, ``RAWLASERn``).
        odom: ``ODOM`` lines read.
        comments: comment lines (``#``) and blank lines.
        skipped: other lines skipped, by message type (``PARAM``, ``SYNC``, ...).
        out_of_order: scan and ``ODOM`` lines whose time is below the previous line's of the same kind.
        dropped: ``RAWLASER`` scans outside the time span of the ``ODOM`` lines (no pose to interpolate).
    """

    lines: int = 0
    scans: int = 0
    odom: int = 0
    comments: int = 0
    skipped: dict = field(default_factory=dict)
    out_of_order: int = 0
    dropped: int = 0


@dataclass
class _Scan:
    line: int
    kind: str
    time: float
    ranges: np.ndarray
    start: Optional[float] = None  # rad, where the line states it
    step: Optional[float] = None
    max_range: Optional[float] = None
    laser: Optional[np.ndarray] = None  # (3,) laser pose, where the line gives it
    robot: Optional[np.ndarray] = None  # (3,) robot odometry pose


@dataclass
class _Parsed:
    path: Path
    scans: list
    odom_line: list
    odom: list  # (t, x, y, theta)
    counts: dict


def beam_convention(n_beams: int) -> tuple[float, float]:
    """The usual beam angles of a CARMEN scan line that states none: ``(start_deg, step_deg)``.

    180 beams: -90 to +89 deg by 1; 181: -90 to +90 by 1; 360: -90 to +89.5 by 0.5; 361: -90 to
    +90 by 0.5; any other count: 180 deg spread over the beams, from -90 to +90.

    Args:
        n_beams: readings per scan.
    """
    if n_beams in (180, 360):
        return -90.0, 180.0 / n_beams
    if n_beams <= 1:
        return 0.0, 1.0
    return -90.0, 180.0 / (n_beams - 1)


def find_carmen_file(path: str | os.PathLike) -> Path:
    """The CARMEN log ``path`` names: the file itself, or the one ``.clf``/``.log`` (``.gz``) file of a
    directory (a corrected log, one with ``corrected`` in its name, aside when it sits next to the raw one).

    Raises:
        FileNotFoundError: no such file, or a directory without exactly one such file.
    """
    p = Path(path)
    if p.is_dir():
        found = sorted(
            f
            for f in p.iterdir()
            if f.is_file()
            and any(f.name.lower().endswith(s) or f.name.lower().endswith(s + ".gz") for s in CARMEN_SUFFIXES)
        )
        raw = [f for f in found if "corrected" not in f.name.lower()]
        found = raw if len(raw) == 1 else found
        if len(found) != 1:
            names = ", ".join(f.name for f in found) or "none"
            raise FileNotFoundError(
                f"{p}: expected exactly one CARMEN log (*.clf, *.log, optionally .gz) in the directory, found {names}"
            )
        return found[0]
    if not p.is_file():
        raise FileNotFoundError(f"{p}: CARMEN log not found")
    return p


def _lines(path: Path) -> list[str]:
    try:
        if path.name.lower().endswith(".gz"):
            with gzip.open(path, "rt") as f:
                return f.read().splitlines()
        return path.read_text().splitlines()
    except UnicodeDecodeError as e:
        raise LogFormatError(f"{path}: not a text file ({e.reason} at byte {e.start})") from None
    except (OSError, EOFError) as e:
        raise LogFormatError(f"{path}: cannot read the file ({e})") from None


@dataclass(frozen=True)
class _Fields:
    """One message line split into its fields, with its place in the file for the error messages."""

    path: Path
    line: int  # 1-based
    kind: str  # the message type, the first field
    tok: list[str]

    def numbers(self, lo: int, hi: int, what: str) -> np.ndarray:
        """Fields ``lo:hi`` as finite floats, or a LogFormatError naming the field."""
        out = np.empty(hi - lo)
        for i in range(lo, hi):
            try:
                v = float(self.tok[i])
            except ValueError:
                v = math.nan
                ok = False
            else:
                ok = math.isfinite(v)
            if not ok:
                raise LogFormatError(
                    f"{self.path} line {self.line} ({self.kind}, field {i + 1}, {what}): expected a finite number, "
                    f"got {self.tok[i]!r}"
                )
            out[i - lo] = v
        return out

    def count(self, i: int, what: str) -> int:
        """Field ``i`` as an integer >= 0, or a LogFormatError naming the field."""
        if i >= len(self.tok):
            raise LogFormatError(
                f"{self.path} line {self.line} ({self.kind}): too few fields, expected {what} in field {i + 1}"
            )
        try:
            n = int(self.tok[i])
        except ValueError:
            n = -1
        if n < 0:
            raise LogFormatError(
                f"{self.path} line {self.line} ({self.kind}, field {i + 1}): expected {what} (an integer >= 0), got "
                f"{self.tok[i]!r}"
            )
        return n

    def need(self, n_fields: int, why: str) -> None:
        """A LogFormatError unless the line has at least ``n_fields`` fields."""
        if len(self.tok) < n_fields:
            raise LogFormatError(
                f"{self.path} line {self.line} ({self.kind}): too few fields, expected at least {n_fields} ({why}), "
                f"got {len(self.tok)}"
            )


def _parse_flaser(f: _Fields, out: _Parsed) -> None:
    """``FLASER n r_1 .. r_n x y theta odom_x odom_y odom_theta ipc_timestamp ...``: a scan with both poses."""
    n = f.count(1, "the number of readings")
    f.need(n + 9, f"{n} readings, two poses and the ipc_timestamp")
    r = f.numbers(2, 2 + n, "a range")
    p = f.numbers(2 + n, 9 + n, "a pose or the ipc_timestamp")
    out.scans.append(_Scan(f.line, f.kind, float(p[6]), r, laser=p[0:3], robot=p[3:6]))


def _parse_laser(f: _Fields, out: _Parsed) -> None:
    """``ROBOTLASER1`` (with both poses) and ``RAWLASERn`` (without a pose): a scan stating its geometry."""
    head = f.numbers(1, min(8, len(f.tok)), "the laser's settings")
    f.need(9, "the laser's settings and the number of readings")
    n = f.count(8, "the number of readings")
    f.need(10 + n, f"{n} readings and the number of remission values")
    r = f.numbers(9, 9 + n, "a range")
    m = f.count(9 + n, "the number of remission values")
    j = 10 + n + m
    scan = _Scan(f.line, f.kind, 0.0, r, start=float(head[1]), step=float(head[3]), max_range=float(head[4]))
    if f.kind == "ROBOTLASER1":
        f.need(j + 12, f"{n} readings, {m} remission values, two poses, 5 values and the ipc_timestamp")
        p = f.numbers(j, j + 12, "a pose, velocity, safety value or the ipc_timestamp")
        scan.laser, scan.robot, scan.time = p[0:3], p[3:6], float(p[11])
    else:
        f.need(j + 1, f"{n} readings, {m} remission values and the ipc_timestamp")
        scan.time = float(f.numbers(j, j + 1, "the ipc_timestamp")[0])
    out.scans.append(scan)


def _parse_odom(f: _Fields, out: _Parsed) -> None:
    """``ODOM x y theta tv rv accel ipc_timestamp ...``: the odometry pose, kept as ``(t, x, y, theta)``."""
    f.need(8, "x, y, theta, tv, rv, accel and the ipc_timestamp")
    p = f.numbers(1, 8, "a pose, velocity or the ipc_timestamp")
    out.odom_line.append(f.line)
    out.odom.append(np.array([p[6], p[0], p[1], p[2]]))


#: The parser of each message type read; every other type is skipped.
_PARSERS = {"FLASER": _parse_flaser, "ROBOTLASER1": _parse_laser, "ODOM": _parse_odom} | {
    k: _parse_laser for k in _RAWLASER
}


def _parse(path: Path) -> _Parsed:
    """Every scan and ODOM line of the file, in file order, with its 1-based line number."""
    text = _lines(path)
    out = _Parsed(path, [], [], [], {})
    comments = 0
    skipped: dict[str, int] = {}
    for k, raw in enumerate(text):
        tok = raw.split()
        if not tok or tok[0].startswith("#"):
            comments += 1
            continue
        parser = _PARSERS.get(tok[0])
        if parser is None:
            skipped[tok[0]] = skipped.get(tok[0], 0) + 1
        else:
            parser(_Fields(path, k + 1, tok[0], tok), out)
    out.counts = dict(lines=len(text), comments=comments, skipped=skipped)
    return out


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def _between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a^-1 * b`` for ``(..., 3)`` poses: ``b`` in the frame of ``a``."""
    d = b[..., :2] - a[..., :2]
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1], _wrap(b[..., 2] - a[..., 2])], -1)


def _steps_back(t: np.ndarray) -> int:
    return int(np.sum(np.diff(t) < 0))


def _check_duplicates(path: Path, t: np.ndarray, poses: np.ndarray, lines: np.ndarray, what: str) -> None:
    """Equal time stamps must carry equal poses (sorted inputs)."""
    same = np.flatnonzero((np.diff(t) == 0) & np.any(np.abs(np.diff(poses, axis=0)) > 1e-9, axis=1))
    if same.size:
        i = int(same[0])
        a, b = sorted((int(lines[i]), int(lines[i + 1])))
        raise LogFormatError(
            f"{path} line {b}: {what} at time {float(t[i + 1])!r} has the same ipc_timestamp as line {a} but a different "
            f"pose; expected one pose per time stamp"
        )


def _readings_per_scan(file: Path, parsed: _Parsed) -> int:
    """The number of readings every scan line has, or a LogFormatError (no scans, or counts that differ)."""
    scans = parsed.scans
    if not scans:
        raise LogFormatError(
            f"{file}: no laser scans; expected FLASER, ROBOTLASER1 or RAWLASER1-4 lines "
            f"({parsed.counts['lines']} lines, {len(parsed.odom)} ODOM)"
        )
    first = scans[0]
    n = first.ranges.size
    for s in scans:
        if s.ranges.size != n:
            raise LogFormatError(
                f"{file} line {s.line} ({s.kind}): {s.ranges.size} readings, but line {first.line} has {n}; "
                f"expected the same number of readings on every scan line"
            )
    return n


def _beam_angles(
    file: Path, scans: list, n: int, laser_start_deg: Optional[float], laser_step_deg: Optional[float]
) -> np.ndarray:
    """The beam angles (rad): the overrides, else the first line that states them, else the convention."""
    stated = next((s for s in scans if s.start is not None), None)
    for s in scans:
        if (
            stated is not None
            and s.start is not None
            and (abs(s.start - stated.start) > 1e-6 or abs(s.step - stated.step) > 1e-6)
        ):
            raise LogFormatError(
                f"{file} line {s.line} ({s.kind}): start angle {s.start!r} and resolution {s.step!r} differ from "
                f"line {stated.line}'s ({stated.start!r}, {stated.step!r}); expected one laser geometry"
            )
    if stated is not None:
        start_deg, step_deg = math.degrees(stated.start), math.degrees(stated.step)
    else:
        start_deg, step_deg = beam_convention(n)
    start_deg = start_deg if laser_start_deg is None else float(laser_start_deg)
    step_deg = step_deg if laser_step_deg is None else float(laser_step_deg)
    if not step_deg > 0:
        raise ValueError(f"{file}: the beam spacing must be > 0 deg, got {step_deg}")
    return np.deg2rad(start_deg + step_deg * np.arange(n))


def _no_return_threshold(file: Path, scans: list, no_return: Optional[float]) -> float:
    """Readings at or above this are no returns: ``no_return``, else the first stated range limit, else the SICK's."""
    limit = next((s.max_range for s in scans if s.max_range is not None and s.max_range > 0), None)
    threshold = float(no_return) if no_return is not None else (limit if limit is not None else SICK_NO_RETURN)
    if not threshold > 0:
        raise ValueError(f"{file}: the no-return threshold must be > 0 m, got {threshold}")
    return threshold


def _ranges(file: Path, scans: list, n: int, threshold: float) -> np.ndarray:
    """``(S, n)`` the scans' readings, no returns set to ``threshold``; a LogFormatError for a negative one."""
    ranges = np.stack([s.ranges for s in scans]) if n else np.zeros((len(scans), 0))
    neg = np.argwhere(ranges < 0)
    if neg.size:
        i, b = (int(v) for v in neg[0])
        raise LogFormatError(
            f"{file} line {scans[i].line} ({scans[i].kind}, reading {b + 1}): expected a range >= 0, got "
            f"{ranges[i, b]!r}"
        )
    return np.where(ranges >= threshold, threshold, ranges)


def _posed_scans(file: Path, scans: list, t: np.ndarray, lines: np.ndarray) -> tuple[np.ndarray, Optional[np.ndarray]]:
    """``(S, 3)`` the robot pose the scan lines state (NaN for a line without one) and the laser's mounting
    (None without a posed line); a LogFormatError for a mounting that changes or two poses at one time."""
    posed = np.array([s.robot is not None for s in scans])
    odom = np.full((len(scans), 3), np.nan)
    if not posed.any():
        return odom, None
    robot = np.stack([s.robot for s in scans if s.robot is not None])
    laser = np.stack([s.laser for s in scans if s.laser is not None])
    m = _between(robot, laser)
    mount = m[0]
    dev = _between(np.broadcast_to(mount, m.shape), m)
    bad = np.flatnonzero((np.hypot(dev[:, 0], dev[:, 1]) > MOUNT_TOL_M) | (np.abs(dev[:, 2]) > MOUNT_TOL_RAD))
    if bad.size:
        ln = lines[posed][int(bad[0])]
        raise LogFormatError(
            f"{file} line {ln}: the laser's pose relative to the robot's, {tuple(round(float(v), 4) for v in m[bad[0]])}, differs "
            f"from line {lines[posed][0]}'s, {tuple(round(float(v), 4) for v in mount)}; expected a fixed mounting (within "
            f"{MOUNT_TOL_M} m, {MOUNT_TOL_RAD} rad)"
        )
    odom[posed] = robot
    _check_duplicates(file, t[posed], robot, lines[posed], "a scan")
    return odom, mount


def _odom_track(file: Path, parsed: _Parsed) -> tuple[Optional[np.ndarray], int]:
    """``(K, 4)`` the ODOM lines' ``(t, x, y, theta)`` sorted by time (None without any) and how many of them
    step back in time; a LogFormatError for two poses at one time."""
    if not parsed.odom:
        return None, 0
    o = np.stack(parsed.odom)
    o_lines = np.array(parsed.odom_line)
    out_of_order = _steps_back(o[:, 0])
    k = np.argsort(o[:, 0], kind="stable")
    o, o_lines = o[k], o_lines[k]
    _check_duplicates(file, o[:, 0], o[:, 1:], o_lines, "an ODOM line")
    return o, out_of_order


def _interpolate_unposed(
    file: Path, scans: list, t: np.ndarray, lines: np.ndarray, odom: np.ndarray, o: Optional[np.ndarray]
) -> np.ndarray:
    """Fill in ``odom`` (in place) at the scans without a pose from the ODOM track ``o``: position linearly,
    heading along the shorter arc. Returns which scans to keep (those without a pose outside the track's
    span are dropped); a LogFormatError when there is no track or no scan to keep."""
    need = np.array([s.robot is None for s in scans])
    if not need.any():
        return np.ones(len(scans), bool)
    if o is None:
        ln = lines[need][0]
        raise LogFormatError(
            f"{file} line {ln} ({scans[int(np.flatnonzero(need)[0])].kind}): a scan without a pose, and the file "
            f"has no ODOM lines to interpolate one from"
        )
    _, keep = np.unique(o[:, 0], return_index=True)
    o = o[keep]
    inside = (t >= o[0, 0]) & (t <= o[-1, 0])
    tq = t[need]
    x = np.interp(tq, o[:, 0], o[:, 1])
    y = np.interp(tq, o[:, 0], o[:, 2])
    # the angle on the circle: interpolate the unwrapped heading
    th = _wrap(np.interp(tq, o[:, 0], np.unwrap(o[:, 3])))
    odom[need] = np.stack([x, y, th], axis=1)
    drop = need & ~inside
    if int(drop.sum()) == len(scans):
        raise LogFormatError(
            f"{file}: no scan lies within the time span of the ODOM lines ({o[0, 0]!r} to {o[-1, 0]!r}); no pose "
            f"to interpolate"
        )
    return ~drop


def read_carmen(
    path: str | os.PathLike,
    *,
    laser_start_deg: Optional[float] = None,
    laser_step_deg: Optional[float] = None,
    no_return: Optional[float] = None,
) -> tuple[LaserOdomLog, CarmenCounts]:
    """Read a CARMEN log; :func:`load_carmen` with what was found besides the scans.

    Args: as :func:`load_carmen`.

    Returns:
        ``(log, counts)``: the :class:`LaserOdomLog` and the :class:`CarmenCounts`.
    """
    file = find_carmen_file(path)
    parsed = _parse(file)
    n = _readings_per_scan(file, parsed)
    scans = parsed.scans
    angles = _beam_angles(file, scans, n, laser_start_deg, laser_step_deg)
    threshold = _no_return_threshold(file, scans, no_return)
    ranges = _ranges(file, scans, n, threshold)
    lines = np.array([s.line for s in scans])
    t = np.array([s.time for s in scans])
    out_of_order = _steps_back(t)
    order = np.argsort(t, kind="stable")
    t, ranges, lines, scans = t[order], ranges[order], lines[order], [scans[i] for i in order]
    odom, mount = _posed_scans(file, scans, t, lines)
    o, odom_steps_back = _odom_track(file, parsed)
    out_of_order += odom_steps_back
    keep = _interpolate_unposed(file, scans, t, lines, odom, o)
    log = LaserOdomLog(
        scans=LaserScans(t[keep], ranges[keep], angles, max_range=threshold, source=str(file)),
        odom=odom[keep],
        laser_pose=np.zeros(3) if mount is None else mount,
        out_of_order=out_of_order,
        source=str(file),
    )
    counts = CarmenCounts(
        lines=parsed.counts["lines"],
        scans=len(scans),
        odom=len(parsed.odom),
        comments=parsed.counts["comments"],
        skipped=parsed.counts["skipped"],
        out_of_order=out_of_order,
        dropped=int(np.sum(~keep)),
    )
    return log, counts


def load_carmen(
    path: str | os.PathLike,
    *,
    laser_start_deg: Optional[float] = None,
    laser_step_deg: Optional[float] = None,
    no_return: Optional[float] = None,
) -> LaserOdomLog:
    """Read the laser scans and odometry of a CARMEN log.

    Beam angles (0 straight ahead, left positive) are those a ``ROBOTLASER1`` or ``RAWLASERn`` line
    states; ``FLASER`` lines state none and follow the usual convention (:func:`beam_convention`:
    180 or 181 readings 1 deg apart, 360 or 361 readings 0.5 deg apart, from -90 deg). Readings at
    or above the no-return threshold are set to it, the scans' ``max_range``. The scans are sorted
    by ``ipc_timestamp``; ``out_of_order`` counts the scan and ``ODOM`` lines whose time is below the
    previous one's. The odometry pose at a scan is the line's robot pose (``FLASER``'s odom pose,
    ``ROBOTLASER1``'s robot pose); the laser's mounting is the robot pose^-1 * laser pose, which must
    stay within :data:`MOUNT_TOL_M` / :data:`MOUNT_TOL_RAD` of the first line's. A ``RAWLASERn`` scan's
    pose is interpolated from the ``ODOM`` lines (position linearly, heading along the shorter arc)
    with the mounting at the origin; such scans outside the time span of the ``ODOM`` lines are dropped.
    Two scans, or two ``ODOM`` lines, with the same time stamp must have the same pose.

    Args:
        path: a ``.clf`` or ``.log`` file (optionally ``.gz``), or a directory holding exactly one
            (:func:`find_carmen_file`).
        laser_start_deg: the first beam's angle (deg) for every scan line; None: the line's, else the convention.
        laser_step_deg: the spacing of the beams (deg); None: the line's, else the convention.
        no_return: readings at or above this (m) are no returns; None: the ``max_range`` the scan
            lines state, else :data:`SICK_NO_RETURN` (80 m).

    Returns:
        The :class:`~nanoslam_jax.data.LaserOdomLog`: scans, the robot's odometry pose at each, the mounting.

    Raises:
        FileNotFoundError: no such file, or a directory without exactly one CARMEN log.
        LogFormatError: a malformed file: too few fields for a line's readings, a field that is not a
            finite number, readings per scan changing between lines, a changing mounting, two poses
            at one time stamp, or no scans; the message names the file and the 1-based line.
    """
    return read_carmen(path, laser_start_deg=laser_start_deg, laser_step_deg=laser_step_deg, no_return=no_return)[0]
