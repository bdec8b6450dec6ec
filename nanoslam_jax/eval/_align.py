"""Rigid alignment in the plane: rotation matrices, the best-fit rigid transform of one point set
onto another, and the root mean square of an error vector."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["rigid_align", "rotation_matrix"]


def rotation_matrix(deg: float) -> np.ndarray:
    """``(2, 2)`` counter-clockwise rotation matrix by ``deg`` degrees."""
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s], [s, c]])


def rigid_align(est: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Best-fit 2-D rigid transform of ``est`` onto ``ref`` (least squares, no scale).

    Minimises ``sum_i |R est_i + t - ref_i|^2`` over rotations ``R`` (det +1: a reflection is
    never returned; Kabsch/Umeyama without scale) and translations ``t``.

    Args:
        est: ``(n, 2)`` points to move.
        ref: ``(n, 2)`` corresponding reference points.

    Returns:
        ``(R, t, aligned)``: ``(2, 2)`` rotation, ``(2,)`` translation and ``(n, 2)``
        ``est @ R.T + t``. With one point, ``R`` is the identity.
    """
    est = np.asarray(est, dtype=float)
    ref = np.asarray(ref, dtype=float)
    if est.shape != ref.shape or est.ndim != 2 or est.shape[1] != 2 or est.shape[0] == 0:
        raise ValueError(f"est and ref must be matching non-empty (n, 2) arrays, got {est.shape} and {ref.shape}")
    mu_e, mu_r = est.mean(axis=0), ref.mean(axis=0)
    if est.shape[0] == 1:
        R = np.eye(2)
    else:
        h = (est - mu_e).T @ (ref - mu_r)  # cross-covariance, (2, 2)
        u, _, vt = np.linalg.svd(h)
        d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
        R = vt.T @ np.diag([1.0, d]) @ u.T
    t = mu_r - R @ mu_e
    return R, t, est @ R.T + t


def _rmse(err: np.ndarray) -> float:
    return float(np.sqrt(np.mean(err**2))) if err.size else float("nan")
