"""Loop closure for the smoother: trees that a run mapped twice, found by registering each stretch
of newly mapped landmarks against the landmarks mapped before it.

A particle that arrives at ground it mapped long before with its pose drifted by more than the
association gate does not recognise the trees there: it maps them again, displaced by its drift,
and its map holds each of those trees twice. Along the particle's path the copies are consistent
with each other, so least squares over the path and the map keeps the drift: nothing ties the
copies to the originals. Here the copies are found as a group. The landmarks first seen in a
window of time (a submap) are registered against the landmarks first seen before the window by
a rigid transform (a rotation and a translation), by RANSAC over pairs of correspondences; a
transform under which enough of the submap falls onto earlier landmarks (within ``radius``,
one-to-one, and never both detected in the same scan: two trees detected together are two trees)
says that those landmarks are copies. Two landmarks within ``radius`` of each other and never
detected together are copies too. The smoother then joins each copy to its original and
solves again, which moves the drifted stretch of the path onto the earlier map.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from jaxtyping import Float, Int
from scipy.spatial import cKDTree

from nanoslam_jax.smoother._settings import SmootherConfig
from nanoslam_jax.models import wrap_angle_np

#: The config's defaults (:class:`nanoslam_jax.app.config.SmootherConfig`), the one source of the settings' defaults.
_DEFAULT = SmootherConfig()

__all__ = ["LoopClosureSettings", "co_observed", "find_duplicates", "loop_closure_settings", "path_moved_by_copies"]


class LoopClosureSettings(NamedTuple):
    """How duplicates are searched for.

    Attributes:
        window: length of the time windows whose newly mapped landmarks form a submap (s).
        radius: a copy lies within this distance of its original after the transform (m).
        search: the transform moves the submap's centre by at most this (m): the drift a
            particle may have accumulated.
        max_turn: the transform turns the submap by at most this (rad).
        min_inliers: a transform is accepted when at least this many landmarks of the submap
            fall onto earlier landmarks.
        accept: after the joined landmarks are solved for, a group of joins is kept when at
            least this fraction of its copies' detections lies within the association gate of a
            landmark.
        hypotheses: pairs of the submap's landmarks tried as one side of a correspondence (at
            most; drawn at random with a fixed seed when the submap has more).
    """

    window: float = _DEFAULT.loop_closure_window
    radius: float = _DEFAULT.loop_closure_radius
    search: float = _DEFAULT.loop_closure_search
    max_turn: float = float(np.deg2rad(_DEFAULT.loop_closure_max_turn_deg))
    min_inliers: int = _DEFAULT.loop_closure_min_inliers
    accept: float = _DEFAULT.loop_closure_accept
    hypotheses: int = 200


def loop_closure_settings(sc) -> LoopClosureSettings:
    """The loop closure's settings from the config's ``smoother`` section
    (:class:`nanoslam_jax.app.config.SmootherConfig`, its ``loop_closure_*`` keys)."""
    return LoopClosureSettings(
        window=sc.loop_closure_window,
        radius=sc.loop_closure_radius,
        search=sc.loop_closure_search,
        max_turn=float(np.deg2rad(sc.loop_closure_max_turn_deg)),
        min_inliers=sc.loop_closure_min_inliers,
        accept=sc.loop_closure_accept,
    )


def co_observed(seg: Int[np.ndarray, " n"], lid: Int[np.ndarray, " n"], n_landmarks: int) -> sp.csr_matrix:
    """Which landmarks were detected in the same scan (a boolean sparse matrix, landmarks x
    landmarks), from the association: the segment and the landmark of each associated detection."""
    if len(seg) == 0:
        return sp.csr_matrix((n_landmarks, n_landmarks), dtype=bool)
    S = sp.csr_matrix((np.ones(len(seg)), (seg, lid)), shape=(int(seg.max()) + 1, n_landmarks))
    return ((S.T @ S) > 0).tocsr()


def _rigid_fit(a: np.ndarray, b: np.ndarray) -> tuple[float, np.ndarray]:
    """The rotation angle and translation that map points ``a`` onto ``b`` in least squares."""
    ca, cb = a.mean(0), b.mean(0)
    u, v = a - ca, b - cb
    th = np.arctan2(np.sum(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]), np.sum(u[:, 0] * v[:, 0] + u[:, 1] * v[:, 1]))
    R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    return th, cb - R @ ca


def _inliers(new, old, tree, th, tr, radius, forbidden):
    """One-to-one correspondences (new index, old index) within ``radius`` under the transform."""
    R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    d, j = tree.query(new @ R.T + tr, distance_upper_bound=radius)
    ok = np.isfinite(d)
    i, j, d = np.nonzero(ok)[0], j[ok], d[ok]
    ok = ~np.asarray(forbidden[i, j]).ravel() if len(i) else np.zeros(0, bool)
    i, j, d = i[ok], j[ok], d[ok]
    order = np.argsort(d)  # one-to-one: the nearest claim on an old landmark wins
    _, first = np.unique(j[order], return_index=True)
    keep = order[first]
    return i[keep], j[keep]


def _hypotheses(new, old, s: LoopClosureSettings, rng) -> tuple[np.ndarray, np.ndarray]:
    """Candidate transforms of ``new`` onto ``old``: ``(H,)`` rotation angles and ``(H, 2)`` translations,
    one for each pair of ``new`` and pair of ``old`` landmarks about as far apart, within the turn and the
    search distance of the settings (empty when there are none)."""
    n, m = len(new), len(old)
    none = (np.zeros(0), np.zeros((0, 2)))
    ia, ib = np.triu_indices(n, 1)
    dn = np.linalg.norm(new[ia] - new[ib], axis=1)
    use = dn > 4 * s.radius  # short pairs fix the rotation badly
    ia, ib, dn = ia[use], ib[use], dn[use]
    if len(ia) > s.hypotheses:
        pick = rng.choice(len(ia), s.hypotheses, replace=False)
        ia, ib, dn = ia[pick], ib[pick], dn[pick]
    ka, kb = np.nonzero(~np.eye(m, dtype=bool))  # ordered pairs of old landmarks
    do = np.linalg.norm(old[ka] - old[kb], axis=1)
    order = np.argsort(do)
    do, ka, kb = do[order], ka[order], kb[order]
    lo = np.searchsorted(do, dn - 2 * s.radius)
    hi = np.searchsorted(do, dn + 2 * s.radius)
    cnt = hi - lo
    if cnt.sum() == 0:
        return none
    h_new = np.repeat(np.arange(len(ia)), cnt)
    h_old = np.concatenate([np.arange(a, b) for a, b in zip(lo, hi)])
    pa, pb, qa, qb = new[ia[h_new]], new[ib[h_new]], old[ka[h_old]], old[kb[h_old]]
    th = wrap_angle_np(np.arctan2(*(qb - qa)[:, ::-1].T) - np.arctan2(*(pb - pa)[:, ::-1].T))
    c, sn = np.cos(th), np.sin(th)
    tr = qa - np.stack([c * pa[:, 0] - sn * pa[:, 1], sn * pa[:, 0] + c * pa[:, 1]], 1)
    centre = new.mean(0)
    moved = np.stack([c * centre[0] - sn * centre[1], sn * centre[0] + c * centre[1]], 1) + tr - centre
    ok = (np.abs(th) <= s.max_turn) & (np.linalg.norm(moved, axis=1) <= s.search)
    return th[ok], tr[ok]


def _inlier_counts(new, tree, th, tr, radius) -> np.ndarray:
    """Every hypothesis's inliers (not yet one-to-one, nor checked for co-observation), counted in
    chunks that bound the memory."""
    n = len(new)
    counts = np.zeros(len(th), int)
    for a in range(0, len(th), 20000):
        t_, r_ = th[a : a + 20000], tr[a : a + 20000]
        R = np.stack([np.stack([np.cos(t_), -np.sin(t_)], 1), np.stack([np.sin(t_), np.cos(t_)], 1)], 1)
        pts = np.einsum("hij,nj->hni", R, new) + r_[:, None, :]
        d, _ = tree.query(pts.reshape(-1, 2), distance_upper_bound=radius)
        counts[a : a + 20000] = np.isfinite(d).reshape(len(t_), n).sum(1)
    return counts


def _refined_inliers(new, old, tree, th, tr, radius, forbidden) -> tuple[np.ndarray, np.ndarray]:
    """The one-to-one inliers of a transform, refined by least squares on them while that adds inliers
    (three times at most)."""
    i, j = _inliers(new, old, tree, th, tr, radius, forbidden)
    for _ in range(3):
        if len(i) < 2:
            break
        t2, r2 = _rigid_fit(new[i], old[j])
        i2, j2 = _inliers(new, old, tree, t2, r2, radius, forbidden)
        if len(i2) <= len(i):
            break
        i, j = i2, j2
    return i, j


def _register(new, old, forbidden, s: LoopClosureSettings, rng) -> tuple[np.ndarray, np.ndarray]:
    """RANSAC over pairs of correspondences: the transform of ``new`` onto ``old`` with the most
    inliers (refined by least squares on them). Returns the inlier pairs (indices into ``new`` and
    ``old``); empty when no transform reaches the acceptance thresholds."""
    n, m = len(new), len(old)
    empty = (np.zeros(0, int), np.zeros(0, int))
    need = s.min_inliers
    if n < need or m < need or n < 2:
        return empty
    th, tr = _hypotheses(new, old, s, rng)
    if len(th) == 0:
        return empty
    tree = cKDTree(old)
    counts = _inlier_counts(new, tree, th, tr, s.radius)
    best_i, best_j = empty
    for h in np.argsort(-counts)[:5]:  # the leading hypotheses, made one-to-one and refined
        if counts[h] < need:
            break
        i, j = _refined_inliers(new, old, tree, th[h], tr[h], s.radius, forbidden)
        if len(i) > len(best_i):
            best_i, best_j = i, j
    if len(best_i) < need:
        return empty
    return best_i, best_j


def find_duplicates(
    landmarks: Float[np.ndarray, "landmarks 2"],
    first_seen: Float[np.ndarray, " landmarks"],
    together: sp.spmatrix,
    settings: LoopClosureSettings = LoopClosureSettings(),
) -> tuple[Int[np.ndarray, " landmarks"], Int[np.ndarray, " landmarks"]]:
    """Landmarks mapped twice, each mapped to its original.

    Args:
        landmarks: the landmarks' positions.
        first_seen: the time each was first detected (s); ``inf`` for one never detected, which
            takes no part (neither copy nor original).
        together: which landmarks were detected in the same scan (:func:`co_observed`).
        settings: the search's settings.

    Returns:
        For every landmark the index of the landmark it is a copy of, or its own index; and the
        group of each copy (one per registered window, one per close pair; -1 for the others),
        which a verification keeps or drops as a whole.
    """
    L = np.asarray(landmarks, float)
    parent = np.arange(len(L))
    first = np.asarray(first_seen, float)
    done = np.isfinite(first)
    group = np.full(len(L), -1)
    if not np.any(done):
        return parent, group
    t0, t1 = float(np.min(first[done])), float(np.max(first[done]))
    together = sp.csr_matrix(together)
    rng = np.random.default_rng(0)
    for start in np.arange(t0 + settings.window, t1 + settings.window / 2, settings.window / 2):
        live = parent == np.arange(len(L))
        new = np.nonzero(live & (first >= start) & (first < start + settings.window))[0]
        if len(new) < settings.min_inliers:
            continue
        centre = L[new].mean(0)
        reach = settings.search + np.max(np.linalg.norm(L[new] - centre, axis=1)) + settings.radius
        old = np.nonzero(live & (first < start) & (np.linalg.norm(L - centre, axis=1) <= reach))[0]
        i, j = _register(L[new], L[old], together[new][:, old], settings, rng)
        parent[new[i]] = old[j]
        group[new[i]] = group.max() + 1
    # Copies the registration left (too few in their window, or bent with the path) that already lie
    # on their original: two landmarks within ``radius`` never detected together. The later one
    # joins the earlier.
    live = np.nonzero((parent == np.arange(len(L))) & np.isfinite(first))[0]
    tree = cKDTree(L[live])
    for a, b in sorted(
        tree.query_pairs(settings.radius, output_type="ndarray").tolist(),
        key=lambda ab: np.linalg.norm(L[live[ab[0]]] - L[live[ab[1]]]),
    ):
        a, b = live[a], live[b]
        if parent[a] != a or parent[b] != b or together[a, b]:
            continue
        if first[b] < first[a]:
            a, b = b, a
        parent[b] = a
        group[b] = group.max() + 1
    return parent, group


def path_moved_by_copies(poses, landmarks, seg, lid, parent, group, time_s, settings: LoopClosureSettings):
    """The path moved as the copies' registration says: where a group's copies were detected, the
    poses moved by the rigid transform that takes the copies onto their originals.

    A drifted stretch of path is where its copies were seen, and it drifted gradually: each group
    of at least ``settings.min_inliers`` copies gives its transform at the median segment of its
    copies' detections; the transforms are interpolated linearly between groups, from the identity
    one ``settings.window`` before the first copy detection to the identity one window after the
    last. This is the start of the solve that joins the copies, which from the drifted path itself
    may not reach the solution (Levenberg-Marquardt crawls along the odometry over a large
    correction)."""
    knots, copies = [], []
    for k in np.unique(group[group >= 0]):
        c = np.nonzero((group == k) & (parent != np.arange(len(parent))))[0]
        if len(c) < settings.min_inliers:
            continue
        th, tr = _rigid_fit(landmarks[c], landmarks[parent[c]])
        at = seg[np.isin(lid, c)]
        if len(at) == 0:
            continue
        knots.append((float(np.median(at)), th, tr[0], tr[1]))
        copies.append(at)
    if not knots:
        return poses
    knots.sort()
    at = np.concatenate(copies)
    t = np.asarray(time_s, float)
    lo = min(int(np.searchsorted(t, t[at.min()] - settings.window)), int(knots[0][0]) - 1)
    hi = max(int(np.searchsorted(t, t[at.max()] + settings.window)), int(knots[-1][0]) + 1)
    x = [lo] + [k[0] for k in knots] + [hi]
    rot, tx, ty = (np.interp(np.arange(len(poses)), x, [0.0] + [k[i] for k in knots] + [0.0]) for i in (1, 2, 3))
    c, s = np.cos(rot), np.sin(rot)
    p = poses
    return np.stack([c * p[:, 0] - s * p[:, 1] + tx, s * p[:, 0] + c * p[:, 1] + ty, wrap_angle_np(p[:, 2] + rot)], 1)
