"""Models from a configuration: the names ``model.motion`` and ``model.measurement`` take (a
built-in name or an import path ``module:Class``), and each model built with its parameters from
the configuration's sections.

A built-in model reads its own sections (``vehicle`` and ``noise`` for the Victoria Park car,
``unicycle``, ``odometry``, ``random_walk``; ``noise``, ``data`` and ``map`` for range-bearing). A model named
by import path is built from ``model.motion_params`` / ``model.measurement_params`` (a mapping of
its fields to numbers), unless its class defines a classmethod ``from_config(cfg)``, which is then
called with the whole configuration. Adding a built-in model is its module in
:mod:`nanoslam_jax.models` and one line in :data:`MOTION_MODELS` or :data:`MEASUREMENT_MODELS`
(with a reader below if it has a section of its own).
"""

from __future__ import annotations

import dataclasses
import importlib
import math
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any, Optional

import numpy as np

from nanoslam_jax.models import (
    AbstractMeasurementModel,
    AbstractMotionModel,
    Ackermann,
    Circle,
    Composite,
    LineSegment,
    Odometry,
    RandomWalk,
    RangeBearing,
    Unicycle,
)
from nanoslam_jax.models._composite import composite_names

if TYPE_CHECKING:
    from nanoslam_jax.app.config import Config

__all__ = [
    "MEASUREMENT_MODELS",
    "MOTION_MODELS",
    "has_own_section",
    "measurement_model_class",
    "measurement_model_from_config",
    "motion_model_class",
    "motion_model_from_config",
]

#: The built-in motion models by their config name (``model.motion``).
MOTION_MODELS: dict[str, type[AbstractMotionModel]] = {
    "ackermann": Ackermann,
    "unicycle": Unicycle,
    "odometry": Odometry,
    "random_walk": RandomWalk,
}

#: The built-in measurement models by their config name (``model.measurement``).
MEASUREMENT_MODELS: dict[str, type[AbstractMeasurementModel]] = {
    "range_bearing": RangeBearing,
    "line": LineSegment,
    "circle": Circle,
}


def _import_object(path: str, key: str) -> Any:
    """``module:attr`` imported (``attr`` may be dotted)."""
    module, _, attr = path.partition(":")
    try:
        obj = importlib.import_module(module)
    except ImportError as e:
        raise ValueError(f"key '{key}': cannot import module {module!r} of {path!r}: {e}") from None
    for part in attr.split("."):
        if not hasattr(obj, part):
            raise ValueError(f"key '{key}': module {module!r} has no attribute {attr!r}")
        obj = getattr(obj, part)
    return obj


def _model_class(name: str, key: str, what: str, builtins: Mapping[str, type], base: type) -> type:
    """A model class by config name: one of ``builtins`` or an import path ``module:Class`` of a
    subclass of ``base``; a ValueError names ``key`` otherwise."""
    if name in builtins:
        return builtins[name]
    if ":" not in name:
        raise ValueError(
            f"key '{key}': {name!r} is not a built-in {what} ({', '.join(builtins)}) nor an import path 'module:Class'"
        )
    cls = _import_object(name, key)
    if not (isinstance(cls, type) and issubclass(cls, base)):
        raise ValueError(f"key '{key}': {name!r} is not a subclass of nanoslam_jax.models.{base.__name__}")
    return cls


def motion_model_class(name: str) -> type[AbstractMotionModel]:
    """The motion model class for ``model.motion``: a built-in name or an import path
    ``package.module:ClassName`` of a subclass of :class:`~nanoslam_jax.models.AbstractMotionModel`.

    Raises:
        ValueError: naming the key, when the name is unknown, cannot be imported or is not a
            motion model class.
    """
    return _model_class(name, "model.motion", "motion model", MOTION_MODELS, AbstractMotionModel)


def measurement_model_class(name: str) -> type[AbstractMeasurementModel]:
    """The measurement model class for ``model.measurement``: a built-in name or an import path
    ``package.module:ClassName`` of a subclass of
    :class:`~nanoslam_jax.models.AbstractMeasurementModel`; several of them joined by ``+``
    (``line+circle``): :class:`~nanoslam_jax.models.Composite`, a map of several landmark types.

    Raises:
        ValueError: naming the key, when the name is unknown, cannot be imported or is not a
            measurement model class.
    """
    if "+" in name:
        for part in composite_names(name):
            measurement_model_class(part)
        return Composite
    return _model_class(name, "model.measurement", "measurement model", MEASUREMENT_MODELS, AbstractMeasurementModel)


def _f(x: Any) -> np.ndarray:
    return np.asarray(x, dtype=np.float64)


def _from_params(cls: type, params: Optional[Mapping[str, Any]], key: str) -> Any:
    """``cls`` built from a mapping of its field names to numbers (``key`` names it in errors)."""
    params = dict(params or {})
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(params) - names)
    if unknown:
        raise ValueError(
            f"key '{key}': {cls.__name__} has no parameter {', '.join(map(repr, unknown))}; it takes "
            f"{', '.join(sorted(names)) or 'none'}"
        )
    try:
        return cls(**{k: _f(v) for k, v in params.items()})
    except TypeError as e:
        raise ValueError(f"key '{key}': cannot build {cls.__name__}: {e}") from None


