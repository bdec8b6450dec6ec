"""Offline smoothing of a run: the final best particle's path and map refined by batch least squares.

A particle filter reports at each scan what it knew then. Where the car drives new ground with few
trees (1000-1400 s of Victoria Park), a particle's path drifts and its map is built along the
drift; when the car meets trees mapped earlier the particle is corrected, but its path before
stays where it was: a Rao-Blackwellised particle's history is never revised, and the particles'
histories coalesce a few seconds back, so the ancestral path (``filter.estimate: path``) is every
particle's. This module revises it after the run, as a full smoothing-and-mapping problem over the
whole log (GraphSLAM / SAM):

* **Variables**: the pose of every segment and the position of every confirmed landmark of the
  final best particle's map, started from its ancestral path and its map.
* **Odometry factors**: between consecutive poses, the segment's motion in the frame of its start
  pose, ``x_{t-1}^{-1} (+) x_t`` (with the heading difference wrapped), against the prior mean
  the filter used (:func:`~nanoslam_jax.filter.relative_prior`, the unscented transform over the
  controls and their noise), with that prior's covariance times ``smoother.odometry_scale`` plus
  a floor (``smoother.floor_xy``, ``floor_phi_deg``). The filter's control noise is set large so
  that its particles cover the drift; the smoother reads the controls as what they are, much
  better than that between two scans. The floor stands for what the car model misses (slip, the
  nonholonomic constraint's exactness) and keeps the factors from being a stiff constraint.
* **Detection factors**: each detection the run's final map explains, ``z - h(x_t, m_j)`` with
  the measurement noise ``(sigma_r, sigma_beta)`` and a Huber loss (``smoother.huber``, on the
  whitened residual's norm) so that a wrong association pulls with a bounded force. Detections
  are associated once, before the iterations, to the nearest confirmed landmark of the final map
  seen from the ancestral path within the chi-square ``filter.gate``; the rest are left out.
* **Loop closure** (``smoother.loop_closure``): a particle that came back to ground it had mapped
  with its pose drifted beyond the gate mapped the trees there a second time, and along its path
  the copies agree with each other. After a first solve, stretches of newly mapped landmarks are
  registered against the earlier map (:mod:`nanoslam_jax._loop_closure`); copies found are joined
  to their originals, the problem is solved again, and the joins are kept only where their
  detections then fit.
* **Solver**: Levenberg-Marquardt on the normal equations, whose matrix is sparse (block
  tridiagonal over the poses, block diagonal over the landmarks, plus each detection's
  pose-landmark block): the poses are eliminated by a banded Cholesky factorisation
  (:func:`scipy.linalg.cholesky_banded`) and the landmarks' dense Schur complement solved. The
  first pose's predecessor is the origin, which fixes the gauge as the filter's start does.
  Residual Jacobians come from autodiff.

The result uses every scan of the log to place every pose: an offline estimate, not a filtering
one. It is compared with the filter's own estimate of the same run wherever it is reported.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
from jaxtyping import Array, Bool, Float, Int

from .filter._params import Params
from .filter import relative_priors
from ._loop_closure import LoopClosureSettings, co_observed, find_duplicates
from .models import innovation, range_bearing, wrap_angle, wrap_angle_np

__all__ = ["LoopClosureSettings", "SmootherSettings", "Smoothed", "associate_path", "final_map", "segment_motion",
           "smooth_path", "smooth_run"]


class SmootherSettings(NamedTuple):
    """The ``smoother`` section (:class:`nanoslam_jax.config.SmootherConfig`).

    Attributes:
        odometry_scale: the odometry factors' covariance is the filter's segment prior covariance
            times this, plus the floors below.
        floor_xy, floor_phi: standard deviations (m, rad) added to every odometry factor, in each
            position coordinate and in the heading. The motion prior of the car model is nearly
            singular (the laser cannot move sideways but through a turn of the car), which makes
            the odometry factors a stiff nonlinear constraint along which Levenberg-Marquardt
            crawls; the floors, the model's own error, let it converge in about ten iterations.
        huber: the Huber loss's threshold on a detection's whitened residual norm.
        max_iter: Levenberg-Marquardt iterations at most.
        tol: converged when no pose or landmark coordinate moves more than this (m, rad).
        loop_closure: how trees mapped twice are searched for and joined after a first solve
            (:class:`LoopClosureSettings`); ``None``: not searched for.
        loop_closure_rounds: searches (each followed by a solve) at most.
    """

    odometry_scale: float = 0.3
    floor_xy: float = 0.1
    floor_phi: float = float(np.deg2rad(0.3))
    huber: float = 2.0
    max_iter: int = 50
    tol: float = 1e-3
    loop_closure: LoopClosureSettings | None = None
    loop_closure_rounds: int = 2

    @classmethod
    def from_config(cls, sc) -> "SmootherSettings":
        """From the config's ``smoother`` section (:class:`nanoslam_jax.config.SmootherConfig`)."""
        lc = LoopClosureSettings(
            window=sc.loop_closure_window, radius=sc.loop_closure_radius, search=sc.loop_closure_search,
            max_turn=float(np.deg2rad(sc.loop_closure_max_turn_deg)), min_inliers=sc.loop_closure_min_inliers,
            accept=sc.loop_closure_accept)
        return cls(odometry_scale=sc.odometry_scale, floor_xy=sc.floor_xy,
                   floor_phi=float(np.deg2rad(sc.floor_phi_deg)), huber=sc.huber, max_iter=sc.max_iter, tol=sc.tol,
                   loop_closure=lc if sc.loop_closure else None, loop_closure_rounds=sc.loop_closure_rounds)


