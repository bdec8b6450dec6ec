"""Square-root unscented Kalman filter primitives and the adaptive measurement-noise estimator.

These are the building blocks of NASRUKF FastSLAM (docs/method/nasrukf.md; the NASRUKF paper's eq. 8-13):

- :func:`chol_rank_one` / :func:`chol_rank_update`: the ``cholupdate`` of eq. 9, 11 and 12, a
  rank-one update (``L L' + w v v'``, ``w > 0``) or downdate (``w < 0``) of a lower Cholesky factor
  by Givens (update) or hyperbolic (downdate) rotations, O(n^2), never a re-factorisation.
- :func:`qr_factor`: the ``qr{[...]}`` of eq. 9 and 12, the lower triangular square root of
  ``M M'`` from the R factor of a QR decomposition of ``M'``.
- :func:`srukf_transform`: the square-root unscented transform of ``y = f(x, w)`` with the noise
  ``w`` augmented (the time update of eq. 8-9, and a new feature's initialisation).
- :func:`predict_measurement` and :func:`measurement_update`: the sigma-point measurement update
  of eq. 10 and 12 (``Sz`` by QR and a rank-one update, ``K = (Pxz / Sz') / Sz``, the state's
  square root downdated by the columns of ``U = K Sz``).
- :func:`adaptive_noise_update` / :func:`adaptive_noise_rows`: the measurement-noise estimate of
  eq. 11 with the forgetting factor ``b``, ``d_k = (1 - b) / (1 - b^(k+1))``;
  :func:`adaptive_noise_summary` (numpy, on the host) reports where a run's estimates ended.
- :func:`process_noise_basis` / :func:`adaptive_process_update`: the estimated process noise
  ``Q`` of eq. 9, a Sage-Husa estimate with the same weights ``d_k`` from the state corrections
  and the covariance change of the updates; :func:`adaptive_process_summary` reports it.

Conventions: the square root of a covariance ``P`` is a lower triangular ``L`` with ``L L' = P`` and
a non-negative diagonal. Sigma points are those of :class:`~nanoslam_jax.lib.quadrature.Unscented`
(``2n + 1`` points, eq. 13; the paper's ``gamma = sqrt(n + lambda)``). Angle components (given by
static index tuples) are averaged relative to the centre point and their deviations wrapped.
Everything works on one filter; ``jax.vmap`` it over features or particles.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax.scipy.linalg import cho_solve, solve_triangular
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from nanoslam_jax.models import wrap_angle
from nanoslam_jax.lib.quadrature import Unscented

#: A downdate whose pivot would fall below ``sqrt(DOWNDATE_FLOOR)`` of its old value (the result
#: would be indefinite: never so when the caller's algebra is right, only by rounding) leaves that
#: column unrotated instead.
DOWNDATE_FLOOR = 1e-12


def _wrap_at(d: Float[Array, "... n"], angles: Sequence[int]) -> Float[Array, "... n"]:
    """``d`` with the components ``angles`` wrapped to (-pi, pi]."""
    for i in angles:
        d = d.at[..., i].set(wrap_angle(d[..., i]))
    return d


def chol_rank_one(L: Float[Array, "n n"], v: Float[Array, " n"], weight: Float[ArrayLike, ""]) -> Float[Array, "n n"]:
    """The lower Cholesky factor of ``L L' + weight v v'`` (``cholupdate``), by rotations.

    For ``weight > 0`` each column pair ``(L[:, k], v)`` is turned by a Givens rotation that
    zeroes ``v[k]`` (``L L' + w v v'`` is invariant); for ``weight < 0`` by a hyperbolic rotation
    (invariant: ``L L' - |w| v v'``). O(n^2), no re-factorisation. ``weight`` may be traced (its
    sign picks the rotation).

    Args:
        L: lower triangular factor with a non-negative diagonal (may be singular for an update).
        v: the update vector.
        weight: scalar weight ``w``; ``0`` returns ``L`` unchanged.

    A downdate that would make the matrix indefinite leaves the offending column unrotated (see
    :data:`DOWNDATE_FLOOR`): the result stays finite and positive semi-definite.
    """
    n = L.shape[-1]
    weight = jnp.asarray(weight, L.dtype)
    sign = jnp.where(weight < 0, -1.0, 1.0)
    v = jnp.sqrt(jnp.abs(weight)) * v
    rows = jnp.arange(n)
    cols = []
    for k in range(n):
        col = L[:, k]
        lk, xk = col[k], v[k]
        r2 = lk * lk + sign * xk * xk
        breakdown = (sign < 0) & (r2 <= DOWNDATE_FLOOR * lk * lk)
        r = jnp.sqrt(jnp.where(breakdown, lk * lk, r2))
        trivial = breakdown | (r == 0)
        safe_r = jnp.where(trivial, 1.0, r)
        c = jnp.where(trivial, 1.0, lk / safe_r)
        s = jnp.where(trivial, 0.0, xk / safe_r)
        below = rows > k
        new_col = jnp.where(below, c * col + sign * s * v, jnp.where(rows == k, jnp.where(trivial, lk, r), col))
        v = jnp.where(below, c * v - s * col, 0.0)
        cols.append(new_col)
    return jnp.stack(cols, axis=-1)


def chol_rank_update(
    L: Float[Array, "n n"], V: Float[Array, "n k"], weight: Float[ArrayLike, ""]
) -> Float[Array, "n n"]:
    """``L L' + weight V V'`` by :func:`chol_rank_one` with each column of ``V`` in turn (``k`` static)."""
    for j in range(V.shape[-1]):
        L = chol_rank_one(L, V[:, j], weight)
    return L


def qr_factor(M: Float[Array, "n m"]) -> Float[Array, "n n"]:
    """Lower triangular ``L`` with ``L L' = M M'`` (``m >= n``): the transposed R factor of ``qr(M')``,
    its rows' signs normalised so the diagonal is non-negative."""
    n, m = M.shape
    if m < n:
        raise ValueError(f"qr_factor needs at least as many columns as rows, got {M.shape}")
    R = jnp.linalg.qr(M.T, mode="r")
    sign = jnp.where(jnp.diagonal(R) < 0, -1.0, 1.0)
    return (R * sign[:, None]).T


def block_diag(A: Float[Array, "n n"], B: Float[Array, "k k"]) -> Float[Array, "n+k n+k"]:
    """The block-diagonal matrix ``[[A, 0], [0, B]]`` (square roots of independent parts)."""
    n, k = A.shape[0], B.shape[0]
    top = jnp.concatenate([A, jnp.zeros((n, k), A.dtype)], axis=1)
    bottom = jnp.concatenate([jnp.zeros((k, n), A.dtype), B], axis=1)
    return jnp.concatenate([top, bottom], axis=0)


def sigma_offsets(
    L: Float[Array, "n n"], rule: Unscented
) -> tuple[Float[Array, "m n"], Float[Array, " m"], Float[Array, " m"]]:
    """The sigma points' offsets from the mean (eq. 8: ``0, +gamma L[:, i], -gamma L[:, i]``) and weights."""
    xi, wm, wc = rule.unit_points(L.shape[-1])
    return xi @ L.T, wm, wc


def _stats(Y: Float[Array, "m d"], wm: Float[Array, " m"], angles: Sequence[int]):
    """Weighted mean of transformed points (angles relative to the centre point) and the
    deviations from it."""
    dev = _wrap_at(Y - Y[0], angles)
    shift = wm @ dev
    return _wrap_at(Y[0] + shift, angles), dev - shift


def _sqrt_from_deviations(D: Float[Array, "m d"], wc: Float[Array, " m"], extra: Float[Array, "d q"] | None = None):
    """``qr{[sqrt(wc_1) D_1:m, extra]}`` then ``cholupdate{., D_0, wc_0}`` (eq. 9 and 12): the square
    root of ``sum_i wc_i D_i D_i' + extra extra'`` (the weights of points ``1..m-1`` are equal)."""
    M = jnp.sqrt(wc[1]) * D[1:].T
    if extra is not None:
        M = jnp.concatenate([M, extra], axis=1)
    return chol_rank_one(qr_factor(M), D[0], wc[0])


def srukf_transform(
    x: Float[Array, " n"],
    L: Float[Array, "n n"],
    f: Callable[[Float[Array, " n"], Float[Array, " q"]], Float[Array, " d"]],
    noise_sqrt: Float[Array, "q q"],
    rule: Unscented,
    angles: Sequence[int] = (),
) -> tuple[Float[Array, " d"], Float[Array, "d d"]]:
    """Square-root unscented transform of ``y = f(x, w)``, ``x ~ N(x, L L')``, ``w ~ N(0, noise_sqrt noise_sqrt')``.

    The sigma points are those of the augmented state ``(x, w)`` (eq. 8 with the noise appended,
    as the noise enters ``f`` non-additively); the mean is their weighted image (eq. 9) and the
    square root ``qr`` of the weighted deviations followed by a rank-one ``cholupdate`` with the
    centre's deviation and weight (eq. 9).

    Args:
        x, L: the state's mean and lower square root.
        f: ``f(x, w)``; vmapped over the sigma points.
        noise_sqrt: lower square root of the noise covariance (``q >= 1``).
        rule: the unscented rule (``alpha``, ``beta``, ``kappa``).
        angles: static indices of the angle components of ``y`` (circular mean, wrapped deviations).

    Returns:
        The mean and lower square root of ``y``.
    """
    n = x.shape[0]
    offsets, wm, wc = sigma_offsets(block_diag(L, noise_sqrt), rule)
    Y = jax.vmap(f)(x + offsets[:, :n], offsets[:, n:])
    mean, D = _stats(Y, wm, angles)
    return mean, _sqrt_from_deviations(D, wc)


class SigmaMeasurement(NamedTuple):
    """The sigma points of a state pushed through a measurement function (eq. 10-11).

    Attributes:
        dx: the points' offsets from the state mean (``gamma`` times the square root's columns).
        z_hat: predicted measurement (eq. 11: the weighted mean of the images).
        dz: the images' deviations from ``z_hat`` (angles wrapped).
        wm, wc: mean and covariance weights (eq. 13).
    """

    dx: Float[Array, "m n"]
    z_hat: Float[Array, " mz"]
    dz: Float[Array, "m mz"]
    wm: Float[Array, " m"]
    wc: Float[Array, " m"]

    def variance(self) -> Float[Array, " mz"]:
        """Diagonal of the predicted measurement covariance without the noise, ``sum_i wc_i dz_i^2``."""
        return self.wc @ jnp.square(self.dz)


def predict_measurement(
    x: Float[Array, " n"],
    L: Float[Array, "n n"],
    h: Callable[[Float[Array, " n"]], Float[Array, " mz"]],
    rule: Unscented,
    z_angles: Sequence[int] = (),
) -> SigmaMeasurement:
    """Sigma points of ``N(x, L L')`` (eq. 10) and their images under ``h`` (eq. 11).

    Args:
        x, L: the predicted state's mean and lower square root.
        h: measurement function; vmapped over the points.
        rule: the unscented rule.
        z_angles: static indices of the angle components of the measurement.
    """
    offsets, wm, wc = sigma_offsets(L, rule)
    z_hat, dz = _stats(jax.vmap(h)(x + offsets), wm, z_angles)
    return SigmaMeasurement(offsets, z_hat, dz, wm, wc)


def measurement_update(
    x: Float[Array, " n"],
    L: Float[Array, "n n"],
    pred: SigmaMeasurement,
    z: Float[Array, " mz"],
    noise_sqrt: Float[Array, "mz mz"],
    x_angles: Sequence[int] = (),
    z_angles: Sequence[int] = (),
) -> tuple[Float[Array, " n"], Float[Array, "n n"], Float[Array, " mz"], Float[Array, "mz mz"]]:
    """The square-root measurement update (eq. 12).

    ``Sz = qr{[sqrt(wc_1) dz_1:2n, sqrt(R)]}`` then ``cholupdate{Sz, dz_0, wc_0}``;
    ``Pxz = sum_i wc_i dx_i dz_i'``; ``K = (Pxz / Sz') / Sz`` (two triangular solves);
    ``x + K (z - z_hat)``; and ``L`` downdated by each column of ``U = K Sz``.

    Args:
        x, L: the predicted state's mean and lower square root.
        pred: :func:`predict_measurement` of ``x, L``.
        z: the measurement.
        noise_sqrt: lower square root of the measurement noise covariance.
        x_angles, z_angles: static indices of angle components (wrapped).

    Returns:
        The updated mean and square root, the innovation ``z - z_hat`` and ``Sz`` (the square
        root of the innovation covariance).
    """
    Sz = _sqrt_from_deviations(pred.dz, pred.wc, noise_sqrt)
    Pxz = (pred.wc[:, None] * pred.dx).T @ pred.dz
    K = cho_solve((Sz, True), Pxz.T).T
    nu = _wrap_at(z - pred.z_hat, z_angles)
    x_new = _wrap_at(x + K @ nu, x_angles)
    return x_new, chol_rank_update(L, K @ Sz, -1.0), nu, Sz


def forgetting_weight(b: Float[ArrayLike, ""], k: Int[ArrayLike, ""]) -> Float[Array, ""]:
    """``d_k = (1 - b) / (1 - b^(k+1))``: the weight of the ``k``-th (0-based) residual in the
    noise estimate (``d_0 = 1``; ``d_k -> 1 - b``)."""
    b = jnp.asarray(b, float)
    return (1.0 - b) / (1.0 - jnp.power(b, jnp.asarray(k, float) + 1.0))


def adaptive_noise_update(
    variance: Float[Array, " mz"],
    k: Int[ArrayLike, ""],
    nu: Float[Array, " mz"],
    predicted: Float[Array, " mz"],
    b: Float[ArrayLike, ""],
    floor: Float[Array, " mz"],
) -> Float[Array, " mz"]:
    """The measurement-noise variances after the ``k``-th residual (eq. 11).

    Eq. 11 forms ``R** = (1 - d) R + d |nu| |nu|'`` and ``R* = R** - d sum_i wc_i dz_i dz_i'`` by
    two ``cholupdate`` calls and keeps ``diag(R*)``; this computes that diagonal directly,
    ``(1 - d) R_ii + d (nu_i^2 - sum_j wc_j dz_ji^2)`` (equal wherever the paper's downdates
    succeed; where the estimate would not be positive, where the paper's downdate fails, it is
    held at ``floor``).

    Args:
        variance: the current estimate (diagonal of ``R``).
        k: how many residuals it has seen (0 for the first).
        nu: the residual ``z - z_hat``.
        predicted: diagonal of the predicted measurement covariance without noise
            (:meth:`SigmaMeasurement.variance`, or ``diag(H P H')`` for a linearised filter).
        b: forgetting factor in (0, 1).
        floor: smallest variances allowed.
    """
    d = forgetting_weight(b, k)
    return jnp.maximum((1.0 - d) * variance + d * (jnp.square(nu) - predicted), floor)


def adaptive_noise_rows(
    variance: Float[Array, " mz"],
    k: Int[Array, ""],
    nu: Float[Array, "rows mz"],
    predicted: Float[Array, "rows mz"],
    use: Bool[Array, " rows"],
    b: Float[ArrayLike, ""],
    floor: Float[Array, " mz"],
) -> tuple[Float[Array, "rows mz"], Float[Array, " mz"], Int[Array, ""]]:
    """:func:`adaptive_noise_update` over a scan's detections in order (rows not ``use``d skipped).

    Returns:
        The estimate after each row (a row's own residual included, as eq. 11 precedes eq. 12),
        the estimate after the last row, and the new residual count.
    """

    def body(carry, inp):
        var, count = carry
        nu_i, p_i, use_i = inp
        new = jnp.where(use_i, adaptive_noise_update(var, count, nu_i, p_i, b, floor), var)
        count = count + use_i.astype(count.dtype)
        return (new, count), new

    (last, count), per_row = jax.lax.scan(body, (variance, jnp.asarray(k)), (nu, predicted, use))
    return per_row, last, count


#: :func:`adaptive_noise_summary` warns when at least this fraction of the particles' estimates of a
#: noise component ends a run at its floor.
NOISE_FLOOR_WARN_FRACTION = 0.5

#: The keys :func:`adaptive_noise_summary` always returns (sweeps record them as columns).
NOISE_SUMMARY_KEYS = (
    "noise_sigma_r_final",
    "noise_sigma_beta_deg_final",
    "noise_at_floor_range",
    "noise_at_floor_bearing",
)

#: The keys :func:`adaptive_noise_summary` adds for NASRUKF's arc features (the diameter's noise).
NOISE_ARC_SUMMARY_KEYS = ("noise_sigma_diameter_final", "noise_at_floor_diameter")

_COMPONENTS = ("range", "bearing", "diameter")


def noise_estimates(state) -> Array:
    """The adaptive measurement-noise variances a filter state holds: ``(particles, mz)`` for a
    particle filter's state (each particle's), ``(mz,)`` for NASRUKF's (one estimate)."""
    return state.particles.noise if hasattr(state, "particles") else state.noise


def adaptive_noise_summary(noise: ArrayLike, configured: ArrayLike, floor_fraction: float) -> tuple[dict, list[str]]:
    """Where a run's adaptive measurement-noise estimates ended, and warnings where they sit at the floor.

    An estimate held at its floor says the residuals were smaller than the filter predicted, not
    that the sensor is that precise: the gates shrink and detections of mapped landmarks fail
    association (``noise.adaptive``'s documentation).

    Args:
        noise: ``(particles, mz)`` or ``(mz,)`` final variances (range, bearing, and diameter for
            arc features).
        configured: ``(mz,)`` (or longer) configured variances.
        floor_fraction: ``noise.adaptive_floor``, the floor as a fraction of ``configured``.

    Returns:
        ``(metrics, warnings)``: ``noise_sigma_r_final`` (m), ``noise_sigma_beta_deg_final`` (deg)
        and, for arcs, ``noise_sigma_diameter_final`` (m): medians over the particles of the
        estimated standard deviations; ``noise_at_floor_range`` / ``_bearing`` / ``_diameter``: the
        fraction of the particles at the floor; one warning per component at the floor in at least
        :data:`NOISE_FLOOR_WARN_FRACTION` of them.
    """
    noise = np.asarray(noise, float)
    noise = noise.reshape(-1, noise.shape[-1])
    floor = floor_fraction * np.asarray(configured, float)[: noise.shape[-1]]
    at_floor = np.mean(noise <= floor * (1.0 + 1e-9), axis=0)
    sigma = np.sqrt(np.median(noise, axis=0))
    names = _COMPONENTS[: noise.shape[-1]]
    metrics = {"noise_sigma_r_final": float(sigma[0])}
    if noise.shape[-1] > 1:
        metrics["noise_sigma_beta_deg_final"] = math.degrees(sigma[1])
    if noise.shape[-1] > 2:
        metrics["noise_sigma_diameter_final"] = float(sigma[2])
    metrics.update({f"noise_at_floor_{n}": float(f) for n, f in zip(names, at_floor)})
    warnings = [
        f"noise.adaptive: the {n} noise estimate ended at noise.adaptive_floor ({floor_fraction:g} of the configured "
        f"variance) in {100 * f:.0f} % of the particles: the residuals were smaller than the filter predicted, "
        "so the gates shrank and detections of mapped landmarks may fail association; see the key's documentation"
        for n, f in zip(names, at_floor)
        if f >= NOISE_FLOOR_WARN_FRACTION
    ]
    return metrics, warnings


def process_noise_basis(
    basis: Float[Array, "w w 3 3"],
    x: Float[Array, "3"],
    dt: Float[Array, " dr"],
    u: Float[Array, "dr c"],
    dr_mask: Bool[Array, " dr"],
    motion,
) -> Float[Array, "w w 3 3"]:
    """The linear map from the process-noise scale ``Lambda`` to the pose covariance it adds.

    A time update with the noise ``S(dt) Lambda^(1/2) e`` (``S`` the motion model's
    :meth:`~nanoslam_jax.models.AbstractMotionModel.noise_sqrt`, ``e`` white) adds, linearised,
    ``Q_pose = sum_ab Lambda_ab B_ab`` to the pose covariance; each piece maps the basis on,
    ``B_ab <- F B_ab F' + A_a A_b'`` with ``F = df/dx``, ``A = (df/dw) S(dt)`` at the noise-free
    pose (autodiff). The basis accumulates over segments until an update uses it.

    Args:
        basis: the basis so far (zeros right after an update).
        x: the pose at the start of the segment.
        dt, u, dr_mask: the segment's DR pieces (masked pieces change nothing).
        motion: the motion model.

    Returns:
        The basis at the end of the segment.
    """

    def body(i, carry):
        p, B = carry
        F, G = motion.jacobians(p, u[i], dt[i])
        A = G @ motion.noise_sqrt(dt[i])
        Bn = jnp.einsum("ij,abjk,lk->abil", F, B, F) + jnp.einsum("ia,jb->abij", A, A)
        pn = motion.step(p, u[i], dt[i])
        return jnp.where(dr_mask[i], pn, p), jnp.where(dr_mask[i], Bn, B)

    n_pieces = jnp.max(jnp.where(dr_mask, jnp.arange(1, dr_mask.shape[0] + 1), 0))
    return jax.lax.fori_loop(0, n_pieces, body, (x, basis))[1]


#: Singular values of the whitened basis below this fraction of the largest are not inverted by
#: :func:`adaptive_process_update`: a noise direction that adds less than that to the prior, relative
#: to the best-seen one, keeps its scale for that update.
PROCESS_RCOND = 1e-2


def adaptive_process_update(
    scale: Float[Array, "w w"],
    k: Int[ArrayLike, ""],
    change: Float[Array, "3 3"],
    prior_sqrt: Float[Array, "3 3"],
    basis: Float[Array, "w w 3 3"],
    b: Float[ArrayLike, ""],
    floor: Float[ArrayLike, ""],
) -> Float[Array, "w w"]:
    """The process-noise scale after the ``k``-th update (Sage-Husa, weights ``d_k``).

    The noise of the time update is ``S(dt) Lambda^(1/2) e``, ``Lambda = I`` the configured one. An
    update moves the pose by ``dx = K nu`` and its covariance from ``P-`` to ``P``. With
    ``P- = Phi P_prev Phi' + Q_pose(Lambda)`` and ``E[dx dx'] = P- - P`` for the true noise, the
    one-update sample of the noise is ``Q_hat = dx dx' + P - Phi P_prev Phi' = Q_pose(Lambda) +
    (dx dx' + P - P-)``; its scale is read off the linear map ``Q_pose`` (:func:`process_noise_basis`)
    by least squares in the prior's whitened frame (``P-^(-1/2) . P-^(-T/2)``), and
    ``Lambda_k = (1 - d_k) Lambda_(k-1) + d_k Lambda_hat = Lambda_(k-1) + d_k L^+(dx dx' + P - P-)``.
    The result is symmetrised and its eigenvalues held at ``floor`` or above (positive definite).

    Args:
        scale: the current ``Lambda`` (symmetric positive definite).
        k: updates it has seen (0 for the first).
        change: ``dx dx' + P - P-`` of this update (the pose's).
        prior_sqrt: lower square root of ``P-``.
        basis: the map ``Lambda -> Q_pose`` since the previous update.
        b: forgetting factor in (0, 1).
        floor: smallest eigenvalue of ``Lambda`` (a fraction of the configured noise).
    """
    w = scale.shape[0]
    Wi = solve_triangular(prior_sqrt, jnp.eye(3, dtype=prior_sqrt.dtype), lower=True)
    white = lambda M: (Wi @ M @ Wi.T).reshape(-1)  # noqa: E731
    pairs = [(a, c) for a in range(w) for c in range(a, w)]
    X = jnp.stack([white(basis[a, c] + basis[c, a] if a != c else basis[a, a]) for a, c in pairs], axis=1)
    y = white(0.5 * (change + change.T))
    theta = jnp.linalg.lstsq(X, y, rcond=PROCESS_RCOND)[0]
    inc = jnp.zeros((w, w), scale.dtype)
    for i, (a, c) in enumerate(pairs):
        inc = inc.at[a, c].set(theta[i]).at[c, a].set(theta[i])
    new = scale + forgetting_weight(b, k) * inc
    vals, vecs = jnp.linalg.eigh(0.5 * (new + new.T))
    held = (vecs * jnp.maximum(vals, floor)) @ vecs.T
    return 0.5 * (held + held.T)


def adaptive_process_summary(scale: ArrayLike, count: int, floor: float) -> tuple[dict, list[str]]:
    """Where a run's process-noise estimate ended, and a warning where it sits at the floor.

    Args:
        scale: the final ``Lambda`` (``w x w``): the estimated noise covariance is
            ``S Lambda S'`` with ``S`` the configured square root.
        count: updates the estimate has seen.
        floor: ``nasrukf.process_floor``.

    Returns:
        ``(metrics, warnings)``: ``process_noise_ratio_<j>`` (``sqrt(Lambda_jj)``, the estimated
        standard deviation of noise component ``j`` over the configured one), ``process_noise_scale``
        (``Lambda`` as nested lists), ``process_noise_updates`` and ``process_noise_at_floor``
        (whether its smallest eigenvalue is at the floor).
    """
    scale = np.asarray(scale, float)
    at_floor = bool(np.min(np.linalg.eigvalsh(scale)) <= floor * (1.0 + 1e-9))
    metrics = {f"process_noise_ratio_{j}": float(np.sqrt(scale[j, j])) for j in range(scale.shape[0])}
    metrics.update(
        process_noise_scale=scale.tolist(), process_noise_updates=int(count), process_noise_at_floor=at_floor
    )
    warnings = (
        [
            f"nasrukf.adaptive_process: the process-noise estimate ended at nasrukf.process_floor ({floor:g} of "
            "the configured covariance) in some direction: the pose corrections were smaller than the "
            "configured noise predicts there"
        ]
        if at_floor
        else []
    )
    return metrics, warnings
