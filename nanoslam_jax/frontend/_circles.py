"""Least-squares circles fitted to many groups of points at once: the algebraic (Kasa) fit in each
group's centred coordinates, refined by Gauss-Newton steps on the geometric residuals
``|p - c| - R``."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from jaxtyping import Float, Int

__all__ = ["CircleFit", "fit_circle", "fit_circles"]


class CircleFit(NamedTuple):
    """Circles fitted to groups of points (NaN where a group has fewer than 3 points or is degenerate).

    Attributes:
        cx, cy: centres.
        radius: radii.
        rms: RMS geometric residual ``|p - c| - R``.
    """

    cx: Float[np.ndarray, " G"]
    cy: Float[np.ndarray, " G"]
    radius: Float[np.ndarray, " G"]
    rms: Float[np.ndarray, " G"]


def _group_sum(values: np.ndarray, starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Sums over contiguous groups (``values[starts[g]:starts[g] + counts[g]]``)."""
    cs = np.concatenate([[0.0], np.cumsum(values)])
    return cs[starts + counts] - cs[starts]


def fit_circles(
    x: Float[np.ndarray, " N"],
    y: Float[np.ndarray, " N"],
    starts: Int[np.ndarray, " G"],
    counts: Int[np.ndarray, " G"],
    iterations: int = 4,
) -> CircleFit:
    """Fit one circle to each contiguous group of points.

    Args:
        x, y: the points, groups contiguous.
        starts: index of each group's first point.
        counts: points per group (groups of fewer than 3 points get NaN).
        iterations: Gauss-Newton steps after the algebraic fit.
    """
    starts = np.asarray(starts, dtype=np.int64)
    counts = np.asarray(counts, dtype=np.int64)
    sel = np.repeat(np.arange(starts.size), counts)
    idx = np.repeat(starts - np.concatenate([[0], np.cumsum(counts)[:-1]]), counts) + np.arange(counts.sum())
    px, py = x[idx], y[idx]
    off = np.concatenate([[0], np.cumsum(counts)[:-1]])
    n = np.maximum(counts, 1).astype(np.float64)
    mx, my = _group_sum(px, off, counts) / n, _group_sum(py, off, counts) / n
    u, v = px - mx[sel], py - my[sel]
    s = lambda w: _group_sum(w, off, counts)  # noqa: E731
    suu, suv, svv = s(u * u), s(u * v), s(v * v)
    z = u * u + v * v
    bu, bv = 0.5 * s(u * z), 0.5 * s(v * z)
    det = suu * svv - suv * suv
    ok = (counts >= 3) & (np.abs(det) > 1e-18 * np.maximum((suu + svv) ** 2, 1e-300))
    det = np.where(ok, det, 1.0)
    uc = (svv * bu - suv * bv) / det
    vc = (suu * bv - suv * bu) / det
    rad = np.sqrt(uc * uc + vc * vc + (suu + svv) / n)
    for _ in range(iterations):
        du, dv = u - uc[sel], v - vc[sel]
        d = np.maximum(np.hypot(du, dv), 1e-12)
        e = d - rad[sel]
        ju, jv = -du / d, -dv / d  # d e / d (uc, vc); d e / d R = -1
        a11, a12, a13 = s(ju * ju), s(ju * jv), -s(ju)
        a22, a23, a33 = s(jv * jv), -s(jv), n
        g1, g2, g3 = s(ju * e), s(jv * e), -s(e)
        mat = np.stack(
            [np.stack([a11, a12, a13], -1), np.stack([a12, a22, a23], -1), np.stack([a13, a23, a33], -1)], -2
        )
        mat = mat + 1e-9 * np.eye(3) * (1.0 + np.trace(mat, axis1=-2, axis2=-1))[:, None, None]
        rhs = np.stack([g1, g2, g3], -1)
        step = np.linalg.solve(np.where(ok[:, None, None], mat, np.eye(3)), -rhs[..., None])[..., 0]
        step = np.where(ok[:, None] & np.isfinite(step), step, 0.0)
        uc, vc, rad = uc + step[:, 0], vc + step[:, 1], np.abs(rad + step[:, 2])
    e = np.hypot(u - uc[sel], v - vc[sel]) - rad[sel]
    rms = np.sqrt(s(e * e) / n)
    nan = np.where(ok, 1.0, np.nan)
    return CircleFit((uc + mx) * nan, (vc + my) * nan, rad * nan, rms * nan)


def fit_circle(x: Float[np.ndarray, " N"], y: Float[np.ndarray, " N"], iterations: int = 4) -> CircleFit:
    """One circle through the points ``x``, ``y`` (fields are 0-d arrays)."""
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    fit = fit_circles(x, y, np.array([0]), np.array([x.size]), iterations)
    return CircleFit(*(f[0] for f in fit))