class Smoothed(NamedTuple):
    """A smoothed run.

    Attributes:
        poses: the pose at each segment.
        landmarks: the landmarks' positions (the final map's confirmed landmarks, in its order; a
            copy joined to its original by the loop closure at the original's position).
        associated: detections that entered as factors.
        detections: detections of the log.
        iterations: Levenberg-Marquardt iterations taken over all solves (the loop closure solves again;
            ``max_iter`` bounds each solve).
        initial_cost, cost: the objective (half the sum of squared whitened residuals, Huber for
            detections) at the start and at the end.
        converged: whether the last solve's last step moved nothing by more than ``tol``.
        seconds: wall time of the smoothing.
        merged: landmarks joined to another as copies of the same tree (loop closure).
        rejected: groups of joins (a window's registration, a close pair) found but dropped: their
            detections did not fit after a solve.
    """

    poses: Float[np.ndarray, "segments 3"]
    landmarks: Float[np.ndarray, "landmarks 2"]
    associated: int
    detections: int
    iterations: int
    initial_cost: float
    cost: float
    converged: bool
    seconds: float
    merged: int = 0
    rejected: int = 0


_relative_priors = jax.jit(relative_priors, static_argnums=2)  # one compilation per log shape and kind


def segment_motion(
    segments, params: Params, kind: str = "unscented"
) -> tuple[Float[Array, "segments 3"], Float[Array, "segments 3 3"]]:
    """Each segment's motion prior in the frame of its start pose (mean and covariance), as the
    filter's prior computes it (:func:`~nanoslam_jax.filter.relative_prior`)."""
    return _relative_priors(segments, params, kind)


def _whitened_d2(x, m, z, sigma_r: float, sigma_beta: float) -> np.ndarray:
    """Squared residual of detections ``z`` (range, bearing) of landmarks ``m`` seen from poses
    ``x``, whitened by the measurement noise; the arrays broadcast over their leading axes."""
    dx, dy = m[..., 0] - x[..., 0], m[..., 1] - x[..., 1]
    return (((z[..., 0] - np.hypot(dx, dy)) / sigma_r) ** 2
            + (wrap_angle_np(z[..., 1] - np.arctan2(dy, dx) + x[..., 2]) / sigma_beta) ** 2)


