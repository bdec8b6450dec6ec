"""UFastSLAM (Kim, Sakthivel & Chung 2008): the proposal by sequential unscented updates.

The prior (unscented transform over the pose augmented with control noise) is shared by all
methods (``filter/_prior.py``). What is specific to UFastSLAM is here: the proposal processes
the scan's associated detections one after another, each by an unscented Kalman update of the
pose over the augmented state ``[pose (3); landmark (l)]`` with block-diagonal covariance
``diag(P, Sigma_k)``, so the landmark's uncertainty enters through the sigma points rather
than through a Jacobian (``S = Pzz + R``). The landmark updates (``filter/_landmarks.py``,
:func:`~nanoslam_jax.methods.maps._landmarks.ukf_update_loglik`) are unscented too.
"""

from __future__ import annotations

from typing import Protocol

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float

from nanoslam_jax.lib._linalg import chol3, chol_small, det2, det3, inv_small, mm, mmt, mv, sym
from nanoslam_jax.models import AbstractMeasurementModel, RangeBearing, wrap_angle
from nanoslam_jax.lib.quadrature import Unscented, sigma_point_cross_cov, sigma_point_stats
from nanoslam_jax.methods.proposals._base import AbstractProposal, Detections, ProposalResult

__all__ = ["UnscentedProposal", "unscented_sequential_update", "unscented_measurement_update"]


def _indices(index: int | tuple[int, ...] | None) -> tuple[int, ...]:
    """A static index, tuple of indices or None as a tuple."""
    if index is None:
        return ()
    return (index,) if isinstance(index, int) else tuple(index)


def _is_pd3(P: Float[Array, "3 3"]) -> Bool[Array, ""]:
    """Sylvester's criterion: all leading principal minors of a symmetric 3x3 matrix positive."""
    return (P[0, 0] > 0) & (det2(P[:2, :2]) > 0) & (det3(P) > 0)


def _block_chol(P: Float[Array, "3 3"], Sigma: Float[Array, "l l"]) -> Float[Array, "n n"]:
    """Lower Cholesky factor of ``diag(P, Sigma)``, ``n = 3 + l`` (block-diagonal, closed-form factors)."""
    n = 3 + Sigma.shape[-1]
    L = jnp.zeros((n, n), P.dtype)
    return L.at[:3, :3].set(chol3(sym(P))).at[3:, 3:].set(chol_small(sym(Sigma)))


class _HasAngles(Protocol):
    """What the unscented updates need of a measurement model: ``h`` and its angle components."""

    angles: tuple[int, ...]

    def h(self, x: Float[Array, "3"], m: Float[Array, " l"]) -> Float[Array, " d"]: ...


def unscented_measurement_update(
    x: Float[Array, "3"],
    P: Float[Array, "3 3"],
    model: AbstractMeasurementModel | _HasAngles,
    z: Float[Array, " d"],
    landmark: tuple[Float[Array, " l"], Float[Array, "l l"]],
    R: Float[Array, "d d"],
    rule: Unscented,
    *,
    x_angle_index: int | None = 2,
) -> tuple[Float[Array, "3"], Float[Array, "3 3"], Float[Array, " d"], Float[Array, "d d"]]:
    """One unscented Kalman update of the pose with one detection of an uncertain landmark.

    Sigma points of the rule are drawn over the augmented state ``[x; m] ~ N([x; m_mean],
    diag(P, m_cov))`` and passed through ``h``. The predicted measurement is the weighted mean
    of the predictions relative to the centre point's (the angle component's deviations wrapped,
    i.e. a circular mean about the centre), ``S = Pzz + R``, ``Pxz`` the pose/measurement
    cross-covariance, ``K = Pxz S^-1``, ``x <- x + K nu`` (``nu`` wrapped), ``P <- P - K S K'``.

    Args:
        x: pose mean (3,).
        P: pose covariance (3, 3).
        model: the measurement model: its ``h(pose, landmark) -> z_hat`` and ``angles``, the
            static indices of the angle components of ``z`` (wrapped). Any object with these
            two attributes serves.
        z: the detection (d,).
        landmark: the landmark's mean (l,) and covariance (l, l).
        R: measurement noise covariance (d, d).
        rule: the unscented rule (``alpha, beta, kappa``; may be traced).
        x_angle_index: static index of the angle component of ``x`` (wrapped), or None.

    Returns:
        ``(x_new, P_new, nu, S)``: the updated pose mean and covariance (symmetrised; the
        previous ``P`` is kept if the update would leave it not positive definite), the
        innovation and its covariance.
    """
    m_mean, m_cov = landmark
    centre = jnp.concatenate([x, m_mean])
    xi, wm, wc = rule.unit_points(centre.shape[-1])
    X = centre + mmt(xi, _block_chol(P, m_cov))  # (2n + 1, n): X_i = centre + L xi_i
    Z = jax.vmap(model.h)(X[:, :3], X[:, 3:])
    dZ = Z - Z[0]
    angles = _indices(model.angles)
    for i in angles:
        dZ = dZ.at[:, i].set(wrap_angle(dZ[:, i]))
    dz_mean, Pzz = sigma_point_stats(dZ, wm, wc)
    z_hat = Z[0] + dz_mean
    Pxz = sigma_point_cross_cov(X[:, :3], x, dZ, dz_mean, wc)
    S = sym(Pzz + R)
    K = mm(Pxz, inv_small(S))
    nu = z - z_hat
    for i in angles:
        nu = nu.at[i].set(wrap_angle(nu[i]))
    x_new = x + mv(K, nu)
    if x_angle_index is not None:
        x_new = x_new.at[x_angle_index].set(wrap_angle(x_new[x_angle_index]))
    P_new = sym(P - mmt(mm(K, S), K))
    P_new = jnp.where(_is_pd3(P_new), P_new, P)
    return x_new, P_new, nu, S


