"""NASRUKF per beam's measurements (docs/method/nasrukf-beams.md; the step is :mod:`._nasrukf_beams`).

The range along a beam to a line in the state's form (:func:`line_ranges`), the square-root UKF
update with a feature's beams stacked as one vector measurement (:func:`stacked_update`,
:func:`update_from_prediction`, :func:`run_updates` over a window of features held as
:class:`FeatureBeams`), and the rows of the adaptive beam-noise estimate: the innovations
(:func:`innovation_rows`), the innovations with the state's uncertainty projected out
(:func:`projected_rows`) and the residuals after the update (:func:`posterior_rows`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax.scipy.linalg import cho_solve
from jaxtyping import Array, Bool, Float

from nanoslam_jax.models._lines import beam_range_line, beam_range_slope_intercept, beam_range_vertical
from nanoslam_jax.lib.quadrature import Unscented
from nanoslam_jax.methods.gaussian._srukf import SigmaMeasurement, _wrap_at, predict_measurement


def line_ranges(
    pose: Float[Array, "3"], phi: Float[Array, " k"], m: Float[Array, "2"], vertical: Bool[Array, ""], form: str
) -> tuple[Float[Array, " k"], Bool[Array, " k"]]:
    """Ranges along beams ``phi`` to a line in the state's form: the normal form, or the paper's
    eq. 14 (``y = a x + b``) and eq. 15 (``x = c`` where ``vertical``)."""
    if form == "normal":
        return beam_range_line(pose, phi, m)
    r1, h1 = beam_range_slope_intercept(pose, phi, m[0], m[1])
    r2, h2 = beam_range_vertical(pose, phi, m[0])
    return jnp.where(vertical, r2, r1), jnp.where(vertical, h2, h1)


def stacked_update(
    y: Float[Array, " n"],
    L: Float[Array, "n n"],
    h: Callable[[Float[Array, " n"]], Float[Array, " b"]],
    z: Float[Array, " b"],
    use: Bool[Array, " b"],
    noise_var: Float[Array, ""],
    rule: Unscented,
    x_angles: Sequence[int] = (),
) -> tuple[Float[Array, " n"], Float[Array, "n n"], SigmaMeasurement]:
    """The square-root UKF update (eq. 10-12) with the beams ``use`` of ``z`` stacked as one vector
    measurement of independent noise ``noise_var``: the sigma-point prediction of ``h`` (its unused
    entries set to 0), then :func:`update_from_prediction`.

    Args:
        y, L: the joint state's mean and lower square root.
        h: its predicted measurement.
        z: the measurement.
        use: which entries are real.
        noise_var: the noise variance of one entry.
        rule: the unscented rule.
        x_angles: angle components of ``y``.

    Returns:
        The updated mean and square root, and the sigma-point prediction (for the noise estimate).
    """
    pred = predict_measurement(y, L, lambda yy: jnp.where(use, h(yy), 0.0), rule)
    yn, Ln = update_from_prediction(y, L, pred, z, use, noise_var, x_angles)
    return yn, Ln, pred


def update_from_prediction(
    y: Float[Array, " n"],
    L: Float[Array, "n n"],
    pred: SigmaMeasurement,
    z: Float[Array, " b"],
    use: Bool[Array, " b"],
    noise_var: Float[Array, ""],
    x_angles: Sequence[int] = (),
) -> tuple[Float[Array, " n"], Float[Array, "n n"]]:
    """The square-root UKF update (eq. 10-12) of the joint state ``(y, L)`` from the sigma-point
    prediction ``pred`` of its stacked measurement (unused entries predicted as 0), with the beams
    ``use`` of ``z`` of independent noise ``noise_var``.

    ``Sz`` the lower Cholesky factor of ``sum_i wc_i dz_i dz_i' + R`` (the matrix whose square root
    eq. 12 forms by ``qr`` and ``cholupdate``); ``K = (Pxz / Sz') / Sz``; ``y + K (z - z_hat)``; the
    new square root the Cholesky factor of ``L L' - U U'``, ``U = K Sz`` (what eq. 12's rank-one
    downdates by the columns of ``U`` give). With ``b`` beams above the ``2n + 1`` sigma points and
    ``n <= 6``, one factorisation of each matrix is cheaper than the rotations, in time and in the
    size of the compiled program. Where rounding leaves ``L L' - U U'`` not positive definite (never
    with the algebra right) the state is left as it was. Unused entries predict and measure 0: their
    rows of ``Pxz`` are 0, so they change nothing.

    Args:
        y, L: the joint state's mean and lower square root.
        pred: the sigma-point prediction of its measurement.
        z: the measurement.
        use: which entries are real.
        noise_var: the noise variance of one entry.
        x_angles: angle components of ``y``.

    Returns:
        The updated mean and square root.
    """
    b = z.shape[0]
    Pzz = (pred.wc[:, None] * pred.dz).T @ pred.dz + noise_var * jnp.eye(b)
    Sz = jnp.linalg.cholesky(0.5 * (Pzz + Pzz.T))
    Pxz = (pred.wc[:, None] * pred.dx).T @ pred.dz
    K = cho_solve((Sz, True), Pxz.T).T
    nu = jnp.where(use, z - pred.z_hat, 0.0)
    U = K @ Sz
    P = L @ L.T - U @ U.T
    Ln = jnp.linalg.cholesky(0.5 * (P + P.T))
    ok = jnp.all(jnp.isfinite(Ln))
    return jnp.where(ok, _wrap_at(y + K @ nu, x_angles), y), jnp.where(ok, Ln, L)


def select_beams(sel: Bool[Array, " k"], size: int) -> tuple[Array, Bool[Array, " size"]]:
    """At most ``size`` of the beams ``sel``, evenly spread (every ``ceil(n / size)``-th), as indices and a mask."""
    n = jnp.sum(sel)
    stride = jnp.maximum(-(-n // size), 1)
    rank = jnp.cumsum(sel) - 1
    take = sel & (rank % stride == 0)
    idx = jnp.nonzero(take, size=size, fill_value=0)[0]
    return idx, jnp.arange(size) < jnp.sum(take)


class FeatureBeams(NamedTuple):
    """The stacked measurements of a window of features, one row per feature.

    Attributes:
        ys, Ls: the joint states (mean, lower square root) at the prior pose.
        zs, ps: the selected beams' ranges and angles.
        use: which of the selected beams are real.
        preds: the sigma-point predictions of the beams (unused entries 0).
    """

    ys: Float[Array, "w n"]
    Ls: Float[Array, "w n n"]
    zs: Float[Array, "w b"]
    ps: Float[Array, "w b"]
    use: Bool[Array, "w b"]
    preds: SigmaMeasurement


def innovation_rows(dat: FeatureBeams) -> tuple[Float[Array, "w 1"], Float[Array, "w 1"], Bool[Array, " w"]]:
    """Each feature's RMS innovation over its beams and their mean predicted variance, as rows of
    the noise estimate (``nasrukf.noise_residual: innovation``), and whether it has beams."""
    _, _, zs, _, use, preds = dat
    n = jnp.maximum(jnp.sum(use, axis=1), 1)
    nu2 = jnp.sum(jnp.where(use, jnp.square(zs - preds.z_hat), 0.0), axis=1) / n
    pv = jnp.sum(jnp.where(use, jax.vmap(SigmaMeasurement.variance)(preds), 0.0), axis=1) / n
    return jnp.sqrt(nu2)[:, None], pv[:, None], jnp.any(use, axis=1)


def projected_rows(
    dat: FeatureBeams, variance: Float[Array, ""]
) -> tuple[Float[Array, "w 1"], Float[Array, "w 1"], Bool[Array, " w"]]:
    """Each feature's innovations with the part the state's uncertainty can explain removed, as
    rows of the noise estimate (``nasrukf.noise_residual: projected``).

    A feature's ``b`` innovations ``nu`` have covariance ``H P H' + r I``. Projected onto the
    orthogonal complement of the columns of ``H P^(1/2)`` (here the sigma points' odd
    deviations, ``sqrt(2 wc) (dz_i - dz_(i+n)) / 2``: the linear part), they keep ``r I`` alone:
    ``E |nu_perp|^2 = r (b - k)`` with ``k`` the directions projected out, whatever ``P`` is. So
    the estimate does not trade the beam noise against the process noise (the innovation form's
    ``nu^2 - H P H'`` does: an overestimated ``P`` drives it to the floor, and the process-noise
    estimate, fed by updates that trust the beams too much, grows without bound). Directions the
    state moves the predictions by less than ``1e-3 variance`` are left in (they add at most that).

    Args:
        dat: the window's predictions and data (:class:`FeatureBeams`).
        variance: the current noise estimate (the threshold's scale).

    Returns:
        ``sqrt(|nu_perp|^2 / (b - k))`` and 0 (no predicted variance to subtract) per feature,
        and whether it has at least one degree of freedom left.
    """
    _, _, zs, _, use, preds = dat
    n = preds.dx.shape[-1]
    nu = jnp.where(use, zs - preds.z_hat, 0.0)
    D = (preds.dz[:, 1 : n + 1] - preds.dz[:, n + 1 :]) * (0.5 * jnp.sqrt(2.0 * preds.wc[:, 1, None, None]))
    vals, vecs = jnp.linalg.eigh(D @ jnp.swapaxes(D, 1, 2))
    keep = vals > 1e-3 * variance
    c = jnp.einsum("wnk,wnb,wb->wk", vecs, D, nu)
    along = jnp.sum(jnp.where(keep, jnp.square(c) / jnp.where(keep, vals, 1.0), 0.0), axis=1)
    dof = jnp.sum(use, axis=1) - jnp.sum(keep, axis=1)
    e2 = jnp.maximum(jnp.sum(jnp.square(nu), axis=1) - along, 0.0) / jnp.maximum(dof, 1)
    return jnp.sqrt(e2)[:, None], jnp.zeros_like(e2)[:, None], dof >= 1


def posterior_rows(ys, Ls, dat: FeatureBeams, h_of, vertical, rule):
    """Each updated feature's RMS residual ``z - h(x+)`` after its update and its mean predicted
    variance there (from the posterior's sigma points), as rows of the noise estimate."""
    _, _, zs, ps, use, _ = dat

    def one(y, L, z, p, u, v):
        pred = predict_measurement(y, L, lambda yy: jnp.where(u, h_of(yy, p, v), 0.0), rule)
        n = jnp.maximum(jnp.sum(u), 1)
        e2 = jnp.sum(jnp.where(u, jnp.square(z - pred.z_hat), 0.0)) / n
        return jnp.sqrt(e2)[None], (jnp.sum(jnp.where(u, pred.variance(), 0.0)) / n)[None]

    return jax.vmap(one)(ys, Ls, zs, ps, use, vertical)


def run_updates(
    dat: FeatureBeams, var: Float[Array, " w"], angles: Sequence[int]
) -> tuple[Float[Array, "w n"], Float[Array, "w n n"]]:
    """Every feature's stacked update from its prediction in ``dat`` (:func:`update_from_prediction`),
    vmapped over the window, with noise variance ``var`` per feature; ``angles``: the joint state's
    angle components.

    Returns:
        The updated means and square roots.
    """
    ys, Ls, zs, _, use, preds = dat

    def one(y, L, z, u, s2, pred):
        return update_from_prediction(y, L, pred, z, u, s2, angles)

    return jax.vmap(one)(ys, Ls, zs, use, var, preds)
