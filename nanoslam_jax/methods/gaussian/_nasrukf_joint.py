"""NASRUKF's joint pose-feature states (docs/method/nasrukf.md; the step is :mod:`._nasrukf`).

A feature's joint state with the vehicle pose is stored in conditional form ``(mean, gain,
sqrt)`` given the shared pose ``N(x, S S')``; its lower square root is ``[[S, 0], [gain S,
sqrt]]`` (:func:`joint_sqrt`). Here: the pose's square-root unscented time update with its start
pose carried (:func:`pose_time_update`) and the features' part of it (:func:`propagate_features`),
the feedback of a joint state to the global pose (:func:`to_conditional`), a joint state's
predicted detection (:func:`measure`), a new feature's joint state (:func:`init_feature`), the
association's innovation information (:func:`association_information`) and the information-weighted
fusion of the per-feature pose estimates (:func:`fuse_poses`, eq. 4-5).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from nanoslam_jax.lib._linalg import chol3, inv2, inv3, mm, mmt, mt, mv, sandwich, sym
from nanoslam_jax.models import inverse_range_bearing, range_bearing, range_bearing_jacobians, wrap_angle
from nanoslam_jax.lib.quadrature import Unscented
from nanoslam_jax.methods._params import Params
from nanoslam_jax.methods.gaussian._srukf import adaptive_process_update, chol_rank_update, srukf_transform
from nanoslam_jax.methods.gaussian._nasrukf_state import NasrukfFeatures


def _rule(params: Params) -> Unscented:
    return Unscented(params.ut_alpha, params.ut_beta, params.ut_kappa)


def _minus(a: Float[Array, "3"], b: Float[Array, "3"]) -> Float[Array, "3"]:
    """Pose difference ``a - b`` with the heading wrapped."""
    d = a - b
    return d.at[2].set(wrap_angle(d[2]))


def pose_time_update(
    x: Float[Array, "3"],
    S: Float[Array, "3 3"],
    dt: Float[Array, " dr"],
    u: Float[Array, "dr c"],
    dr_mask: Bool[Array, " dr"],
    params: Params,
    noise_scale_sqrt: Float[Array, "w w"] | None = None,
) -> tuple[Float[Array, "3"], Float[Array, "3 3"], Float[Array, "3 3"], Float[Array, "3 3"]]:
    """The pose's SR-UKF time update through a segment's DR pieces, with its start pose carried.

    The state ``(x, x_start)`` starts as ``(x, x)`` with square root ``[[S, 0], [S, 0]]``; each
    real piece is a :func:`~._srukf.srukf_transform` with the control noise augmented
    (``x <- f(x, u + w)``, ``x_start`` unchanged). From the final square root
    ``[[S_x, 0], [S_sx, D]]``: ``T = S_sx S_x^-1`` (the start pose's regression on the predicted
    one) and ``D`` (the square root of ``Cov(x_start | x)``).

    Args:
        x, S: the pose mean and lower square root at the start of the segment.
        dt, u, dr_mask: the segment's DR pieces (masked pieces change nothing).
        params: vehicle constants, control noise, unscented parameters.
        noise_scale_sqrt: a lower square root ``Lambda^(1/2)`` scaling the motion model's noise,
            ``S(dt) Lambda^(1/2)`` (the estimated ``Q`` of eq. 9); None: the configured noise.

    Returns:
        The predicted mean and square root, ``T`` and ``D``.
    """
    rule = _rule(params)
    zero = jnp.zeros((3, 3), S.dtype)
    L = jnp.concatenate([jnp.concatenate([S, zero], 1), jnp.concatenate([S, zero], 1)], 0)
    motion = params.motion

    def body(i, carry):
        y, L = carry

        def move(p, w):
            return jnp.concatenate([motion.noisy_step(p[:3], u[i], w, dt[i]), p[3:]])

        Sw = motion.noise_sqrt(dt[i])
        Sw = Sw if noise_scale_sqrt is None else Sw @ noise_scale_sqrt
        yn, Ln = srukf_transform(y, L, move, Sw, rule, angles=(2, 5))
        return jnp.where(dr_mask[i], yn, y), jnp.where(dr_mask[i], Ln, L)

    n_pieces = jnp.max(jnp.where(dr_mask, jnp.arange(1, dr_mask.shape[0] + 1), 0))
    y, L = jax.lax.fori_loop(0, n_pieces, body, (jnp.concatenate([x, x]), L))
    Sx = L[:3, :3]
    return y[:3], Sx, mm(L[3:, :3], inv3(Sx)), L[3:, 3:]


def propagate_features(features: NasrukfFeatures, T: Float[Array, "3 3"], D: Float[Array, "3 3"]) -> NasrukfFeatures:
    """The features' part of the joint time update: ``gain <- gain T``, ``sqrt sqrt' += gain D D' gain'``
    (rank-one ``cholupdate`` with each column of ``gain D``)."""
    cols = mm(features.gain, D)
    sqrt = jax.vmap(chol_rank_update, (0, 0, None))(features.sqrt, cols, 1.0)
    return features._replace(gain=mm(features.gain, T), sqrt=sqrt)


def joint_sqrt(S: Float[Array, "3 3"], gain: Float[Array, "f 3"], sqrt: Float[Array, "f f"]) -> Float[Array, "n n"]:
    """Lower square root ``[[S, 0], [gain S, sqrt]]`` of a feature's joint state (pose first)."""
    f = gain.shape[0]
    top = jnp.concatenate([S, jnp.zeros((3, f), S.dtype)], 1)
    return jnp.concatenate([top, jnp.concatenate([gain @ S, sqrt], 1)], 0)


