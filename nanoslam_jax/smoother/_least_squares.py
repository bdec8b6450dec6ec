"""The smoother's least-squares problem (:mod:`nanoslam_jax.smoother._smoother`): its residuals, their
autodiff Jacobians, and Levenberg-Marquardt on the normal equations, whose pose block is banded
(each pose tied to the next by an odometry factor) and whose landmark block is block diagonal."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from nanoslam_jax.models import innovation, range_bearing, wrap_angle, wrap_angle_np


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
        raise ValueError(
            "smoother: the poses' normal matrix is not banded (an odometry factor ties non-consecutive poses)"
        )
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


def _solve(path, lm_all, seg, z_obs, lid, motion, w_odo, w_det, settings):
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
        ed, Jx, Jm = (
            np.asarray(a)[:n] for a in _detection_linearised(P[seg_p], L[lid_p] if M else np.zeros((n_pad, 2)), zz)
        )
        ed, Jx, Jm = ed * w_det, Jx * w_det[:, None], Jm * w_det[:, None]
        norm = np.linalg.norm(ed, axis=1)
        huber = norm > k
        cost = 0.5 * np.sum(eo**2) + np.sum(np.where(huber, k * norm - 0.5 * k * k, 0.5 * norm**2))
        sw = np.sqrt(np.where(huber, k / np.maximum(norm, 1e-300), 1.0))  # IRLS weights of the Huber loss
        vals = np.concatenate(
            [Ja[1:].ravel(), Jb.ravel(), (Jx * sw[:, None, None]).ravel(), (Jm * sw[:, None, None]).ravel()]
        )
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