def associate_path(
    path: Float[np.ndarray, "segments 3"],
    landmarks: Float[np.ndarray, "landmarks 2"],
    z: Float[np.ndarray, "segments k 2"],
    z_mask: Bool[np.ndarray, "segments k"],
    sigma_r: float,
    sigma_beta: float,
    gate: float,
) -> tuple[Int[np.ndarray, "n"], Int[np.ndarray, "n"], Int[np.ndarray, "n"]]:
    """Each detection's nearest landmark seen from ``path`` within the chi-square ``gate`` (on the
    measurement noise alone). Returns the segment, the detection's index in it and the landmark of
    every associated detection."""
    seg, det = np.nonzero(np.asarray(z_mask))
    lm = np.asarray(landmarks)
    if len(lm) == 0 or len(seg) == 0:
        empty = np.zeros(0, int)
        return empty, empty, empty
    x = np.asarray(path)[seg]
    zz = np.asarray(z)[seg, det]
    best = np.full(len(seg), np.inf)
    idx = np.zeros(len(seg), int)
    for start in range(0, len(lm), 256):  # bounded memory: detections x 256 landmarks at a time
        m = lm[start:start + 256]
        d2 = _whitened_d2(x[:, None], m[None], zz[:, None], sigma_r, sigma_beta)
        j = np.argmin(d2, axis=1)
        d = d2[np.arange(len(seg)), j]
        better = d < best
        best[better], idx[better] = d[better], start + j[better]
    ok = best < gate
    return seg[ok], det[ok], idx[ok]


def _odometry_residual(xa, xb, motion):
    c, s = jnp.cos(xa[2]), jnp.sin(xa[2])
    dx, dy = xb[0] - xa[0], xb[1] - xa[1]
    return jnp.stack([c * dx + s * dy - motion[0], -s * dx + c * dy - motion[1], wrap_angle(xb[2] - xa[2] - motion[2])])


def _detection_residual(x, m, z):
    return innovation(z, range_bearing(x, m))


@jax.jit
def _odometry_linearised(xa, xb, motion):
    f = lambda a, b, d: (_odometry_residual(a, b, d), *jax.jacfwd(_odometry_residual, (0, 1))(a, b, d))  # noqa: E731
    return jax.vmap(f)(xa, xb, motion)


@jax.jit
def _detection_linearised(x, m, z):
    f = lambda a, b, c: (_detection_residual(a, b, c), *jax.jacfwd(_detection_residual, (0, 1))(a, b, c))  # noqa: E731
    return jax.vmap(f)(x, m, z)