def to_conditional(
    x: Float[Array, "3"], m: Float[Array, " f"], L: Float[Array, "n n"], x_global: Float[Array, "3"]
) -> tuple[Float[Array, " f"], Float[Array, "f 3"], Float[Array, "f f"]]:
    """A joint state ``N((x, m), L L')`` fed back to the global pose (the feature's conditional kept).

    Returns:
        The feature's ``(mean, gain, sqrt)`` given the shared pose: ``gain = L_mx L_xx^-1``,
        ``sqrt = L_mm``, ``mean = m + gain (x_global - x)``.
    """
    gain = mm(L[3:, :3], inv3(L[:3, :3]))
    return m + gain @ _minus(x_global, x), gain, L[3:, 3:]


def measure(y: Float[Array, " n"]) -> Float[Array, " mz"]:
    """A joint state's predicted detection: range and bearing of the centre (and the diameter,
    twice the radius, for arcs)."""
    zb = range_bearing(y[:3], y[3:5])
    return jnp.concatenate([zb, 2.0 * y[5:6]]) if y.shape[0] == 6 else zb


def init_feature(
    x: Float[Array, "3"], S: Float[Array, "3 3"], z: Float[Array, " mz"], noise: Float[Array, " mz"], params: Params
) -> tuple[Float[Array, " n"], Float[Array, "n n"]]:
    """A new feature's joint state: the SR unscented transform of (pose, detection) through
    ``(x, m) = (x, g^-1(x, z))`` (and the radius as half the diameter for arcs).

    Args:
        x, S: the pose mean and lower square root.
        z: the detection (range, bearing[, diameter]).
        noise: measurement-noise variances.
        params: unscented parameters.
    """

    def place(p, w):
        zw = z + w
        parts = [p, inverse_range_bearing(p, zw[:2])] + ([0.5 * zw[2:3]] if z.shape[0] == 3 else [])
        return jnp.concatenate(parts)

    return srukf_transform(x, S, place, jnp.diag(jnp.sqrt(noise)), _rule(params), angles=(2,))


def association_information(
    x: Float[Array, "3"],
    P: Float[Array, "3 3"],
    mean: Float[Array, "slots f"],
    gain: Float[Array, "slots f 3"],
    sqrt: Float[Array, "slots f f"],
    R: Float[Array, "2 2"],
) -> tuple[
    tuple[Float[Array, " slots"], Float[Array, " slots"]],
    tuple[Float[Array, " slots"], Float[Array, " slots"], Float[Array, " slots"]],
]:
    """Predicted range and bearing of each slot's centre and the entries of its inverse innovation
    covariance ``J P J' + Gm C Gm' + R``, ``J = Gx + Gm gain`` (joint state linearised, autodiff)."""
    c = mean[:, :2]
    z_hat = jax.vmap(range_bearing, (None, 0))(x, c)
    Gx, Gm = jax.vmap(range_bearing_jacobians, (None, 0))(x, c)
    J = Gx + mm(Gm, gain[:, :2])
    s = sqrt[:, :2, :2]
    Si = inv2(sym(sandwich(J, P) + sandwich(Gm, mmt(s, s)) + R))
    return (z_hat[:, 0], z_hat[:, 1]), (Si[:, 0, 0], Si[:, 0, 1], Si[:, 1, 1])


