"""Measurement models: what a sensor reports about a landmark seen from a planar pose.

A measurement model is an :class:`equinox.Module` deriving from
:class:`AbstractMeasurementModel`. Its array fields are its traced parameters (noise levels, the
sensor's footprint), so the model object is part of the pytree the compiled filter receives:
changing a value reuses the compiled program, changing the model's class compiles a new one. The
filter needs only

- :meth:`~AbstractMeasurementModel.h`: the predicted detection ``z = h(x, m, aux)`` of landmark
  ``m`` from pose ``x = (px, py, phi)``; ``aux`` is the detection's auxiliary input (e.g. the
  beam angle of a single range reading), ``None`` for a model without one;
- :meth:`~AbstractMeasurementModel.landmark_from`: its inverse, the landmark a detection ``z``
  made from pose ``x`` starts;
- :meth:`~AbstractMeasurementModel.noise_cov`: the measurement noise covariance ``R``;
- :meth:`~AbstractMeasurementModel.innovation`: ``z - z_hat`` with the angular components
  (:attr:`~AbstractMeasurementModel.angles`) wrapped;
- :meth:`~AbstractMeasurementModel.visible`: whether the sensor would detect a landmark from a
  pose (landmark management counts a miss for a visible landmark that is not detected).

Jacobians come from autodiff of :meth:`~AbstractMeasurementModel.h` and
:meth:`~AbstractMeasurementModel.landmark_from` (:meth:`~AbstractMeasurementModel.jacobians`,
:meth:`~AbstractMeasurementModel.inverse_jacobians`). The built-in :class:`RangeBearing` (range and
bearing to a point) also has hand-specialised paths in the filter, chosen by its type
(:func:`is_range_bearing`); any other model takes the generic path.
"""

from __future__ import annotations

import abc
import math
from typing import Any, ClassVar, TypeGuard

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float

from nanoslam_jax.models._settings import SensorDefaults
from nanoslam_jax.lib._angles import wrap_angle
from nanoslam_jax.models._motion import _f
from nanoslam_jax.models._range_bearing import (
    innovation as _rb_innovation,
)
from nanoslam_jax.models._range_bearing import (
    inverse_range_bearing,
    inverse_range_bearing_jacobians,
    range_bearing,
    range_bearing_jacobians,
)

__all__ = [
    "AbstractMeasurementModel",
    "RangeBearing",
    "is_range_bearing",
]


class AbstractMeasurementModel(eqx.Module):
    """A measurement model with its traced parameters.

    Class attributes a model sets:
        landmark_dim: length of a landmark's state ``m`` (the filter's local window searches
            the landmarks by :meth:`window_distance2`; by default its first two components are its
            position in the plane).
        measurement_dim: length of a detection ``z``.
        aux_dim: length of a detection's auxiliary input (0: none; ``aux`` is then None).
        angles: indices of the components of ``z`` that are angles (wrapped to (-pi, pi] in
            :meth:`innovation`).
    """

    landmark_dim: ClassVar[int] = 2
    measurement_dim: ClassVar[int] = 2
    aux_dim: ClassVar[int] = 0
    angles: ClassVar[tuple[int, ...]] = ()

    @abc.abstractmethod
    def h(
        self, x: Float[Array, "3"], m: Float[Array, " l"], aux: Float[Array, " a"] | None = None
    ) -> Float[Array, " d"]:
        """The predicted detection of a landmark.

        Args:
            x: the sensor's pose ``(px, py, phi)``.
            m: the landmark (``landmark_dim`` values).
            aux: the detection's auxiliary input (``aux_dim`` values), None when ``aux_dim`` is 0.

        Returns:
            ``z_hat`` (``measurement_dim`` values; angular components wrapped).
        """

    @abc.abstractmethod
    def landmark_from(
        self, x: Float[Array, "3"], z: Float[Array, " d"], aux: Float[Array, " a"] | None = None
    ) -> Float[Array, " l"]:
        """The landmark a detection starts: the inverse of :meth:`h` in ``m``.

        Args:
            x: the sensor's pose.
            z: the detection.
            aux: its auxiliary input (None when ``aux_dim`` is 0).
        """

    @abc.abstractmethod
    def noise_cov(self) -> Float[Array, "d d"]:
        """The measurement noise covariance ``R`` (``measurement_dim`` square)."""

    @abc.abstractmethod
    def visible(self, x: Float[Array, "3"], m: Float[Array, " l"]) -> Bool[Array, ""]:
        """Whether the sensor at pose ``x`` would detect landmark ``m`` (inside its field of view
        and range, shrunk by any margin): a landmark that is visible and not detected counts a miss
        in landmark management."""

    def window_distance2(self, position: Float[Array, "2"], m: Float[Array, "n l"]) -> Float[Array, " n"]:
        """Squared distance from a position to each landmark, by which the filter's local window
        picks the landmarks near a particle (those within the sensor's range plus a margin).

        The default is the Euclidean distance to the landmark's first two components (its position
        in the plane); a landmark with an extent overrides it (a line: its perpendicular distance).

        Args:
            position: the particle's position ``(px, py)``.
            m: ``(n, landmark_dim)`` landmarks.
        """
        # Components written out: a reduction over a trailing axis of 2 is much slower on XLA:CPU.
        return jnp.square(m[:, 0] - position[0]) + jnp.square(m[:, 1] - position[1])

    @property
    def R(self) -> Float[Array, "d d"]:
        """:meth:`noise_cov`."""
        return self.noise_cov()

    def innovation(self, z: Float[Array, " d"], z_hat: Float[Array, " d"]) -> Float[Array, " d"]:
        """``z - z_hat`` with the components in :attr:`angles` wrapped to (-pi, pi]."""
        d = jnp.asarray(z) - jnp.asarray(z_hat)
        for i in self.angles:
            d = d.at[i].set(wrap_angle(d[i]))
        return d

    def jacobians(
        self, x: Float[Array, "3"], m: Float[Array, " l"], aux: Float[Array, " a"] | None = None
    ) -> tuple[Float[Array, "d 3"], Float[Array, "d l"]]:
        """Jacobians ``(Gx, Gm)`` of :meth:`h` with respect to the pose and the landmark (autodiff)."""
        return jax.jacfwd(lambda x_, m_: self.h(x_, m_, aux), argnums=(0, 1))(jnp.asarray(x), jnp.asarray(m))

    def inverse_jacobians(
        self, x: Float[Array, "3"], z: Float[Array, " d"], aux: Float[Array, " a"] | None = None
    ) -> tuple[Float[Array, "l 3"], Float[Array, "l d"]]:
        """Jacobians of :meth:`landmark_from` with respect to the pose and the detection (autodiff)."""
        return jax.jacfwd(lambda x_, z_: self.landmark_from(x_, z_, aux), argnums=(0, 1))(
            jnp.asarray(x), jnp.asarray(z)
        )