def _pad(n: int) -> int:
    """Association arrays are padded to a multiple of 4096 so that runs with different counts share
    one compiled linearisation."""
    return max(4096, -(-n // 4096) * 4096)


#: Upper bandwidth of the poses' block of the normal matrix: a pose (3 unknowns) is tied to the
#: next one only, so an entry is at most 5 places from the diagonal.
_BAND = 5


def _solve_normal(H: sp.spmatrix, rhs: np.ndarray, n_poses: int) -> np.ndarray:
    """Solve ``H x = rhs`` for the smoother's normal matrix (symmetric positive definite): poses
    first (a banded block, tied to each other only by consecutive odometry factors), then the
    landmarks (a block-diagonal block). The poses are eliminated with a banded Cholesky
    factorisation, the landmarks' Schur complement (dense, two unknowns per landmark) is solved,
    and the poses are substituted back: exact, and linear in the number of poses."""
    H = H.tocsr()
    nP = n_poses
    A = H[:nP, :nP].tocoo()
    upper = A.col >= A.row
    if np.any(A.col - A.row > _BAND):
        raise ValueError("smoother: the poses' normal matrix is not banded (an odometry factor ties non-consecutive poses)")
    ab = np.zeros((_BAND + 1, nP))
    ab[_BAND + A.row[upper] - A.col[upper], A.col[upper]] = A.data[upper]
    cb = sla.cholesky_banded(ab, lower=False)
    rp, rl = rhs[:nP], rhs[nP:]
    if rl.size == 0:
        return sla.cho_solve_banded((cb, False), rp)
    B = H[:nP, nP:].toarray()
    C = H[nP:, nP:].toarray()
    Y = sla.cho_solve_banded((cb, False), np.column_stack([B, rp]))
    YB, yp = Y[:, :-1], Y[:, -1]
    S = C - B.T @ YB
    xl = sla.solve(0.5 * (S + S.T), rl - B.T @ yp, assume_a="pos")
    return np.concatenate([yp - YB @ xl, xl])


def smooth_path(
    path: Float[np.ndarray, "segments 3"],
    landmarks: Float[np.ndarray, "landmarks 2"],
    z: Float[np.ndarray, "segments k 2"],
    z_mask: Bool[np.ndarray, "segments k"],
    motion_mean: Float[np.ndarray, "segments 3"],
    motion_cov: Float[np.ndarray, "segments 3 3"],
    sigma_r: float,
    sigma_beta: float,
    gate: float,
    settings: SmootherSettings = SmootherSettings(),
    time_s: Float[np.ndarray, "segments"] | None = None,
) -> Smoothed:
    """Smooth a path and its map by Levenberg-Marquardt over odometry and detection factors.

    Args:
        path: the initial pose at each segment (the final best particle's ancestral path).
        landmarks: the initial landmark positions (its map's confirmed landmarks).
        z, z_mask: the log's detections per segment (``Segments.z``, ``Segments.z_mask``).
        motion_mean, motion_cov: each segment's motion prior in its start pose's frame
            (:func:`segment_motion`); the pose before the first segment is the origin.
        sigma_r, sigma_beta: measurement noise (m, rad).
        gate: chi-square gate of the association.
        settings: the smoother's settings.
        time_s: each segment's time (s); needed by the loop closure (``settings.loop_closure``).

    Returns:
        The smoothed poses and landmarks and the solver's account.
    """
    t0 = time.perf_counter()
    path = np.asarray(path, float)
    lm_all = np.asarray(landmarks, float).reshape(-1, 2)
    seg, det, lid = associate_path(path, lm_all, z, z_mask, sigma_r, sigma_beta, gate)
    zz = np.asarray(z)[seg, det].reshape(-1, 2)
    cov = settings.odometry_scale * np.asarray(motion_cov, float) + np.diag(
        [settings.floor_xy ** 2, settings.floor_xy ** 2, settings.floor_phi ** 2]) + 1e-12 * np.eye(3)
    w_odo = np.transpose(np.linalg.cholesky(np.linalg.inv(cov)), (0, 2, 1))  # whitened e = W e, W'W = cov^-1
    w_det = np.array([1.0 / sigma_r, 1.0 / sigma_beta])
    motion = np.asarray(motion_mean, float)

    def solve(poses, lms, seg_, zz_, lid_):
        return _solve(poses, lms, seg_, zz_, lid_, motion, w_odo, w_det, settings)

    poses, lm_out = path, lm_all.copy()
    poses, lm_out, iterations, initial_cost, cost, converged = solve(poses, lm_out, seg, zz, lid)
    merged, rejected, owner = 0, 0, np.arange(len(lm_out))
    if settings.loop_closure is not None and time_s is not None and len(lid):
        t = np.asarray(time_s, float)
        for _ in range(settings.loop_closure_rounds):
            first = np.full(len(lm_out), np.inf)
            np.minimum.at(first, lid, t[seg])
            parent, group = find_duplicates(lm_out, first, co_observed(seg, lid, len(lm_out)),
                                            settings.loop_closure)
            while np.any(parent[parent] != parent):  # chains of copies end at the original
                parent = parent[parent]
            kept = False
            for _ in range(2):
                new_lid = parent[lid]
                joined = new_lid != lid
                if not np.any(joined):
                    break
                p2, l2, it, _, c2, conv2 = solve(poses, lm_out, seg, zz, new_lid)
                iterations += it
                # Verification: a true loop closure lets the joined detections fit as the others do
                # once the path has moved; a false one leaves them outside the gate. A group that
                # does not fit is dropped and the rest solved again.
                fit = _whitened_d2(p2[seg[joined]], l2[new_lid[joined]], zz[joined], sigma_r, sigma_beta) < gate
                g = group[lid[joined]]
                bad = [k for k in np.unique(g) if np.mean(fit[g == k]) < settings.loop_closure.accept]
                if not bad:
                    kept = True
                    break
                rejected += len(bad)
                drop = np.isin(group, bad)
                parent[drop] = np.nonzero(drop)[0]
            if not kept:
                break
            merged += int(np.sum(parent != np.arange(len(parent))))  # copies joined earlier have no detections
            poses, lm_out, cost, converged, owner = p2, l2, c2, conv2, parent[owner]
            # The path has moved: associate every detection again, to the landmarks that remain.
            live = np.nonzero(owner == np.arange(len(owner)))[0]
            seg, det, lid = associate_path(poses, lm_out[live], z, z_mask, sigma_r, sigma_beta, gate)
            lid, zz = live[lid], np.asarray(z)[seg, det].reshape(-1, 2)
            poses, lm_out, it, _, cost, converged = solve(poses, lm_out, seg, zz, lid)
            iterations += it
    return Smoothed(poses=poses, landmarks=lm_out[owner], associated=int(len(seg)),
                    detections=int(np.sum(z_mask)), iterations=iterations, initial_cost=float(initial_cost),
                    cost=float(cost), converged=converged, seconds=time.perf_counter() - t0, merged=merged,
                    rejected=rejected)


def _solve(path, lm_all, seg, z_obs, lid, motion, w_odo, w_det, settings: SmootherSettings):
    """Levenberg-Marquardt from ``path`` and ``lm_all`` over the odometry factors and the detections
    ``z_obs`` (made at segments ``seg`` of landmarks ``lid``). Returns the poses, all landmarks
    (those without a detection unchanged), iterations, initial and final cost, converged."""
    T = path.shape[0]
    # Only landmarks that explain a detection are variables (the others keep their positions).
    seen, lid = np.unique(lid, return_inverse=True)
    lid = lid.reshape(-1)
    lm0, M = lm_all[seen], len(seen)
    n = len(seg)
    n_pad = _pad(n)
    zz = np.zeros((n_pad, 2))
    zz[:n] = z_obs
    seg_p, lid_p = np.zeros(n_pad, int), np.zeros(n_pad, int)
    seg_p[:n], lid_p[:n] = seg, lid
    nP, nV = 3 * T, 3 * T + 2 * M
    k = float(settings.huber)

    # Fixed sparsity pattern: odometry rows (3 per segment) then detection rows (2 per detection).
    ro = np.arange(3 * T).reshape(T, 3)
    rows_prev = np.repeat(ro[1:], 3, axis=1).ravel()
    cols_prev = np.tile(np.arange(3), (T - 1, 3)).ravel() + np.repeat(3 * np.arange(T - 1), 9)
    rows_cur = np.repeat(ro, 3, axis=1).ravel()
    cols_cur = np.tile(np.arange(3), (T, 3)).ravel() + np.repeat(3 * np.arange(T), 9)
    rd = 3 * T + np.arange(2 * n).reshape(n, 2)
    rows_dx = np.repeat(rd, 3, axis=1).ravel()
    cols_dx = np.tile(np.arange(3), (n, 2)).ravel() + np.repeat(3 * seg, 6)
    rows_dm = np.repeat(rd, 2, axis=1).ravel()
    cols_dm = np.tile(np.arange(2), (n, 2)).ravel() + np.repeat(nP + 2 * lid, 4)
    rows = np.concatenate([rows_prev, rows_cur, rows_dx, rows_dm])
    cols = np.concatenate([cols_prev, cols_cur, cols_dx, cols_dm])

    def linearise(X):
        P, L = X[:nP].reshape(T, 3), X[nP:].reshape(M, 2)
        xa = np.concatenate([np.zeros((1, 3)), P[:-1]])
        eo, Ja, Jb = (np.asarray(a) for a in _odometry_linearised(xa, P, motion))
        eo, Ja, Jb = np.einsum("tij,tj->ti", w_odo, eo), w_odo @ Ja, w_odo @ Jb
        ed, Jx, Jm = (np.asarray(a)[:n] for a in _detection_linearised(P[seg_p], L[lid_p] if M else np.zeros((n_pad, 2)), zz))
        ed, Jx, Jm = ed * w_det, Jx * w_det[:, None], Jm * w_det[:, None]
        norm = np.linalg.norm(ed, axis=1)
        huber = norm > k
        cost = 0.5 * np.sum(eo ** 2) + np.sum(np.where(huber, k * norm - 0.5 * k * k, 0.5 * norm ** 2))
        sw = np.sqrt(np.where(huber, k / np.maximum(norm, 1e-300), 1.0))  # IRLS weights of the Huber loss
        vals = np.concatenate([Ja[1:].ravel(), Jb.ravel(), (Jx * sw[:, None, None]).ravel(),
                               (Jm * sw[:, None, None]).ravel()])
        J = sp.csr_matrix((vals, (rows, cols)), shape=(3 * T + 2 * n, nV))
        e = np.concatenate([eo.ravel(), (ed * sw[:, None]).ravel()])
        return cost, J, e

    X = np.concatenate([path.ravel(), lm0.ravel()])
    cost, J, e = linearise(X)
    initial_cost, lam, converged, it = cost, 1e-4, False, 0
    for it in range(1, settings.max_iter + 1):
        H = (J.T @ J).tocsr()
        g = J.T @ e
        d = H.diagonal()
        while True:
            try:
                step = _solve_normal(H + sp.diags(lam * d + 1e-12), -g, nP)
            except np.linalg.LinAlgError:  # not positive definite to working precision: damp more
                lam *= 10.0
                if lam > 1e8:
                    step = np.zeros_like(X)
                    break
                continue
            Xn = X + step
            Xn[2:nP:3] = wrap_angle_np(Xn[2:nP:3])
            new_cost, Jn, en = linearise(Xn)
            if np.isfinite(new_cost) and new_cost <= cost:
                break
            lam *= 10.0
            if lam > 1e8:
                step = np.zeros_like(X)
                break
        if not np.any(step):
            converged = not np.any(g)  # at a stationary point; else damping could not lower the cost
            break
        X, cost, J, e = Xn, new_cost, Jn, en
        lam = max(lam / 10.0, 1e-9)
        if np.max(np.abs(step)) < settings.tol:
            converged = True
            break
    lm_out = lm_all.copy()
    lm_out[seen] = X[nP:].reshape(M, 2)
    return X[:nP].reshape(T, 3), lm_out, it, initial_cost, cost, converged


def final_map(state, index: int | None = None) -> Float[np.ndarray, "landmarks 2"]:
    """The positions of the confirmed landmarks of a run's final best particle (``index``: the
    member of a batch run)."""
    lm = state.particles.landmarks
    best = np.asarray(state.best)
    take = (lambda a: np.asarray(a)[best]) if index is None else (lambda a: np.asarray(a)[index, best[index]])
    keep = take(lm.active) & take(lm.confirmed)
    return take(lm.mean)[keep]


def smooth_run(path, landmarks, segments, params: Params, settings: SmootherSettings, prior: str = "unscented") -> Smoothed:
    """:func:`smooth_path` for a run: the log's detections and motion priors from ``segments`` and
    ``params`` (one run's hyperparameters), the association gate ``params.gate``.

    Args:
        path: the run's ancestral path (``reported_trajectory("path", ...)``).
        landmarks: the positions of its final best particle's confirmed landmarks.
        segments: the log's segments.
        params: the run's hyperparameters.
        settings: the smoother's settings.
        prior: ``filter.prior``, how the motion prior is propagated.
    """
    mean, cov = segment_motion(segments, params, prior)
    return smooth_path(path, landmarks, np.asarray(segments.z), np.asarray(segments.z_mask), np.asarray(mean),
                       np.asarray(cov), float(params.sigma_r), float(params.sigma_beta), float(params.gate), settings,
                       np.asarray(segments.time))
