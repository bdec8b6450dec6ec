"""Map RMSE after a rigid alignment of an estimated map onto surveyed landmarks (re-exported by
:mod:`nanoslam_jax.eval.metrics`)."""

from __future__ import annotations

import math

import numpy as np

from nanoslam_jax.eval._feature_metrics import gated_assignment
from nanoslam_jax.eval._align import _rmse, rigid_align, rotation_matrix

__all__ = ["map_alignment_metrics"]


def _angle_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.arctan2(R[1, 0], R[0, 0])))


def _pair_transforms(
    est: np.ndarray, tru: np.ndarray, tol: float, max_pairs: int, min_pairs: int = 16, budget: int = 300_000
) -> tuple[np.ndarray, np.ndarray]:
    """Candidate rigid transforms of ``est`` onto ``tru``, each mapping a pair of estimates onto a
    pair of true landmarks of about the same separation (within ``tol``), or with fewer than two
    points on a side, one point onto another (a translation).

    The pairs of estimates are taken in a fixed pseudo-random order, at most ``max_pairs`` of them,
    and fewer (but at least ``min_pairs``) when they would give more than ``budget`` candidates:
    with a mostly correct map most pairs give the right transform.

    Returns:
        ``(theta, t)``: ``(C,)`` rotation angles and ``(C, 2)`` translations.
    """
    E, L = est.shape[0], tru.shape[0]
    if E < 2 or L < 2:
        i, k = np.divmod(np.arange(E * L), L)
        return np.zeros(E * L), tru[k] - est[i]
    i, j = np.triu_indices(E, 1)
    order = np.random.default_rng(0).permutation(i.size)[:max_pairs]
    i, j = i[order], j[order]
    k, m = np.nonzero(~np.eye(L, dtype=bool))  # ordered pairs of true landmarks
    de, dt = est[j] - est[i], tru[m] - tru[k]
    close = np.abs(np.hypot(*de.T)[:, None] - np.hypot(*dt.T)[None, :]) <= tol
    used = np.searchsorted(np.cumsum(close.sum(axis=1)), budget, side="right")
    a, b = np.nonzero(close[: max(min_pairs, used)])
    theta = np.arctan2(dt[b, 1], dt[b, 0]) - np.arctan2(de[a, 1], de[a, 0])
    c, s = np.cos(theta), np.sin(theta)
    mid_e, mid_t = 0.5 * (est[i[a]] + est[j[a]]), 0.5 * (tru[k[b]] + tru[m[b]])
    t = mid_t - np.stack([c * mid_e[:, 0] - s * mid_e[:, 1], s * mid_e[:, 0] + c * mid_e[:, 1]], axis=1)
    return theta, t