# The configuration's defaults are the one source of the built-in model's defaults:
# ``RangeBearing()`` is the configuration's default sensor (the ``noise``, ``data`` and ``map`` sections take these).
_NOISE = _DATA = _MAP = SensorDefaults()


class RangeBearing(AbstractMeasurementModel):
    """Range and bearing to a point landmark ``m = (mx, my)``: ``z = (|m - p|, atan2(m - p) - phi)``,
    the bearing relative to the sensor's forward axis and wrapped.

    The sensor detects a point at ranges in ``(min_range, max_range)`` and bearings within
    ``half_fov``; :meth:`visible` shrinks that footprint by ``view_margin`` (range) and
    ``view_margin_angle`` (bearing), so that a landmark near the edge counts no miss. The defaults
    are the configuration's (``noise``, ``data`` and ``map`` sections): Victoria Park's laser.

    Attributes:
        sigma_r: range noise (m).
        sigma_beta: bearing noise (rad).
        min_range: the sensor's minimum range (m).
        max_range: the sensor's range (m).
        half_fov: half the field of view (rad).
        view_margin: range margin of :meth:`visible` (m).
        view_margin_angle: bearing margin of :meth:`visible` (rad).
    """

    angles: ClassVar[tuple[int, ...]] = (1,)

    sigma_r: Float[Array, ""] = eqx.field(default=_NOISE.sigma_r, converter=_f)
    sigma_beta: Float[Array, ""] = eqx.field(default=math.radians(_NOISE.sigma_beta_deg), converter=_f)
    min_range: Float[Array, ""] = eqx.field(default=_DATA.min_range, converter=_f)
    max_range: Float[Array, ""] = eqx.field(default=_DATA.max_range, converter=_f)
    half_fov: Float[Array, ""] = eqx.field(default=math.radians(_MAP.fov_deg) / 2, converter=_f)
    view_margin: Float[Array, ""] = eqx.field(default=_MAP.view_margin, converter=_f)
    view_margin_angle: Float[Array, ""] = eqx.field(default=math.radians(_MAP.view_margin_deg), converter=_f)

    def h(self, x, m, aux=None):
        return range_bearing(x, m)

    def landmark_from(self, x, z, aux=None):
        return inverse_range_bearing(x, z)

    def noise_cov(self):
        return jnp.diag(jnp.stack([jnp.square(self.sigma_r), jnp.square(self.sigma_beta)]))

    def innovation(self, z, z_hat):
        return _rb_innovation(z, z_hat)

    def jacobians(self, x, m, aux=None):
        return range_bearing_jacobians(x, m)

    def inverse_jacobians(self, x, z, aux=None):
        return inverse_range_bearing_jacobians(x, z)

    def in_view(self, r: Float[ArrayLike, "*n"], b: Float[ArrayLike, "*n"]) -> Bool[Array, "*n"]:
        """:meth:`visible` of landmarks predicted at range ``r`` and bearing ``b``."""
        r, b = jnp.asarray(r), jnp.asarray(b)
        return (
            (r > self.min_range + self.view_margin)
            & (r < self.max_range - self.view_margin)
            & (jnp.abs(b) < self.half_fov - self.view_margin_angle)
        )

    def visible(self, x, m):
        z = range_bearing(x, m)
        return self.in_view(z[0], z[1])


def is_range_bearing(model: Any) -> TypeGuard[RangeBearing]:
    """Whether the filter's hand-specialised range-bearing paths apply to ``model`` (a
    :class:`RangeBearing`, subclasses included); any other model takes the generic (autodiff) path."""
    return isinstance(model, RangeBearing)