def _information(L: Float[Array, "3 3"]) -> Float[Array, "3 3"]:
    """``(L L')^-1`` from a lower square root."""
    Li = inv3(L)
    return mm(mt(Li), Li)


def fuse_poses(
    x0: Float[Array, "3"],
    S0: Float[Array, "3 3"],
    xs: Float[Array, "k 3"],
    Ls: Float[Array, "k 3 3"],
    use: Bool[Array, " k"],
    shared_prior: bool = True,
) -> tuple[Float[Array, "3"], Float[Array, "3 3"]]:
    """The global pose from per-feature pose estimates, information-weighted (eq. 4-5).

    Args:
        x0, S0: the scan's prior pose (mean, lower square root).
        xs, Ls: the per-feature pose estimates (means, lower square roots).
        use: which estimates take part (none: the prior is returned).
        shared_prior: the estimates all started from ``N(x0, S0 S0')`` (the filter's case): eq. 4
            is applied to their information gains over it, ``Lambda = Lambda_0 + sum_i (Lambda_i -
            Lambda_0)``, the exact posterior when the detections are independent given the pose.
            False: eq. 4 as printed for independent estimates, ``Lambda = sum_i Lambda_i``. Both
            ``x = x0 + Lambda^-1 sum_i Lambda_i (x_i - x0)`` (headings relative to ``x0``).

    Returns:
        The fused mean (heading wrapped) and the lower square root of ``Lambda^-1``.
    """
    I0 = _information(S0)
    Ii = jax.vmap(_information)(Ls)
    w = use.astype(x0.dtype)
    eta = jnp.sum(w[:, None] * mv(Ii, jax.vmap(_minus, (0, None))(xs, x0)), axis=0)
    if shared_prior:
        Lam = I0 + jnp.sum(w[:, None, None] * (Ii - I0), axis=0)
    else:
        Lam = jnp.where(jnp.any(use), jnp.sum(w[:, None, None] * Ii, axis=0), I0)
    P = sym(inv3(sym(Lam)))
    x = x0 + P @ eta
    return x.at[2].set(wrap_angle(x[2])), chol3(P)


def fused_process_update(
    process: tuple[Array, Array, Array],
    xs: Float[Array, "k 3"],
    Ls: Float[Array, "k 3 3"],
    use: Bool[Array, " k"],
    x0: Float[Array, "3"],
    S0: Float[Array, "3 3"],
    forgetting: Float[Array, ""],
    floor: Float[Array, ""],
) -> tuple[Array, Array, Array]:
    """The adaptive process noise after a scan whose fused joint states corrected the pose:
    :func:`~._srukf.adaptive_process_update` with their mean ``dx dx' + P_i - P-``.

    Args:
        process: the estimate ``(scale, count, basis)``: ``Lambda``, the updates it has seen and the
            map ``Lambda -> Q_pose`` since the last.
        xs, Ls: the fused joint states' poses (means, lower square roots).
        use: which of them were fused (none: the estimate is returned unchanged).
        x0, S0: the scan's prior pose (mean, lower square root).
        forgetting, floor: ``nasrukf.process_forgetting`` and ``process_floor``.

    Returns:
        The new ``(scale, count, basis)``; after an update the basis starts again from zero.
    """
    scale, count, basis = process
    P0 = mmt(S0, S0)
    dx = jax.vmap(_minus, (0, None))(xs, x0)
    w = use.astype(x0.dtype)
    change = jnp.sum(w[:, None, None] * (dx[:, :, None] * dx[:, None, :] + mmt(Ls, Ls) - P0), axis=0)
    change = change / jnp.maximum(jnp.sum(w), 1.0)
    updated = jnp.any(use)
    new_scale = adaptive_process_update(scale, count, change, S0, basis, forgetting, floor)
    return (
        jnp.where(updated, new_scale, scale),
        count + updated.astype(count.dtype),
        jnp.where(updated, jnp.zeros_like(basis), basis),
    )
