"""Several landmark types in one map: a composite measurement model.

A :class:`Composite` holds one measurement model per landmark type (e.g. a wall's line and a
pillar's circle). A landmark of the map and a detection each carry their type, an integer ``kind``
(the index of their model in :attr:`Composite.types`), and hold ``L`` values, ``L`` the largest
``landmark_dim`` of the types (every type's ``landmark_dim`` equals its ``measurement_dim``, so a
detection holds ``L`` values too). A type with fewer values uses the leading ones; the rest are
padding:

- a detection's padding is 0, and so is the padding of its prediction: the innovation has zeros
  there and its Jacobians zero rows and columns, so the padding takes no part in an update;
- the noise covariance of a detection of that type (:meth:`OfKind.noise_cov`) is the type's own
  with :data:`PAD_VARIANCE` on the padding's diagonal, the variance at which a Gaussian's density
  at its mean is 1: the padding adds nothing to a detection's log-likelihood;
- a new landmark's padding is its detection's (0) with variance :data:`PAD_VARIANCE` and no
  correlation: it stays as it started.

The filter evaluates a composite through :meth:`Composite.of_kind`: an :class:`OfKind` is a
measurement model of the type its ``kind`` names (a traced integer, or an array of them for a
batch of rows), which evaluates every type's model and selects the result of its own (masked
evaluation: fixed shapes, no branch). Data association compares a detection only with the
landmarks of its type.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from nanoslam_jax.models._measurement import AbstractMeasurementModel, RangeBearing

__all__ = [
    "Composite",
    "OfKind",
    "PAD_VARIANCE",
    "is_composite",
    "composite_names",
    "row_models",
    "row_noise",
    "check_measurement_model",
]

#: Noise variance of a padded component: ``N(0; 0, 1 / (2 pi)) = 1``, so a padded component adds
#: nothing to a detection's log-likelihood.
PAD_VARIANCE = 1.0 / (2.0 * math.pi)


def _pad(v: Array, n: int) -> Array:
    """``v`` (trailing axis) padded with zeros to ``n`` values."""
    extra = n - v.shape[-1]
    if extra == 0:
        return v
    return jnp.concatenate([v, jnp.zeros(v.shape[:-1] + (extra,), v.dtype)], axis=-1)


class Composite(AbstractMeasurementModel):
    """Several landmark types in one map (see the module docstring).

    Attributes:
        types: one measurement model per landmark type; a landmark's or detection's ``kind`` is
            the index of its type's model. Each has ``landmark_dim == measurement_dim`` and no
            auxiliary input.
        names: the types' names (for messages and outputs).
    """

    angles: ClassVar[tuple[int, ...]] = ()

    types: tuple[AbstractMeasurementModel, ...]
    names: tuple[str, ...] = eqx.field(static=True, default=())

    def __check_init__(self):
        if not self.types:
            raise ValueError("key 'model.measurement': a composite needs at least one landmark type")
        for t in self.types:
            if t.landmark_dim != t.measurement_dim or t.aux_dim != 0 or isinstance(t, Composite):
                raise ValueError(
                    f"key 'model.measurement': a composite's type {type(t).__name__} must have landmark_dim == "
                    f"measurement_dim (got {t.landmark_dim} and {t.measurement_dim}), no auxiliary input and "
                    "not be a composite itself"
                )

    @property
    def landmark_dim(self) -> int:  # type: ignore[override]  # the instance's, from its types
        """The largest ``landmark_dim`` of the types."""
        return max(t.landmark_dim for t in self.types)

    @property
    def measurement_dim(self) -> int:  # type: ignore[override]
        """The largest ``measurement_dim`` of the types (equal to :attr:`landmark_dim`)."""
        return max(t.measurement_dim for t in self.types)

    def of_kind(self, kind: Int[Array, "*n"] | int) -> "OfKind":
        """The measurement model of the type ``kind`` (an integer array: one per row of a batch)."""
        return OfKind(self, jnp.asarray(kind, jnp.int32))

    def _whole(self, what: str):
        raise TypeError(f"Composite.{what}: a composite's landmarks and detections are evaluated by of_kind(kind)")

    def h(self, x, m, aux=None):
        self._whole("h")

    def landmark_from(self, x, z, aux=None):
        self._whole("landmark_from")

    def visible(self, x, m):
        self._whole("visible")

    def noise_cov(self):
        """The first type's noise, padded (a detection's own is ``of_kind(kind).noise_cov()``)."""
        return self.of_kind(0).noise_cov()


def composite_names(measurement: str) -> list[str]:
    """The type names of a composite ``model.measurement`` (``'line+circle'``: ``['line', 'circle']``)."""
    return [n.strip() for n in measurement.split("+")]


def is_composite(model: Any) -> bool:
    """Whether ``model`` is a :class:`Composite` (its rows are evaluated through ``of_kind``)."""
    return isinstance(model, Composite)


class OfKind(AbstractMeasurementModel):
    """The type ``kind`` of a :class:`Composite`: its model on the composite's padded landmarks and
    detections (every type is evaluated and the result of ``kind``'s selected).

    Attributes:
        composite: the composite.
        kind: the type (an integer; an array for a batch of rows, whose leading axes the
            landmarks of :meth:`window_distance2` share).
    """

    composite: Composite
    kind: Int[Array, "*n"]

    @property
    def landmark_dim(self) -> int:  # type: ignore[override]
        return self.composite.landmark_dim

    @property
    def measurement_dim(self) -> int:  # type: ignore[override]
        return self.composite.measurement_dim

    def _select(self, values: list[Array], trailing: int) -> Array:
        """``values[kind]``: each type's result (same shape), selected element-wise by ``kind``,
        which is broadcast over the values' ``trailing`` last axes."""
        k = self.kind.reshape(self.kind.shape + (1,) * trailing)
        out = jnp.broadcast_to(values[0], jnp.broadcast_shapes(k.shape, values[0].shape))
        for t, v in enumerate(values[1:], start=1):
            out = jnp.where(k == t, v, out)
        return out

    def h(self, x, m, aux=None):
        n = self.measurement_dim
        return self._select([_pad(t.h(x, m[: t.landmark_dim]), n) for t in self.composite.types], 1)

    def landmark_from(self, x, z, aux=None):
        return self._select(
            [
                jnp.concatenate([t.landmark_from(x, z[: t.measurement_dim]), z[t.landmark_dim :]])
                for t in self.composite.types
            ],
            1,
        )

    def noise_cov(self):
        n = self.measurement_dim
        covs = []
        for t in self.composite.types:
            d = t.measurement_dim
            R = jnp.zeros((n, n)).at[:d, :d].set(t.noise_cov())
            covs.append(R.at[jnp.arange(d, n), jnp.arange(d, n)].set(PAD_VARIANCE))
        return self._select(covs, 2)

    def innovation(self, z, z_hat):
        n = self.measurement_dim
        return self._select(
            [_pad(t.innovation(z[: t.measurement_dim], z_hat[: t.measurement_dim]), n) for t in self.composite.types],
            1,
        )

    def visible(self, x, m):
        return self._select([jnp.asarray(t.visible(x, m[: t.landmark_dim])) for t in self.composite.types], 0)

    def window_distance2(self, position, m):
        return self._select([t.window_distance2(position, m[:, : t.landmark_dim]) for t in self.composite.types], 0)


def row_models(model: AbstractMeasurementModel, kind: Int[Array, " n"] | None) -> tuple[AbstractMeasurementModel, Any]:
    """The model of each of ``n`` rows (landmarks or detections) and its ``vmap`` axes: for a
    :class:`Composite` with the rows' ``kind``, ``model.of_kind(kind)`` mapped over its ``kind``;
    else ``(model, None)`` (one model shared by the rows)."""
    if kind is not None and isinstance(model, Composite):
        rows = model.of_kind(kind)
        leaves, tree = jax.tree.flatten(rows)  # the kind is the last leaf: vmap over it alone
        return rows, jax.tree.unflatten(tree, [None] * (len(leaves) - 1) + [0])
    return model, None


def row_noise(
    model: AbstractMeasurementModel, axis: Any, R: Float[Array, "d d"]
) -> tuple[Float[Array, "*n d d"], int | None]:
    """The rows' noise covariances and their ``vmap`` axis: ``R`` shared (``axis`` None), or each
    row's own (the ``OfKind`` rows of :func:`row_models`)."""
    return (model.noise_cov(), 0) if axis is not None else (R, None)


def check_measurement_model(
    model: type[AbstractMeasurementModel] | AbstractMeasurementModel, method: str, smoother: bool = False
) -> None:
    """Raise a ValueError naming ``model.measurement`` when the filter cannot run ``model``.

    The filter's maps hold landmarks of the model's ``landmark_dim``; a detection has
    ``measurement_dim`` values, as many (a new landmark is started through the inverse model,
    whose Jacobian must be square); detections carry no auxiliary input yet (``aux_dim == 0``);
    NASRUKF (``filter.method: nasrukf``) and the smoother run range-bearing models only.
    """
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
