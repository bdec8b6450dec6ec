"""Errors of estimated line, arc and point maps against the truth: the second paper's Table 1
(re-exported by :mod:`nanoslam_jax.eval.metrics`)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = [
    "FeatureGates",
    "line_feature_errors",
    "arc_feature_errors",
    "point_feature_errors",
    "break_point_line_errors",
    "line_intersections",
    "feature_map_errors",
]


def _lines_np(lines: np.ndarray) -> np.ndarray:
    """``(n, 2)`` lines ``(rho, alpha)`` in normal form, normalised: ``rho >= 0``, ``alpha`` in (-pi, pi]."""
    a = np.asarray(lines, dtype=float).reshape(-1, 2) if np.size(lines) else np.zeros((0, 2))
    flip = a[:, 0] < 0
    alpha = np.where(flip, a[:, 1] + np.pi, a[:, 1])
    alpha = np.mod(alpha + np.pi, 2.0 * np.pi) - np.pi
    return np.stack([np.abs(a[:, 0]), np.where(alpha <= -np.pi, alpha + 2.0 * np.pi, alpha)], axis=1)


def _wrap_np(a: np.ndarray) -> np.ndarray:
    return np.mod(np.asarray(a) + np.pi, 2.0 * np.pi) - np.pi


def _oriented_differences(est: np.ndarray, tru: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(E, L)`` differences ``(rho_e - rho_t, alpha_e - alpha_t)`` of every estimated line from every
    true one, each estimate written in the orientation of its normal nearer the true line's
    (``(rho, alpha)`` or ``(-rho, alpha + pi)``, the same line)."""
    d_alpha = _wrap_np(est[:, None, 1] - tru[None, :, 1])
    flip = np.abs(d_alpha) > np.pi / 2
    d_rho = np.where(flip, -est[:, None, 0], est[:, None, 0]) - tru[None, :, 0]
    return d_rho, np.where(flip, _wrap_np(d_alpha + np.pi), d_alpha)


def gated_assignment(cost: np.ndarray, gate: float) -> tuple[np.ndarray, np.ndarray]:
    """The one-to-one assignment minimising the sum of ``min(cost, gate)`` (scipy's
    ``linear_sum_assignment``) over an ``(E, L)`` cost matrix: its pairs ``(rows, cols)`` with
    ``cost <= gate`` (pairs beyond the gate dropped; none for an empty matrix). A non-finite cost
    (an estimate of a diverged run) is beyond the gate."""
    from scipy.optimize import linear_sum_assignment

    if cost.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    rows, cols = linear_sum_assignment(np.where(cost <= gate, cost, gate))
    keep = cost[rows, cols] <= gate
    return rows[keep], cols[keep]


def _hungarian(cost: np.ndarray, gate: float) -> np.ndarray:
    """``(L,)`` the estimate row assigned to each column (-1: none) by :func:`gated_assignment`."""
    match = np.full(cost.shape[1], -1, dtype=np.int64)
    rows, cols = gated_assignment(cost, gate)
    match[cols] = rows
    return match