def _ackermann(cls: type, cfg: "Config") -> Any:
    v, nz = cfg.vehicle, cfg.noise
    return cls(v.wheelbase, v.encoder_offset, v.laser_a, v.laser_b, nz.sigma_v, math.radians(nz.sigma_alpha_deg))


def _unicycle(cls: type, cfg: "Config") -> Any:
    u = cfg.unicycle
    return cls(u.sensor_x, u.sensor_y, u.sigma_v, math.radians(u.sigma_omega_deg))


def _odometry(cls: type, cfg: "Config") -> Any:
    o = cfg.odometry
    return cls(
        o.alpha1,
        o.alpha2,
        o.alpha3,
        o.alpha4,
        o.floor_xy,
        math.radians(o.floor_phi_deg),
        o.min_translation,
        o.sensor_x,
        o.sensor_y,
    )


def _random_walk(cls: type, cfg: "Config") -> Any:
    r = cfg.random_walk
    return cls(r.sigma_xy, math.radians(r.sigma_phi_deg))


def _range_bearing(cls: type, cfg: "Config") -> Any:
    nz, d, mp = cfg.noise, cfg.data, cfg.map
    return cls(
        nz.sigma_r,
        math.radians(nz.sigma_beta_deg),
        d.min_range,
        d.max_range,
        math.radians(mp.fov_deg) / 2,
        mp.view_margin,
        math.radians(mp.view_margin_deg),
    )


def _composite(cls: type, cfg: "Config") -> Any:
    """The types of ``model.measurement`` (built-in names or import paths joined by ``+``, e.g.
    ``line+circle``), each with its parameters from ``model.measurement_params.<name>``."""
    names = composite_names(cfg.model.measurement)
    params = dict(cfg.model.measurement_params or {})
    unknown = sorted(set(params) - set(names))
    if unknown:
        raise ValueError(
            f"key 'model.measurement_params': a composite takes one mapping per type ({', '.join(names)}), "
            f"got {', '.join(map(repr, unknown))}"
        )
    types = []
    for name in names:
        sub = params.get(name) or {}
        if not isinstance(sub, dict):
            raise ValueError(f"key 'model.measurement_params.{name}': expected a mapping, got {sub!r}")
        model = dataclasses.replace(cfg.model, measurement=name, measurement_params=sub or None)
        try:
            types.append(_measurement_of(measurement_model_class(name), dataclasses.replace(cfg, model=model)))
        except ValueError as e:  # name the type's own mapping
            raise ValueError(
                str(e).replace("'model.measurement_params'", f"'model.measurement_params.{name}'")
            ) from None
    return cls(tuple(types), tuple(names))


#: The readers of the built-in models' own sections, by class (a subclass inherits its base's).
_SECTION_READERS: dict[type, Callable[[type, "Config"], Any]] = {
    Ackermann: _ackermann,
    Unicycle: _unicycle,
    Odometry: _odometry,
    RandomWalk: _random_walk,
    RangeBearing: _range_bearing,
    Composite: _composite,
}


def _reader(cls: type) -> Optional[Callable[[type, "Config"], Any]]:
    return next((_SECTION_READERS[b] for b in cls.__mro__ if b in _SECTION_READERS), None)


def has_own_section(cls: type) -> bool:
    """Whether ``cls`` reads its parameters from sections of its own (a built-in model, or one
    with a ``from_config`` classmethod) rather than from ``model.motion_params`` /
    ``model.measurement_params``."""
    return _reader(cls) is not None or callable(getattr(cls, "from_config", None))


def _build(cls: type, cfg: "Config", params: Optional[Mapping[str, Any]], key: str) -> Any:
    read = _reader(cls)
    if read is not None:
        return read(cls, cfg)
    own = getattr(cls, "from_config", None)
    if callable(own):
        return own(cfg)
    return _from_params(cls, params, key)


def _measurement_of(cls: type, cfg: "Config") -> AbstractMeasurementModel:
    return _build(cls, cfg, cfg.model.measurement_params, "model.measurement_params")


def motion_model_of(cls: type, cfg: "Config") -> AbstractMotionModel:
    """A motion model of class ``cls`` with its parameters from the configuration."""
    return _build(cls, cfg, cfg.model.motion_params, "model.motion_params")


def motion_model_from_config(cfg: "Config") -> AbstractMotionModel:
    """The motion model named by ``model.motion`` with its parameters from the configuration."""
    return motion_model_of(motion_model_class(cfg.model.motion), cfg)


def measurement_model_from_config(cfg: "Config") -> AbstractMeasurementModel:
    """The measurement model named by ``model.measurement`` with its parameters from the configuration."""
    return _measurement_of(measurement_model_class(cfg.model.measurement), cfg)


def measurement_model_of(cls: type, cfg: "Config") -> AbstractMeasurementModel:
    """A measurement model of class ``cls`` with its parameters from the configuration."""
    return _measurement_of(cls, cfg)