def unscented_sequential_update(
    x0: Float[Array, "3"],
    P0: Float[Array, "3 3"],
    model: AbstractMeasurementModel | _HasAngles,
    det: Detections,
    R: Float[Array, "d d"],
    rule: Unscented,
    *,
    x_angle_index: int | None = 2,
) -> tuple[Float[Array, "3"], Float[Array, "3 3"]]:
    """UFastSLAM's proposal: unscented updates of the pose by the detections, one after another.

    A ``lax.scan`` over the ``k`` rows applies :func:`unscented_measurement_update` to each
    real row (``det.mask``); masked rows leave the state unchanged. For a measurement function
    linear in pose and landmark this is exactly the Kalman posterior with the landmark
    covariance folded into the noise (``S = Hx P Hx' + Hm Sigma Hm' + R``).

    Args:
        x0: prior pose mean (3,).
        P0: prior pose covariance (3, 3).
        model: the measurement model (its ``h`` and ``angles``, as for
            :func:`unscented_measurement_update`).
        det: the detections ``(k, d)``, their associated landmarks' means and covariances and
            which rows are real associations.
        R: measurement noise covariance (d, d).
        rule: the unscented rule (``alpha, beta, kappa``; may be traced).
        x_angle_index: static index of the heading in the pose, or None.

    Returns:
        The proposal mean and covariance ``(x, P)``.
    """

    def body(carry, row):
        x, P = carry
        zk, mk, Sk, use = row
        xn, Pn, _, _ = unscented_measurement_update(x, P, model, zk, (mk, Sk), R, rule, x_angle_index=x_angle_index)
        return (jnp.where(use, xn, x), jnp.where(use, Pn, P)), None

    (x, P), _ = jax.lax.scan(body, (x0, P0), (det.z, det.mean, det.cov, det.mask))
    return x, P


class UnscentedProposal(AbstractProposal):
    """UFastSLAM's proposal (Kim, Sakthivel & Chung 2008) on a measurement model (range-bearing by default).

    The associated detections update the prior one after another, each by an unscented update
    over ``[pose; landmark]`` (:func:`unscented_sequential_update`). The published settings
    are ``alpha = 0.9, beta = 2, kappa = 0``.

    Attributes:
        alpha: unscented spread (traced scalar).
        beta: unscented prior-knowledge term (traced scalar).
        kappa: unscented secondary scaling (traced scalar).
        measurement: the measurement model (its ``h`` and angular components).
    """

    alpha: Float[Array, ""]
    beta: Float[Array, ""]
    kappa: Float[Array, ""]
    measurement: AbstractMeasurementModel

    def __init__(
        self,
        alpha: Float[ArrayLike, ""] = 0.9,
        beta: Float[ArrayLike, ""] = 2.0,
        kappa: Float[ArrayLike, ""] = 0.0,
        measurement: AbstractMeasurementModel | None = None,
    ):
        """Args: the unscented parameters (scalars, may be traced) and the measurement model
        (default range-bearing)."""
        self.alpha = jnp.asarray(alpha, dtype=float)
        self.beta = jnp.asarray(beta, dtype=float)
        self.kappa = jnp.asarray(kappa, dtype=float)
        self.measurement = RangeBearing() if measurement is None else measurement

    def __call__(self, x0, P0, det: Detections, R) -> ProposalResult:
        """Args: the prior mean ``x0`` and covariance ``P0``, the associated detections, the noise ``R``."""
        rule = Unscented(alpha=self.alpha, beta=self.beta, kappa=self.kappa)
        x, P = unscented_sequential_update(x0, P0, self.measurement, det, R, rule)
        ok = jnp.all(jnp.isfinite(x)) & jnp.all(jnp.isfinite(P))
        x = jnp.where(ok, x, x0)
        P = jnp.where(ok, P, P0)
        zero = jnp.zeros((), jnp.int32)
        return ProposalResult(x, P, zero, jnp.where(ok, zero, jnp.asarray(2, jnp.int32)))
