"""A run as a Rerun recording (``output.rerun``): what the viewer replays, scan by scan.

:func:`write_rerun` takes host arrays only (the run's outputs after it finished) and writes an
``.rrd`` file with the optional ``rerun-sdk`` package (``pip install 'nanoslam-jax[viz]'``). It logs
on two time lines, ``scan`` (the segment's index) and ``time`` (its time, s):

- ``world/path``: the path so far, a line strip (at most ``path_points`` poses, the current last);
- ``world/pose``: the pose, a point and a heading arrow, and its exact ``x, y, phi`` in float64 as
  the component ``pose`` (the viewer's points are float32);
- ``world/particles``: every particle's position, when the run kept them;
- ``world/ellipse``: the 2-sigma ellipse of the position's covariance, at the scans it is known at;
- ``world/scan``: the scan's points in the world frame, projected from the pose;
- ``world/landmarks``: the final map, at the last scan (points; lines as long segments).
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple, Optional, Sequence

import numpy as np

#: Colours (RGB) of the recording's entities.
_PATH, _POSE, _PARTICLES, _ELLIPSE, _SCAN = (
    (40, 110, 220),
    (220, 40, 40),
    (150, 150, 150),
    (230, 140, 20),
    (40, 170, 80),
)
_CONFIRMED, _TENTATIVE = (20, 20, 20), (170, 170, 170)


def _require_rerun():
    try:
        import rerun
    except ImportError:
        raise ImportError(
            "output.rerun: writing a Rerun recording needs the rerun-sdk package; "
            "install it with pip install 'nanoslam-jax[viz]' (or pip install rerun-sdk), or unset output.rerun"
        ) from None
    return rerun


def to_world(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``(n, 2)`` points in the frame of ``pose = (x, y, phi)`` (forward, left) in the world frame."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    return np.c_[pose[0] + c * p[:, 0] - s * p[:, 1], pose[1] + s * p[:, 0] + c * p[:, 1]]


def polar_points(r: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``(n, 2)`` the points at ranges ``r`` and bearings ``b`` (rad, 0 straight ahead, left positive)."""
    r, b = np.asarray(r, dtype=float).ravel(), np.asarray(b, dtype=float).ravel()
    return np.c_[r * np.cos(b), r * np.sin(b)]


def ellipse(center: np.ndarray, cov: np.ndarray, sigmas: float = 2.0, n: int = 48) -> np.ndarray:
    """``(n + 1, 2)`` the closed ``sigmas``-sigma ellipse of the 2x2 covariance ``cov`` about ``center``."""
    w, v = np.linalg.eigh(0.5 * (cov + cov.T))
    a = np.linspace(0.0, 2 * np.pi, n + 1)
    unit = np.c_[np.cos(a), np.sin(a)] * (sigmas * np.sqrt(np.clip(w, 0.0, None)))
    return np.asarray(center)[:2] + unit @ v.T


def line_segments(lines: np.ndarray, half_length: float) -> np.ndarray:
    """``(L, 2, 2)`` a segment ``2 * half_length`` long about the foot point of each line ``(rho, alpha)``
    (the line of points ``p`` with ``p . (cos alpha, sin alpha) = rho``)."""
    rho, alpha = np.asarray(lines, dtype=float)[:, 0], np.asarray(lines, dtype=float)[:, 1]
    foot = np.c_[rho * np.cos(alpha), rho * np.sin(alpha)]
    d = np.c_[-np.sin(alpha), np.cos(alpha)] * half_length
    return np.stack([foot - d, foot + d], axis=1)


def _decimated(path: np.ndarray, most: int) -> np.ndarray:
    """The rows of ``path`` at most ``most`` of them, evenly spaced, always with the last."""
    if len(path) <= most:
        return path
    keep = np.unique(np.r_[np.linspace(0, len(path) - 1, most).round().astype(int), len(path) - 1])
    return path[keep]


class RerunMap(NamedTuple):
    """The final map of a run, logged at its last scan.

    Attributes:
        landmarks: ``(L, 2)`` the point landmarks, or None.
        confirmed: ``(L,)`` which of them are confirmed (drawn dark; the others grey), or None: all.
        lines: ``(M, 2)`` the lines ``(rho, alpha)`` in the world frame, or None.
    """

    landmarks: Optional[np.ndarray] = None
    confirmed: Optional[np.ndarray] = None
    lines: Optional[np.ndarray] = None


class RecordingOptions(NamedTuple):
    """How the recording is written.

    Attributes:
        name: the recording's application id.
        path_points: the most poses ``world/path`` holds at one scan (evenly spaced, the current pose
            always last): the recording grows with scans times this.
    """

    name: str = "nanoslam"
    path_points: int = 500


def _per_scan_cov(pose_cov: Optional[np.ndarray], n: int) -> Optional[np.ndarray]:
    """``(S, 3, 3)`` the pose covariance at each scan: as given, or a ``(3, 3)`` one at the last scan
    (NaN before it); None when there is none."""
    cov = None if pose_cov is None else np.asarray(pose_cov, dtype=float)
    if cov is not None and cov.shape == (3, 3):
        cov = np.concatenate([np.full((n - 1, 3, 3), np.nan), cov[None]]) if n else cov[None][:0]
    return cov


