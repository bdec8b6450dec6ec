"""The smoother's least-squares problem (:mod:`nanoslam_jax.smoother._smoother`): its residuals, their
autodiff Jacobians, and Levenberg-Marquardt on the normal equations, whose pose block is banded
(each pose tied to the next by an odometry factor) and whose landmark block is block diagonal."""

from __future__ import annotations

import warnings
from typing import NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

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


def _solve_sparse(H: sp.spmatrix, rhs: np.ndarray) -> np.ndarray:
    """``H x = rhs`` by SuperLU with a minimum-degree ordering of ``H``'s symmetric pattern;
    ``LinAlgError`` where ``H`` is singular to working precision (never NaNs)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", spla.MatrixRankWarning)
        try:
            x = spla.spsolve(H.tocsc(), rhs, permc_spec="MMD_AT_PLUS_A")
        except (spla.MatrixRankWarning, RuntimeError) as err:
            raise np.linalg.LinAlgError(f"smoother: the normal matrix is singular ({err})") from err
    if not np.all(np.isfinite(x)):
        raise np.linalg.LinAlgError("smoother: the sparse solve of the normal matrix is not finite")
    return x


#: The most entries (8 bytes each) of the dense pose-landmark block that :func:`_solve_normal`
#: builds; a larger problem (a city-sized log) is solved by a sparse factorisation instead.
DENSE_BUDGET = 1 << 27


def _solve_normal(H: sp.spmatrix, rhs: np.ndarray, n_poses: int, dense_budget: int = DENSE_BUDGET) -> np.ndarray:
    """Solve ``H x = rhs`` for the smoother's normal matrix (symmetric positive definite): the
    ``n_poses`` pose unknowns first (a banded block, tied to each other only by consecutive odometry
    factors), then the landmarks (a block-diagonal block).

    While the pose-landmark block has at most ``dense_budget`` entries, the poses are eliminated
    with a banded Cholesky factorisation, the landmarks' Schur complement (dense, two unknowns per
    landmark) is solved, and the poses are substituted back: exact, and linear in the number of
    poses. A larger problem is solved by SuperLU on the sparse matrix with a minimum-degree ordering
    of its symmetric pattern, whose memory grows with the matrix's nonzeros, not with poses times
    landmarks. Raises ``numpy.linalg.LinAlgError`` where the matrix is singular to working precision.
    """
    nP = n_poses
    if nP * (H.shape[0] - nP) > dense_budget:
        return _solve_sparse(H, rhs)
    H = H.tocsr()
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


class Observations(NamedTuple):
    """The detections that enter as factors.

    Attributes:
        seg: ``(n,)`` the segment of each.
        z: ``(n, 2)`` its range and bearing.
        lid: ``(n,)`` the landmark it is of (an index into the landmarks solved for).
    """

    seg: np.ndarray
    z: np.ndarray
    lid: np.ndarray


class Factors(NamedTuple):
    """What the factors weigh, the same for every solve of a run.

    Attributes:
        motion: ``(T, 3)`` each segment's odometry mean in its start pose's frame.
        w_odo: ``(T, 3, 3)`` the odometry residuals' whitening (``W' W = cov^-1``).
        w_det: ``(2,)`` the detection residuals' whitening (``1 / sigma_r``, ``1 / sigma_beta``).
        huber: the Huber loss's threshold on a whitened detection residual's norm.
        max_iter: Levenberg-Marquardt iterations at most.
        tol: converged when no coordinate moves more than this.
    """

    motion: np.ndarray
    w_odo: np.ndarray
    w_det: np.ndarray
    huber: float
    max_iter: int
    tol: float


class _Problem(NamedTuple):
    """One solve's problem: ``T`` poses then ``M`` landmarks as unknowns, the detections padded to ``n_pad``
    (:func:`_pad`) and the Jacobian's fixed sparsity pattern."""

    T: int
    M: int
    n: int
    n_pad: int
    seg_p: np.ndarray
    lid_p: np.ndarray
    zz: np.ndarray
    rows: np.ndarray
    cols: np.ndarray


