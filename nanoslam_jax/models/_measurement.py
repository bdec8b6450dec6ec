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
import dataclasses
import math
from typing import TYPE_CHECKING, Any, ClassVar, TypeGuard

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float

from nanoslam_jax.app._config_schema import DataConfig, MapConfig, NoiseConfig
from nanoslam_jax.lib._angles import wrap_angle
from nanoslam_jax.models._motion import _f, _model_class
from nanoslam_jax.models._range_bearing import (
    innovation as _rb_innovation,
)
from nanoslam_jax.models._range_bearing import (
    inverse_range_bearing,
    inverse_range_bearing_jacobians,
    range_bearing,
    range_bearing_jacobians,
)

if TYPE_CHECKING:
    from nanoslam_jax.app.config import Config

__all__ = [
    "AbstractMeasurementModel",
    "RangeBearing",
    "MEASUREMENT_MODELS",
    "is_range_bearing",
    "check_measurement_model",
    "measurement_model_class",
    "measurement_model_from_config",
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

    @classmethod
    def from_config(cls, cfg: "Config") -> "AbstractMeasurementModel":
        """The model with its parameters from a run configuration.

        The default reads ``model.measurement_params`` (a mapping of field name to value) and
        passes it to the constructor; the built-in model reads its own config sections.
        """
        params = dict(cfg.model.measurement_params or {})
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(params) - names)
        if unknown:
            raise ValueError(
                f"key 'model.measurement_params': {cls.__name__} has no parameter "
                f"{', '.join(map(repr, unknown))}; it takes {', '.join(sorted(names)) or 'none'}"
            )
        try:
            return cls(**{k: _f(v) for k, v in params.items()})
        except TypeError as e:
            raise ValueError(f"key 'model.measurement_params': cannot build {cls.__name__}: {e}") from None


# The configuration's defaults are the one source of the built-in model's defaults:
# ``RangeBearing()`` equals ``RangeBearing.from_config(Config())``.
_NOISE, _DATA, _MAP = NoiseConfig(), DataConfig(), MapConfig()


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

    @classmethod
    def from_config(cls, cfg: "Config") -> "RangeBearing":
        nz, d, mp = cfg.noise, cfg.data, cfg.map
        # The fields' converters take the floats (a converter is invisible to mypy).
        args: tuple[Any, ...] = (
            nz.sigma_r,
            math.radians(nz.sigma_beta_deg),
            d.min_range,
            d.max_range,
            math.radians(mp.fov_deg) / 2,
            mp.view_margin,
            math.radians(mp.view_margin_deg),
        )
        return cls(*args)


def is_range_bearing(model: Any) -> TypeGuard[RangeBearing]:
    """Whether the filter's hand-specialised range-bearing paths apply to ``model`` (a
    :class:`RangeBearing`, subclasses included); any other model takes the generic (autodiff) path."""
    return isinstance(model, RangeBearing)


#: The built-in measurement models by their config name (``model.measurement``).
MEASUREMENT_MODELS: dict[str, type[AbstractMeasurementModel]] = {
    "range_bearing": RangeBearing,
}


def measurement_model_class(name: str) -> type[AbstractMeasurementModel]:
    """The measurement model class for ``model.measurement``: a built-in name or an import path
    ``package.module:ClassName`` of a subclass of :class:`AbstractMeasurementModel`; several of
    them joined by ``+`` (``line+circle``): :class:`~nanoslam_jax.models.Composite`, a map of
    several landmark types.

    Raises:
        ValueError: naming the key, when the name is unknown, cannot be imported or is not a
            measurement model class.
    """
    if "+" in name:
        from nanoslam_jax.models._composite import Composite, composite_names

        for part in composite_names(name):
            measurement_model_class(part)
        return Composite
    return _model_class(name, "model.measurement", "measurement model", MEASUREMENT_MODELS, AbstractMeasurementModel)


def measurement_model_from_config(cfg: "Config") -> AbstractMeasurementModel:
    """The measurement model named by ``model.measurement`` with its parameters from the configuration."""
    return measurement_model_class(cfg.model.measurement).from_config(cfg)


def check_measurement_model(
    model: type[AbstractMeasurementModel] | AbstractMeasurementModel, method: str, smoother: bool = False
) -> None:
    """Raise a ValueError naming ``model.measurement`` when the filter cannot run ``model``.

    The filter's maps hold landmarks of the model's ``landmark_dim``; a detection has
    ``measurement_dim`` values, as many (a new landmark is started through the inverse model,
    whose Jacobian must be square); detections carry no auxiliary input yet (``aux_dim == 0``);
    NASRUKF (``filter.method: nasrukf``) and the smoother run range-bearing models only.
    """
    from nanoslam_jax.models._composite import Composite

    cls = model if isinstance(model, type) else type(model)
    name = cls.__name__
    if issubclass(cls, Composite):  # its types are checked when it is built
        if method in ("ufastslam", "nasrukf") or smoother:
            raise ValueError(
                "key 'model.measurement': a map of several landmark types runs with ekf_slam, fastslam1, "
                f"fastslam2, iterated and nano, not with {'the smoother' if smoother else method}"
            )
        return
    if cls.landmark_dim < 1 or cls.landmark_dim != cls.measurement_dim:
        raise ValueError(
            f"key 'model.measurement': {name} has landmark_dim {cls.landmark_dim} and measurement_dim "
            f"{cls.measurement_dim}; the filter starts a landmark from one detection through the inverse "
            "model and needs them equal (and at least 1)"
        )
    if cls.aux_dim != 0:
        raise ValueError(
            f"key 'model.measurement': {name} takes an auxiliary input (aux_dim {cls.aux_dim}); the "
            "log's detections carry none"
        )
    if not issubclass(cls, RangeBearing):
        if method == "nasrukf":
            raise ValueError(
                f"key 'model.measurement': filter.method nasrukf runs range-bearing models only, not {name}"
            )
        if smoother:
            raise ValueError(
                f"key 'model.measurement': the smoother (smoother.enabled) runs range-bearing models only, not {name}"
            )