def _log_scan(rr, rec, x: np.ndarray, path: np.ndarray, particles, cov, scan_points) -> None:
    """Log one scan at pose ``x``: the path so far (``path``, already decimated), the pose, and the
    particles, the covariance's ellipse and the scan's points where given."""
    rec.log("world/path", rr.LineStrips2D([path], colors=[_PATH]))
    rec.log(
        "world/pose",
        rr.Points2D([x[:2]], colors=[_POSE], radii=[0.3]),
        rr.Arrows2D(origins=[x[:2]], vectors=[[2.0 * np.cos(x[2]), 2.0 * np.sin(x[2])]], colors=[_POSE]),
        rr.AnyValues(pose=x.copy()),
    )
    if particles is not None:
        rec.log("world/particles", rr.Points2D(np.asarray(particles)[:, :2], colors=[_PARTICLES], radii=[0.1]))
    if cov is not None and np.all(np.isfinite(cov[:2, :2])):
        rec.log("world/ellipse", rr.LineStrips2D([ellipse(x, cov[:2, :2])], colors=[_ELLIPSE]))
    if scan_points is not None:
        rec.log("world/scan", rr.Points2D(to_world(x, scan_points), colors=[_SCAN], radii=[0.08]))


def _log_map(rr, rec, poses: np.ndarray, final_map: RerunMap) -> None:
    """Log the final map: its point landmarks, and its lines as segments long enough to cross the path."""
    landmarks, confirmed, lines = final_map
    if landmarks is not None and len(landmarks):
        lm = np.asarray(landmarks, dtype=float).reshape(-1, 2)
        ok = np.ones(len(lm), bool) if confirmed is None else np.asarray(confirmed, bool)
        colors = np.where(ok[:, None], _CONFIRMED, _TENTATIVE).astype(np.uint8)
        rec.log("world/landmarks", rr.Points2D(lm, colors=colors, radii=[0.4]))
    if lines is not None and len(lines):
        finite = poses[np.all(np.isfinite(poses), axis=1), :2]
        extent = float(np.ptp(finite, axis=0).max()) if len(finite) else 0.0
        strips = line_segments(np.asarray(lines)[:, :2], 0.5 * extent + 10.0)
        rec.log("world/lines", rr.LineStrips2D(list(strips), colors=[_CONFIRMED]))


def write_rerun(
    path: str | Path,
    times: np.ndarray,
    poses: np.ndarray,
    scan_points: Optional[Sequence[np.ndarray]] = None,
    *,
    particles: Optional[np.ndarray] = None,
    pose_cov: Optional[np.ndarray] = None,
    final_map: RerunMap = RerunMap(),
    options: RecordingOptions = RecordingOptions(),
) -> Path:
    """Write a Rerun recording (``.rrd``) of a run, one time step per scan (see the module's docs).

    Args:
        path: the file written (its folder is created).
        times: ``(S,)`` the time of each scan (s).
        poses: ``(S, 3)`` the estimated pose ``(x, y, phi)`` at each scan.
        scan_points: per scan, ``(n, 2)`` its points in the frame of the pose (forward, left), or
            None: no ``world/scan``.
        particles: ``(S, P, 3)`` every particle's pose at each scan, or None.
        pose_cov: the pose's covariance: ``(S, 3, 3)`` at each scan (NaN where unknown), or
            ``(3, 3)`` at the last scan only, or None.
        final_map: the final map (:class:`RerunMap`: landmarks, which are confirmed, lines).
        options: the recording's name and the length of its path (:class:`RecordingOptions`).

    Returns:
        The file written.

    Raises:
        ImportError: ``rerun-sdk`` is not installed (the message says how to install it).
    """
    rr = _require_rerun()
    times = np.asarray(times, dtype=float)
    poses = np.asarray(poses, dtype=float)
    n = times.shape[0]
    if poses.shape != (n, 3):
        raise ValueError(f"write_rerun: poses must be (S, 3) = ({n}, 3) for {n} times, got {poses.shape}")
    if scan_points is not None and len(scan_points) != n:
        raise ValueError(f"write_rerun: {len(scan_points)} scans of points for {n} times")
    cov = _per_scan_cov(pose_cov, n)
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream(options.name, make_default=False, make_thread_default=False)
    rec.save(str(out))
    try:
        for i in range(n):
            rec.set_time("scan", sequence=i)
            rec.set_time("time", duration=float(times[i]))
            x = poses[i]
            if not np.all(np.isfinite(x)):
                continue  # a non-finite pose: nothing drawn at this scan
            _log_scan(
                rr,
                rec,
                x,
                _decimated(poses[: i + 1, :2], options.path_points),
                None if particles is None else particles[i],
                None if cov is None else cov[i],
                None if scan_points is None else scan_points[i],
            )
        if n:
            _log_map(rr, rec, poses, final_map)
        rec.flush()
    finally:
        rec.disconnect()
    return out