def _sparsity(T: int, seg: np.ndarray, lid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The Jacobian's nonzero ``(rows, cols)``: odometry rows (3 per segment) then detection rows (2 per
    detection), in the order :func:`_linearise` lays out its values."""
    n, nP = len(seg), 3 * T
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
    return rows, cols


def _problem(T: int, M: int, obs: Observations) -> _Problem:
    """The problem of ``T`` poses and ``M`` landmarks with the detections ``obs`` (landmarks indexed ``0 .. M-1``)."""
    seg, lid = obs.seg, obs.lid
    n = len(seg)
    n_pad = _pad(n)
    zz = np.zeros((n_pad, 2))
    zz[:n] = obs.z
    seg_p, lid_p = np.zeros(n_pad, int), np.zeros(n_pad, int)
    seg_p[:n], lid_p[:n] = seg, lid
    rows, cols = _sparsity(T, seg, lid)
    return _Problem(T, M, n, n_pad, seg_p, lid_p, zz, rows, cols)


def _linearise(prob: _Problem, f: Factors, X: np.ndarray) -> tuple[float, sp.csr_matrix, np.ndarray]:
    """``(cost, J, e)`` at the unknowns ``X``: the objective (half the sum of squared whitened residuals,
    Huber for detections), the Jacobian and the residuals, both weighted for the Huber loss (IRLS)."""
    T, M, n, n_pad = prob.T, prob.M, prob.n, prob.n_pad
    nP, nV = 3 * T, 3 * T + 2 * M
    k = float(f.huber)
    w_odo, w_det = f.w_odo, f.w_det
    P, L = X[:nP].reshape(T, 3), X[nP:].reshape(M, 2)
    xa = np.concatenate([np.zeros((1, 3)), P[:-1]])
    eo, Ja, Jb = (np.asarray(a) for a in _odometry_linearised(xa, P, f.motion))
    eo, Ja, Jb = np.einsum("tij,tj->ti", w_odo, eo), w_odo @ Ja, w_odo @ Jb
    ed, Jx, Jm = (
        np.asarray(a)[:n]
        for a in _detection_linearised(P[prob.seg_p], L[prob.lid_p] if M else np.zeros((n_pad, 2)), prob.zz)
    )
    ed, Jx, Jm = ed * w_det, Jx * w_det[:, None], Jm * w_det[:, None]
    norm = np.linalg.norm(ed, axis=1)
    huber = norm > k
    cost = 0.5 * np.sum(eo**2) + np.sum(np.where(huber, k * norm - 0.5 * k * k, 0.5 * norm**2))
    sw = np.sqrt(np.where(huber, k / np.maximum(norm, 1e-300), 1.0))  # IRLS weights of the Huber loss
    vals = np.concatenate(
        [Ja[1:].ravel(), Jb.ravel(), (Jx * sw[:, None, None]).ravel(), (Jm * sw[:, None, None]).ravel()]
    )
    J = sp.csr_matrix((vals, (prob.rows, prob.cols)), shape=(3 * T + 2 * n, nV))
    e = np.concatenate([eo.ravel(), (ed * sw[:, None]).ravel()])
    return cost, J, e


class _Step(NamedTuple):
    """A damped step: the step (zero when damping could not lower the cost), the damping after it and,
    for a nonzero step, the unknowns it reaches with their cost, Jacobian and residuals."""

    step: np.ndarray
    lam: float
    X: Optional[np.ndarray] = None
    cost: float = 0.0
    J: Optional[sp.csr_matrix] = None
    e: Optional[np.ndarray] = None


def _damped_step(
    prob: _Problem, f: Factors, X: np.ndarray, cost: float, H: sp.csr_matrix, g: np.ndarray, lam: float
) -> _Step:
    """The Levenberg-Marquardt step from ``X``: damping ``lam`` raised tenfold until the step lowers the cost
    (or keeps it), given up above 1e8 (a zero step)."""
    nP = 3 * prob.T
    d = H.diagonal()
    while True:
        try:
            step = _solve_normal(H + sp.diags(lam * d + 1e-12), -g, nP)
        except np.linalg.LinAlgError:  # not positive definite to working precision: damp more
            lam *= 10.0
            if lam > 1e8:
                return _Step(np.zeros_like(X), lam)
            continue
        Xn = X + step
        Xn[2:nP:3] = wrap_angle_np(Xn[2:nP:3])
        new_cost, Jn, en = _linearise(prob, f, Xn)
        if np.isfinite(new_cost) and new_cost <= cost:
            return _Step(step, lam, Xn, new_cost, Jn, en)
        lam *= 10.0
        if lam > 1e8:
            return _Step(np.zeros_like(X), lam)


def _solve(path, lm_all, obs: Observations, f: Factors):
    """Levenberg-Marquardt from ``path`` and ``lm_all`` over the odometry factors and the detections
    ``obs``. Returns the poses, all landmarks (those without a detection unchanged), iterations,
    initial and final cost, converged."""
    T = path.shape[0]
    # Only landmarks that explain a detection are variables (the others keep their positions).
    seen, lid = np.unique(obs.lid, return_inverse=True)
    lid = lid.reshape(-1)
    lm0, M = lm_all[seen], len(seen)
    prob = _problem(T, M, obs._replace(lid=lid))
    nP = 3 * T

    X = np.concatenate([path.ravel(), lm0.ravel()])
    cost, J, e = _linearise(prob, f, X)
    initial_cost, lam, converged, it = cost, 1e-4, False, 0
    for it in range(1, f.max_iter + 1):
        H = (J.T @ J).tocsr()
        g = J.T @ e
        st = _damped_step(prob, f, X, cost, H, g, lam)
        lam = st.lam
        if not np.any(st.step):
            converged = not np.any(g)  # at a stationary point; else damping could not lower the cost
            break
        assert st.X is not None and st.J is not None and st.e is not None  # a nonzero step reaches them
        X, cost, J, e = st.X, st.cost, st.J, st.e
        lam = max(lam / 10.0, 1e-9)
        if np.max(np.abs(st.step)) < f.tol:
            converged = True
            break
    lm_out = lm_all.copy()
    lm_out[seen] = X[nP:].reshape(M, 2)
    return X[:nP].reshape(T, 3), lm_out, it, initial_cost, cost, converged
