"""The proposal interface shared by all particle methods."""

from __future__ import annotations

import abc
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from nanoslam_jax.lib._linalg import inv_small, sandwich
from nanoslam_jax.models import AbstractMeasurementModel, RangeBearing, row_models, row_noise, wrap_angle


class Detections(NamedTuple):
    """The detections of one scan that are associated with existing landmarks.

    Attributes:
        z: detections (``(range, bearing)`` for range-bearing).
        mean: the associated landmark means.
        cov: the associated landmark covariances.
        mask: which rows are real associations.
        kind: each row's type (a :class:`~nanoslam_jax.models.Composite` measurement model), or
            None (one type).
    """

    z: Float[Array, "k d"]
    mean: Float[Array, "k l"]
    cov: Float[Array, "k l l"]
    mask: Bool[Array, " k"]
    kind: Int[Array, " k"] | None = None


class ProposalResult(NamedTuple):
    """A Gaussian proposal over the pose and how it was obtained.

    Attributes:
        mean: proposal mean.
        cov: proposal covariance.
        iterations: iterations taken by an iterative proposal (0 otherwise).
        result: 0 converged, 1 iteration cap reached, 2 non-finite values (fell back to the prior).
    """

    mean: Float[Array, "3"]
    cov: Float[Array, "3 3"]
    iterations: Int[Array, ""]
    result: Int[Array, ""]


RESULT_CODES = ("successful", "max_steps_reached", "nonfinite")


class AbstractProposal(eqx.Module):
    """A method's proposal: a Gaussian over the pose given the prior and associated detections.

    A proposal that evaluates the detections holds the measurement model it was built with (the
    built-in ones: a ``measurement`` field, set from ``params.measurement`` by their methods'
    registrations).
    """

    @abc.abstractmethod
    def __call__(
        self, x0: Float[Array, "3"], P0: Float[Array, "3 3"], det: Detections, R: Float[Array, "d d"]
    ) -> ProposalResult:
        """Args: the prior mean ``x0`` and covariance ``P0``, the associated detections, the noise ``R``."""


def pose_difference(a: Float[Array, "3"], b: Float[Array, "3"]) -> Float[Array, "3"]:
    """``a - b`` with the heading difference wrapped."""
    d = a - b
    return d.at[2].set(wrap_angle(d[2]))


def wrap_pose(x: Float[Array, "3"]) -> Float[Array, "3"]:
    """Pose with its heading wrapped to (-pi, pi]."""
    return x.at[2].set(wrap_angle(x[2]))


def measurement_residuals(det: Detections, model: AbstractMeasurementModel | None = None):
    """``x -> z_k - g(x, m_k)`` (angular components wrapped) for all rows of ``det``, ``g`` the
    measurement model (default range-bearing)."""
    rows, ax = row_models(RangeBearing() if model is None else model, det.kind)

    def residual(x):
        z_hat = jax.vmap(lambda md, m: md.h(x, m), (ax, 0))(rows, det.mean)
        return jax.vmap(lambda md, z, zh: md.innovation(z, zh), (ax, 0, 0))(rows, det.z, z_hat)

    return residual


#: :func:`measurement_residuals` of the range-bearing model.
range_bearing_residuals = measurement_residuals


def noise_information(
    x0: Float[Array, "3"],
    det: Detections,
    R: Float[Array, "d d"],
    landmark_noise: bool,
    model: AbstractMeasurementModel | None = None,
) -> Float[Array, "k d d"]:
    """Inverse noise of each detection: ``R^-1``, or ``(R + Gm Sigma Gm')^-1`` at the prior mean
    (``Gm`` of the measurement model, default range-bearing)."""
    rows, ax = row_models(RangeBearing() if model is None else model, det.kind)
    R, _ = row_noise(rows, ax, R)
    if not landmark_noise:
        return jnp.broadcast_to(inv_small(R), det.z.shape[:1] + R.shape[-2:])
    _, Gm = jax.vmap(lambda md, m: md.jacobians(x0, m), (ax, 0))(rows, det.mean)
    return inv_small(sandwich(Gm, det.cov) + R)