def _paper_form(lines: np.ndarray, steep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Slope and intercept of lines in normal form: ``y = a x + b`` (``a = -cos/sin``, ``b = rho/sin``),
    or where ``steep``, ``x = a' y + c`` (``a' = -sin/cos``, ``c = rho/cos``)."""
    c, s = np.cos(lines[:, 1]), np.sin(lines[:, 1])
    den = np.where(steep, c, s)
    num = np.where(steep, s, c)
    with np.errstate(divide="ignore", invalid="ignore"):
        return -num / den, lines[:, 0] / den


def line_feature_errors(
    est_lines: np.ndarray, true_lines: np.ndarray, gate: float = 0.5, lever: float = 1.0, max_slope: float = 1.0
) -> dict:
    """Errors of estimated lines against true ones, all in normal form ``(rho, alpha)`` in the same frame.

    **Matching**: one-to-one (Hungarian, ``scipy.optimize.linear_sum_assignment``) minimising the
    sum of ``|rho_e - rho_t| + lever |alpha_e - alpha_t|`` (each estimate in the orientation of its
    normal nearer the true line's; ``lever`` in m per rad turns an angle error into a distance),
    pairs costing more than ``gate`` left unmatched.

    **Errors** of each matched true line, estimate minus truth: ``rho`` and ``alpha`` (wrapped);
    and in the second paper's form (its Table 1): ``y = a x + b`` for a line with ``|a| <=
    max_slope``, else ``x = a' y + c`` (the paper's vertical form ``x = c``, eq. 15, with a slope
    about the y axis so that a nearly vertical line has bounded parameters; the paper's vertical
    walls have ``a' = 0``): ``slope`` (``a`` or ``a'``) and ``intercept`` (``b`` or ``c``, m). The
    form is the true line's, and the estimate is written in the same form.

    Args:
        est_lines: ``(E, 2)`` estimated lines.
        true_lines: ``(L, 2)`` true lines.
        gate: the largest matching cost (m).
        lever: the weight of the angle in the matching cost (m per rad).
        max_slope: true lines steeper than this take the form ``x = a' y + c``.

    Returns:
        A dict of ``(L,)`` arrays per true line (NaN where unmatched): ``match`` (the estimate's
        row, -1 where unmatched), ``rho_error``, ``alpha_error``, ``slope_error``,
        ``intercept_error``, ``steep`` (the form ``x = a' y + c``); and ``n_est``, ``n_true``,
        ``n_matched``.
    """
    est, tru = _lines_np(est_lines), _lines_np(true_lines)
    d_rho, d_alpha = _oriented_differences(est, tru)
    match = _hungarian(np.abs(d_rho) + lever * np.abs(d_alpha), gate)
    ok = match >= 0
    n = tru.shape[0]
    rho_err, alpha_err = np.full(n, np.nan), np.full(n, np.nan)
    cols = np.flatnonzero(ok)
    rho_err[cols], alpha_err[cols] = d_rho[match[cols], cols], d_alpha[match[cols], cols]
    steep = np.abs(np.cos(tru[:, 1])) > max_slope * np.abs(np.sin(tru[:, 1]))
    slope_t, icpt_t = _paper_form(tru, steep)
    slope_err, icpt_err = np.full(n, np.nan), np.full(n, np.nan)
    if cols.size:
        # the matched estimate in the true line's orientation: (rho_t + d_rho, alpha_t + d_alpha)
        est_oriented = np.stack([tru[cols, 0] + rho_err[cols], tru[cols, 1] + alpha_err[cols]], axis=1)
        slope_e, icpt_e = _paper_form(est_oriented, steep[cols])
        slope_err[cols], icpt_err[cols] = slope_e - slope_t[cols], icpt_e - icpt_t[cols]
    return {
        "match": match,
        "rho_error": rho_err,
        "alpha_error": alpha_err,
        "slope_error": slope_err,
        "intercept_error": icpt_err,
        "steep": steep,
        "n_est": int(est.shape[0]),
        "n_true": int(n),
        "n_matched": int(ok.sum()),
    }


def arc_feature_errors(est_arcs: np.ndarray, true_arcs: np.ndarray, gate: float = 0.5) -> dict:
    """Errors of estimated arcs (circles) against true ones, ``(xc, yc, R)`` in the same frame.

    **Matching**: one-to-one (Hungarian) minimising the sum of the centre distances, pairs farther
    apart than ``gate`` left unmatched.

    Args:
        est_arcs: ``(E, 3)`` estimated circles.
        true_arcs: ``(L, 3)`` true circles.
        gate: the largest centre distance of a match (m).

    Returns:
        A dict of ``(L,)`` arrays per true arc (NaN where unmatched): ``match`` (-1 where
        unmatched), ``centre_error`` (distance, m), ``radius_error`` (estimate minus truth, m); and
        ``n_est``, ``n_true``, ``n_matched``.
    """
    est = np.asarray(est_arcs, dtype=float).reshape(-1, 3) if np.size(est_arcs) else np.zeros((0, 3))
    tru = np.asarray(true_arcs, dtype=float).reshape(-1, 3) if np.size(true_arcs) else np.zeros((0, 3))
    d = np.hypot(est[:, None, 0] - tru[None, :, 0], est[:, None, 1] - tru[None, :, 1])
    match = _hungarian(d, gate)
    cols = np.flatnonzero(match >= 0)
    centre, radius = np.full(tru.shape[0], np.nan), np.full(tru.shape[0], np.nan)
    centre[cols] = d[match[cols], cols]
    radius[cols] = est[match[cols], 2] - tru[cols, 2]
    return {
        "match": match,
        "centre_error": centre,
        "radius_error": radius,
        "n_est": int(est.shape[0]),
        "n_true": int(tru.shape[0]),
        "n_matched": int(cols.size),
    }


def point_feature_errors(est_points: np.ndarray, true_points: np.ndarray, gate: float = 0.2) -> dict:
    """Errors of estimated point features (break points, corners) against true ones.

    **Matching**: one-to-one (Hungarian) minimising the sum of the distances, pairs farther apart
    than ``gate`` left unmatched.

    Args:
        est_points: ``(E, 2)`` estimated points.
        true_points: ``(L, 2)`` true points.
        gate: the largest distance of a match (m).

    Returns:
        A dict: ``match`` ``(L,)`` (-1 where unmatched), ``error`` ``(L,)`` the distance (m; NaN
        where unmatched), ``n_est``, ``n_true``, ``n_matched``.
    """
    est = np.asarray(est_points, dtype=float).reshape(-1, 2) if np.size(est_points) else np.zeros((0, 2))
    tru = np.asarray(true_points, dtype=float).reshape(-1, 2) if np.size(true_points) else np.zeros((0, 2))
    d = np.hypot(est[:, None, 0] - tru[None, :, 0], est[:, None, 1] - tru[None, :, 1])
    match = _hungarian(d, gate)
    cols = np.flatnonzero(match >= 0)
    err = np.full(tru.shape[0], np.nan)
    err[cols] = d[match[cols], cols]
    return {
        "match": match,
        "error": err,
        "n_est": int(est.shape[0]),
        "n_true": int(tru.shape[0]),
        "n_matched": int(cols.size),
    }


def _point_line_distances(points: np.ndarray, lines: np.ndarray) -> np.ndarray:
    """``(K, L)`` the distance of each point to each line ``(rho, alpha)``."""
    c, s = np.cos(lines[None, :, 1]), np.sin(lines[None, :, 1])
    return np.abs(points[:, None, 0] * c + points[:, None, 1] * s - lines[None, :, 0])


def break_point_line_errors(
    est_lines: np.ndarray, true_lines: np.ndarray, line_match: np.ndarray, break_points: np.ndarray, tol: float = 0.01
) -> dict:
    """Errors of break points where the map holds lines but no segment ends: each true break point's
    distance to the estimated line matched to its own wall's line.

    A map of lines ``(rho, alpha)`` places a wall's end nowhere along the wall; what it places is the
    wall across it. The error of a break point is the distance between it and the estimate of the
    wall it ends (the estimated line's point nearest it), the wall being the true line that passes
    within ``tol`` of it (the nearest one).

    Args:
        est_lines: ``(E, 2)`` estimated lines.
        true_lines: ``(L, 2)`` true lines.
        line_match: ``(L,)`` the estimate matched to each true line, -1 for none
            (:func:`line_feature_errors`'s ``match``).
        break_points: ``(K, 2)`` true break points.
        tol: the largest distance (m) of a break point from its wall's true line.

    Returns:
        A dict: ``line`` ``(K,)`` the true line of each break point (-1: none within ``tol``),
        ``error`` ``(K,)`` the distances (m; NaN where the line is unmatched or there is none),
        ``n_true``, ``n_matched``.
    """
    est, tru = _lines_np(est_lines), _lines_np(true_lines)
    pts = np.asarray(break_points, dtype=float).reshape(-1, 2) if np.size(break_points) else np.zeros((0, 2))
    line = np.full(pts.shape[0], -1, dtype=np.int64)
    err = np.full(pts.shape[0], np.nan)
    if pts.shape[0] and tru.shape[0]:
        d = _point_line_distances(pts, tru)
        near = np.argmin(d, axis=1)
        line = np.where(d[np.arange(pts.shape[0]), near] <= tol, near, -1)
        m = np.where(line >= 0, np.asarray(line_match)[np.maximum(line, 0)], -1)
        ok = m >= 0
        if ok.any():
            err[ok] = np.diagonal(_point_line_distances(pts[ok], est[m[ok]]))
    return {"line": line, "error": err, "n_true": int(pts.shape[0]), "n_matched": int(np.isfinite(err).sum())}


def line_intersections(lines_a: np.ndarray, lines_b: np.ndarray) -> np.ndarray:
    """``(K, 2)`` the intersection of each pair of lines in normal form (NaN where parallel).

    Args:
        lines_a: ``(K, 2)`` lines ``(rho, alpha)``.
        lines_b: ``(K, 2)`` the lines they meet.
    """
    a = np.asarray(lines_a, dtype=float).reshape(-1, 2)
    b = np.asarray(lines_b, dtype=float).reshape(-1, 2)
    det = np.sin(b[:, 1] - a[:, 1])
    ok = np.abs(det) > 1e-12
    det = np.where(ok, det, 1.0)
    x = (a[:, 0] * np.sin(b[:, 1]) - b[:, 0] * np.sin(a[:, 1])) / det
    y = (b[:, 0] * np.cos(a[:, 1]) - a[:, 0] * np.cos(b[:, 1])) / det
    return np.where(ok[:, None], np.stack([x, y], axis=1), np.nan)


def _summary(errors: np.ndarray) -> tuple[float, float]:
    e = np.abs(np.asarray(errors, dtype=float))
    e = e[np.isfinite(e)]
    return (float(np.median(e)), float(e.max())) if e.size else (float("nan"), float("nan"))


class FeatureGates(NamedTuple):
    """How :func:`feature_map_errors` matches estimated features to true ones.

    Attributes:
        line_gate: lines whose matching cost exceeds this are unmatched (:func:`line_feature_errors`'s ``gate``).
        lever: metres per radian of angle in a line's matching cost (:func:`line_feature_errors`).
        max_slope: the largest slope of a true line written ``y = a x + b`` (:func:`line_feature_errors`).
        arc_gate: arcs whose centres lie farther apart are unmatched (:func:`arc_feature_errors`'s ``gate``).
        point_gate: break points farther apart are unmatched (:func:`point_feature_errors`'s ``gate``).
    """

    line_gate: float = 0.5
    lever: float = 1.0
    max_slope: float = 1.0
    arc_gate: float = 0.5
    point_gate: float = 0.2


def _put_summary(summary: dict, name: str, errors: np.ndarray) -> None:
    """``summary[name + "_median"]`` and ``summary[name + "_worst"]`` of ``errors`` (:func:`_summary`)."""
    summary[f"{name}_median"], summary[f"{name}_worst"] = _summary(errors)


def _corner_errors(est_lines: np.ndarray, true_lines: np.ndarray, match: np.ndarray, corners: np.ndarray) -> dict:
    """The corners where pairs of true lines meet against where their matched estimates meet: ``error``,
    ``true`` and ``estimate`` (NaN where a line is unmatched or the lines are parallel)."""
    pairs = np.asarray(corners, dtype=np.int64).reshape(-1, 2)
    tru = _lines_np(true_lines)
    n_true = tru.shape[0]
    if pairs.size and (pairs.min() < 0 or pairs.max() >= n_true):
        raise ValueError(f"corners: expected indices into the {n_true} true lines, got {pairs.min()}..{pairs.max()}")
    est = _lines_np(est_lines)
    true_xy = line_intersections(tru[pairs[:, 0]], tru[pairs[:, 1]])
    m = match[pairs]
    ok = np.all(m >= 0, axis=1)
    est_xy = np.full_like(true_xy, np.nan)
    if ok.any():
        est_xy[ok] = line_intersections(est[m[ok, 0]], est[m[ok, 1]])
    err = np.hypot(*(est_xy - true_xy).T)
    return {"error": err, "true": true_xy, "estimate": est_xy}


def feature_map_errors(
    est_lines: np.ndarray,
    true_lines: np.ndarray,
    *,
    est_arcs: np.ndarray | None = None,
    true_arcs: np.ndarray | None = None,
    corners: np.ndarray | None = None,
    est_break_points: np.ndarray | None = None,
    true_break_points: np.ndarray | None = None,
    gates: FeatureGates = FeatureGates(),
) -> dict:
    """The second paper's Table 1 for a map of lines (and arcs): line slope and intercept errors, arc
    centre and radius errors, corner and break point position errors, with a summary.

    Lines are matched by :func:`line_feature_errors`, arcs by :func:`arc_feature_errors`. A corner
    is where two true lines meet (``corners`` names them); its estimate is where their matched
    estimated lines meet (:func:`line_intersections`), so a corner error is the map's error where
    the walls meet, and a corner of an unmatched line has none. Break points (a wall's end at a
    range discontinuity) are points: estimated ones (e.g. the ends of the estimated walls'
    segments) are matched to the true ones by :func:`point_feature_errors`; without them (a map of
    lines alone) a break point's error is its distance to its wall's estimated line
    (:func:`break_point_line_errors`).

    Args:
        est_lines: ``(E, 2)`` estimated lines ``(rho, alpha)``.
        true_lines: ``(L, 2)`` true lines.
        est_arcs: ``(A', 3)`` estimated arcs ``(xc, yc, R)``, or None.
        true_arcs: ``(A, 3)`` true arcs, or None.
        corners: ``(K, 2)`` rows of indices into ``true_lines`` of the two lines meeting at each
            corner, or None.
        est_break_points: ``(B', 2)`` estimated break points, or None (the map's lines alone).
        true_break_points: ``(B, 2)`` true break points, or None.
        gates: how features are matched (:class:`FeatureGates`).

    Returns:
        A dict: ``lines`` (:func:`line_feature_errors`), ``arcs`` (:func:`arc_feature_errors`, or
        None), ``corners`` (``error`` ``(K,)`` distances, NaN where a line is unmatched or the
        lines are parallel; ``true`` and ``estimate`` ``(K, 2)``; or None), ``break_points``
        (:func:`point_feature_errors` or :func:`break_point_line_errors`, or None), and
        ``summary``: for each of ``line_slope``, ``line_intercept``, ``line_rho``, ``line_alpha``, ``arc_centre``, ``arc_radius``,
        ``corner``, ``break_point`` the median and the worst absolute error over the matched
        features (``<name>_median``, ``<name>_worst``; NaN when there are none) and the counts
        ``n_<kind>`` and ``n_<kind>_matched``. Unmatched features enter the counts only; the
        arcs', corners' and break points' entries are there when their truth is given.

    Raises:
        ValueError: when ``corners`` names a line that ``true_lines`` does not hold.
    """
    lines = line_feature_errors(est_lines, true_lines, gates.line_gate, gates.lever, gates.max_slope)
    summary: dict = {"n_lines": lines["n_true"], "n_lines_matched": lines["n_matched"]}
    for name, key in (
        ("line_slope", "slope_error"),
        ("line_intercept", "intercept_error"),
        ("line_rho", "rho_error"),
        ("line_alpha", "alpha_error"),
    ):
        _put_summary(summary, name, lines[key])
    arcs = None
    if true_arcs is not None:
        arcs = arc_feature_errors(np.zeros((0, 3)) if est_arcs is None else est_arcs, true_arcs, gates.arc_gate)
        summary["n_arcs"], summary["n_arcs_matched"] = arcs["n_true"], arcs["n_matched"]
        for name, key in (("arc_centre", "centre_error"), ("arc_radius", "radius_error")):
            _put_summary(summary, name, arcs[key])
    corner = None
    if corners is not None:
        corner = _corner_errors(est_lines, true_lines, lines["match"], corners)
        err = corner["error"]
        summary["n_corners"], summary["n_corners_matched"] = int(err.shape[0]), int(np.isfinite(err).sum())
        _put_summary(summary, "corner", corner["error"])
    breaks = None
    if true_break_points is not None:
        breaks = (
            break_point_line_errors(est_lines, true_lines, lines["match"], true_break_points)
            if est_break_points is None
            else point_feature_errors(est_break_points, true_break_points, gates.point_gate)
        )
        summary["n_break_points"], summary["n_break_points_matched"] = breaks["n_true"], breaks["n_matched"]
        _put_summary(summary, "break_point", breaks["error"])
    return {"lines": lines, "arcs": arcs, "corners": corner, "break_points": breaks, "summary": summary}
