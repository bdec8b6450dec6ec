"""Scoring a path against a reference path (e.g. a corrected log's): NumPy only.

- the trajectory error: positions after the best-fit rigid (SE(2)) alignment of the path onto the
  reference (:func:`~nanoslam_jax.eval.metrics.rigid_align`), as RMSE and worst error;
- the relative-motion error: for each pair of consecutive reference poses, the motion between them
  (``ref_i^-1 * ref_{i+1}``) against the path's over the same pair, as the mean translation error
  (m) and the mean rotation error (deg). It needs no alignment and does not grow with drift.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nanoslam_jax.eval._align import rigid_align

__all__ = [
    "ReferencePath",
    "align_on_reference",
    "reference_report",
    "relative_motion_error",
    "score_reference",
    "trajectory_error",
]


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def _between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = b[..., :2] - a[..., :2]
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1], _wrap(b[..., 2] - a[..., 2])], -1)


def _check(est: np.ndarray, ref: np.ndarray, cols: int) -> tuple[np.ndarray, np.ndarray]:
    est, ref = np.asarray(est, dtype=np.float64), np.asarray(ref, dtype=np.float64)
    if est.shape != ref.shape or est.ndim != 2 or est.shape[1] < cols or est.shape[0] == 0:
        raise ValueError(f"est and ref must be matching non-empty (n, {cols}) arrays, got {est.shape} and {ref.shape}")
    return est, ref


def trajectory_error(est: np.ndarray, ref: np.ndarray) -> dict:
    """Position error of a path after its best-fit rigid alignment onto the reference.

    Args:
        est: ``(n, 2+)`` the path's positions (further columns ignored) at the reference poses.
        ref: ``(n, 2+)`` the reference positions.

    Returns:
        ``rmse`` and ``max`` (m) of the aligned position errors, ``rotation_deg`` of the alignment.
    """
    est, ref = _check(est, ref, 2)
    R, _, aligned = rigid_align(est[:, :2], ref[:, :2])
    err = np.linalg.norm(aligned - ref[:, :2], axis=1)
    return {
        "rmse": float(np.sqrt(np.mean(err**2))),
        "max": float(np.max(err)),
        "rotation_deg": float(np.degrees(np.arctan2(R[1, 0], R[0, 0]))),
    }


def relative_motion_error(est: np.ndarray, ref: np.ndarray) -> dict:
    """Error of the motion between consecutive reference poses.

    Args:
        est: ``(n, 3)`` the path's poses ``(x, y, theta)`` at the reference poses.
        ref: ``(n, 3)`` the reference poses.

    Returns:
        ``translation`` (m) and ``rotation_deg``: the mean over the ``n - 1`` pairs of the norm of the
        translation difference and the absolute (wrapped) rotation difference of the relative motions
        (NaN with fewer than two poses).
    """
    est, ref = _check(est, ref, 3)
    if est.shape[0] < 2:
        return {"translation": float("nan"), "rotation_deg": float("nan")}
    de, dr = _between(est[:-1], est[1:]), _between(ref[:-1], ref[1:])
    return {
        "translation": float(np.mean(np.linalg.norm(de[:, :2] - dr[:, :2], axis=1))),
        "rotation_deg": float(np.degrees(np.mean(np.abs(_wrap(de[:, 2] - dr[:, 2]))))),
    }


def reference_report(est: np.ndarray, ref: np.ndarray, prefix: str = "ref_") -> dict:
    """Both errors of a path as flat metrics: ``{prefix}rmse``, ``{prefix}max``, ``{prefix}rel_trans``
    (m), ``{prefix}rel_rot_deg`` and ``{prefix}n`` (poses compared).

    Args:
        est: ``(n, 3)`` the path's poses at the reference poses.
        ref: ``(n, 3)`` the reference poses.
        prefix: the names' prefix (``'ref_'`` for the estimate, ``'dr_ref_'`` for dead reckoning).
    """
    t, r = trajectory_error(est, ref), relative_motion_error(est, ref)
    return {
        f"{prefix}rmse": t["rmse"],
        f"{prefix}max": t["max"],
        f"{prefix}rel_trans": r["translation"],
        f"{prefix}rel_rot_deg": r["rotation_deg"],
        f"{prefix}n": int(np.asarray(est).shape[0]),
    }


@dataclass(frozen=True)
class ReferencePath:
    """A reference path for a run: poses at some scan times.

    Attributes:
        time: ``(R,)`` the times of the scans with a reference pose (s, the log's clock), increasing.
        poses: ``(R, 3)`` the reference poses ``(x, y, theta)`` of the laser (m, m, rad).
        heading_offset: the laser's angle from the robot's heading (rad), added to a path's heading
            (the robot's) before comparing.
        source: the file it came from.
    """

    time: np.ndarray
    poses: np.ndarray
    heading_offset: float = 0.0
    source: str = ""


def _matched(ref: ReferencePath, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each reference pose, the index of the path time it falls on and whether one does
    (within 1 microsecond)."""
    times = np.asarray(times, dtype=np.float64)
    j = np.clip(np.searchsorted(times, ref.time), 0, max(times.size - 1, 0))
    ok = np.abs(times[j] - ref.time) <= 1e-6 if times.size else np.zeros(ref.time.shape, bool)
    return j, ok


def align_on_reference(ref: ReferencePath, times: np.ndarray, est: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A path moved onto the reference by its best-fit rigid alignment at the reference poses, for
    drawing it with the reference.

    Args:
        ref: the reference path.
        times: ``(T,)`` the times of the path's poses (s).
        est: ``(T, 2+)`` the path's poses at ``times``.

    Returns:
        ``(aligned, error)``: ``(T, 2)`` every position of the path after the alignment, and
        ``(n, 2)`` the reference times that are also path times with the aligned position error
        there (m). Both empty when no reference time is a path time.
    """
    est = np.asarray(est, dtype=np.float64)
    j, ok = _matched(ref, times)
    if ok.sum() == 0:
        return np.zeros((0, 2)), np.zeros((0, 2))
    R, t, aligned = rigid_align(est[j[ok], :2], ref.poses[ok, :2])
    err = np.linalg.norm(aligned - ref.poses[ok, :2], axis=1)
    return est[:, :2] @ R.T + t, np.stack([ref.time[ok], err], axis=1)


def score_reference(
    ref: ReferencePath, times: np.ndarray, est: np.ndarray | None, dr: np.ndarray | None = None
) -> dict:
    """The :func:`reference_report` of a run's path (``ref_*``) and of its dead reckoning (``dr_ref_*``).

    Args:
        ref: the reference path.
        times: ``(T,)`` the times of the path's poses (s).
        est: ``(T, 3)`` the estimated poses at ``times``, or None (only dead reckoning's figures).
        dr: ``(T, 3)`` the dead-reckoned poses at ``times``, or None.

    Returns:
        The metrics, compared at the reference times that are also path times (within 1 microsecond);
        ``ref_n`` says how many. Empty when none is.
    """
    j, ok = _matched(ref, times)
    if ok.sum() == 0:
        return {}
    out = {}
    for prefix, path in (("ref_", est), ("dr_ref_", dr)):
        if path is None or not np.all(np.isfinite(path[j[ok]])):
            continue
        p = np.array(path[j[ok]], dtype=np.float64)
        p[:, 2] = _wrap(p[:, 2] + ref.heading_offset)
        out.update(reference_report(p, ref.poses[ok], prefix))
    return out