def _score_transforms(
    est: np.ndarray, tree, theta: np.ndarray, t: np.ndarray, radius: float, chunk: int = 500_000
) -> tuple[np.ndarray, np.ndarray]:
    """Per candidate transform: how many moved estimates lie within ``radius`` of a true landmark
    (``tree``: a ``scipy.spatial.cKDTree`` of them), and the sum over the estimates of
    ``min(d^2, radius^2)`` (``d`` the distance to the nearest)."""
    n_in, cost = np.zeros(theta.size, dtype=np.int64), np.zeros(theta.size)
    step = max(1, chunk // max(1, est.shape[0]))
    for lo in range(0, theta.size, step):
        c, s, tt = np.cos(theta[lo : lo + step]), np.sin(theta[lo : lo + step]), t[lo : lo + step]
        x = c[:, None] * est[None, :, 0] - s[:, None] * est[None, :, 1] + tt[:, 0:1]
        y = s[:, None] * est[None, :, 0] + c[:, None] * est[None, :, 1] + tt[:, 1:2]
        d, _ = tree.query(np.stack([x, y], axis=-1), distance_upper_bound=radius)
        n_in[lo : lo + step] = np.isfinite(d).sum(axis=1)
        cost[lo : lo + step] = np.minimum(d, radius).__pow__(2).sum(axis=1)
    return n_in, cost


def _first_alignments(
    est: np.ndarray,
    tru: np.ndarray,
    radius: float,
    max_pairs: int,
    keep: int = 10,
    probe: int = 12,
    shortlist: int = 100,
) -> list[tuple[np.ndarray, np.ndarray]]:
    """The ``keep`` best candidate alignments ``(R, t)`` of :func:`_pair_transforms`: scored on
    ``probe`` of the estimates first, then the ``shortlist`` best on all of them (most estimates
    within ``radius`` of a true landmark, then the smallest truncated squared distance)."""
    from scipy.spatial import cKDTree

    tree = cKDTree(tru)
    theta, t = _pair_transforms(est, tru, 2.0 * radius, max_pairs)
    if est.shape[0] > probe:
        sub = est[np.random.default_rng(1).permutation(est.shape[0])[:probe]]
        n_in, cost = _score_transforms(sub, tree, theta, t, radius)
        top = np.lexsort((cost, -n_in))[:shortlist]
        theta, t = theta[top], t[top]
    n_in, cost = _score_transforms(est, tree, theta, t, radius)
    return [(rotation_matrix(math.degrees(theta[c])), t[c]) for c in np.lexsort((cost, -n_in))[:keep]]


def _assign(aligned: np.ndarray, tru: np.ndarray, radius: float) -> np.ndarray:
    """One-to-one pairs ``(est index, true index)`` within ``radius``: the assignment minimising
    the sum of ``min(d^2, radius^2)`` (:func:`gated_assignment`), pairs beyond ``radius`` dropped."""
    d2 = np.sum((aligned[:, None, :] - tru[None, :, :]) ** 2, axis=-1)
    return np.stack(gated_assignment(d2, radius**2), axis=1)


def map_alignment_metrics(
    est_xy: np.ndarray,
    true_xy: np.ndarray,
    est_ids: np.ndarray | None = None,
    true_ids: np.ndarray | None = None,
    match_radius: float = 0.5,
    *,
    max_iter: int = 50,
    max_pairs: int = 400,
) -> dict:
    """A map against surveyed landmarks in another frame: its RMSE after the best rigid alignment
    (rotation and translation, no scale; least squares, :func:`rigid_align`), the landmarks it
    found and its spurious ones.

    * **With ids** (``est_ids`` given): each estimate is paired with the true landmark of its id;
      the alignment is the least-squares fit over all pairs and ``rmse`` the RMS distance over all
      of them (however far). A true landmark is found when an estimate of its id lies within
      ``match_radius`` of it after the alignment; an estimate is spurious when it does not lie
      within ``match_radius`` of the true landmark of its id (or its id is none of ``true_ids``,
      e.g. -1).
    * **Without ids**: the pairs are found too. A first alignment is chosen robustly among the
      transforms that map a pair of estimates onto a pair of true landmarks of about the same
      separation (within ``2 match_radius``; from a fixed pseudo-random subset of the pairs of
      estimates, at most ``max_pairs`` and fewer for a large map): the one that brings the most
      estimates within ``match_radius`` of a true landmark (then the smallest truncated squared
      distance; a large map's candidates are shortlisted on 12 of its estimates). From the best ten,
      one-to-one assignment within ``match_radius`` (Hungarian, ``scipy.optimize.
      linear_sum_assignment``) and the least-squares alignment of the assigned pairs alternate
      until the pairs no longer change; the result with the most pairs (then the smallest squared
      error) is kept. ``rmse`` is over the assigned pairs, found landmarks are the assigned true
      ones, spurious estimates the unassigned ones.

    With one pair the alignment is a translation (``rmse`` 0); with none it is the identity and
    ``rmse`` NaN.

    Args:
        est_xy: ``(E, 2)`` the estimated landmark positions (in the map's own frame).
        true_xy: ``(L, 2)`` the surveyed positions.
        est_ids: ``(E,)`` the landmark id of each estimate (-1: unknown), or None: pair by position.
        true_ids: ``(L,)`` the id of each true landmark, distinct (default: the row index).
        match_radius: an aligned estimate within this distance (m) of a true landmark matches it.
        max_iter: at most this many assignment-alignment rounds (without ids).
        max_pairs: at most this many pairs of estimates seed the first alignment (without ids).

    Returns:
        A dict: ``rmse``; ``n_est``, ``n_true``, ``n_pairs`` (pairs in the alignment), ``n_found``,
        ``found_fraction``, ``n_spurious``; the alignment ``p -> R(align_rotation_deg) p +
        (align_x, align_y)`` (estimate frame onto the surveyed one) and as arrays ``rotation``
        ``(2, 2)`` and ``translation`` ``(2,)``; ``aligned`` ``(E, 2)`` the moved estimates,
        ``pairs`` ``(n_pairs, 2)`` the (estimate row, true row) pairs and ``pair_errors`` their
        distances after the alignment.

    Raises:
        ValueError: on bad shapes, ``true_ids`` without ``est_ids``, repeated ``true_ids`` or a
            ``match_radius`` <= 0.
    """
    est = np.asarray(est_xy, dtype=float).reshape(-1, 2) if np.size(est_xy) else np.zeros((0, 2))
    tru = np.asarray(true_xy, dtype=float).reshape(-1, 2) if np.size(true_xy) else np.zeros((0, 2))
    E, L = est.shape[0], tru.shape[0]
    if not match_radius > 0:
        raise ValueError(f"match_radius: expected a distance > 0, got {match_radius}")
    if est_ids is None and true_ids is not None:
        raise ValueError("true_ids given without est_ids: pass the estimates' ids too, or neither")
    R, shift = np.eye(2), np.zeros(2)
    if est_ids is not None:
        est_ids = np.asarray(est_ids).reshape(-1).astype(np.int64)
        true_ids = np.arange(L) if true_ids is None else np.asarray(true_ids).reshape(-1).astype(np.int64)
        if est_ids.shape[0] != E or true_ids.shape[0] != L:
            raise ValueError(
                f"est_ids must have E = {E} and true_ids L = {L} entries, got {est_ids.shape[0]} "
                f"and {true_ids.shape[0]}"
            )
        if np.unique(true_ids).size != L:
            raise ValueError("true_ids: expected distinct ids")
        row_of = {int(k): r for r, k in enumerate(true_ids.tolist())}
        rows = np.array([row_of.get(int(k), -1) for k in est_ids.tolist()], dtype=np.int64)
        pairs = np.stack([np.flatnonzero(rows >= 0), rows[rows >= 0]], axis=1)
        if pairs.shape[0]:
            R, shift, _ = rigid_align(est[pairs[:, 0]], tru[pairs[:, 1]])
    elif E and L:
        best = None
        for Rc, tc in _first_alignments(est, tru, match_radius, max_pairs):
            pc = None
            for _ in range(max_iter):
                p = _assign(est @ Rc.T + tc, tru, match_radius)
                if p.shape[0] == 0 or (pc is not None and np.array_equal(p, pc)):
                    break
                pc = p
                Rc, tc, _ = rigid_align(est[p[:, 0]], tru[p[:, 1]])
            if pc is None:
                continue
            sse = float(np.sum((est[pc[:, 0]] @ Rc.T + tc - tru[pc[:, 1]]) ** 2))
            if best is None or (pc.shape[0], -sse) > (best[0].shape[0], -best[3]):
                best = (pc, Rc, tc, sse)
        pairs = np.zeros((0, 2), dtype=np.int64) if best is None else best[0]
        if best is not None:
            R, shift = best[1], best[2]
    else:
        pairs = np.zeros((0, 2), dtype=np.int64)
    aligned = est @ R.T + shift
    err = np.hypot(*(aligned[pairs[:, 0]] - tru[pairs[:, 1]]).T) if pairs.shape[0] else np.zeros(0)
    close = pairs[err <= match_radius]
    n_found = int(np.unique(close[:, 1]).size)
    return {
        "rmse": _rmse(err),
        "n_est": E,
        "n_true": L,
        "n_pairs": int(pairs.shape[0]),
        "n_found": n_found,
        "found_fraction": n_found / L if L else float("nan"),
        "n_spurious": E - int(np.unique(close[:, 0]).size),
        "align_rotation_deg": _angle_deg(R),
        "align_x": float(shift[0]),
        "align_y": float(shift[1]),
        "rotation": R,
        "translation": shift,
        "aligned": aligned,
        "pairs": pairs,
        "pair_errors": err,
    }
