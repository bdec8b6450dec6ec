"""Core objects from a configuration: the filter's static settings and traced hyperparameters of a
run (:func:`settings_from_config`), the method's static settings (:func:`method_static`)."""

from __future__ import annotations

import dataclasses
from collections.abc import Hashable
from typing import Any

from nanoslam_jax.app.config import Config
from nanoslam_jax.app.registry import get_method, static_of, traced_of
from nanoslam_jax.methods import (
    AncestralPath,
    BestParticle,
    KnownAssociation,
    LinearisedPrior,
    MarginalWeight,
    Multinomial,
    NearestAssociation,
    ProductWeight,
    Residual,
    Stratified,
    Systematic,
    UnscentedPrior,
    WeightedMean,
)
from nanoslam_jax.methods._params import Params, Static, particle_devices, row_buckets, shardable
from nanoslam_jax.methods._settings import hyperparameters
from nanoslam_jax.app._models import measurement_model_from_config, motion_model_from_config
from nanoslam_jax.models import check_motion_model

__all__ = ["COMPONENTS", "method_static", "settings_from_config"]


def _named(*classes: Any) -> dict[str, Any]:
    return {c.name: c for c in classes}


#: The built-in components of the filter's static settings by the ``filter`` key that names them:
#: ``{key: {name: class}}``.
COMPONENTS: dict[str, dict[str, Any]] = {
    "prior": _named(UnscentedPrior, LinearisedPrior),
    "association": _named(NearestAssociation, KnownAssociation),
    "weight": _named(ProductWeight, MarginalWeight),
    "resampler": _named(Systematic, Stratified, Multinomial, Residual),
    "estimate": _named(BestParticle, WeightedMean, AncestralPath),
}


def method_static(cfg: Config) -> Hashable:
    """The static settings of ``cfg``'s method (``Static.method_settings``), built by its
    registration from ``cfg`` without any JAX computation."""
    return static_of(get_method(cfg.filter.method), cfg)


def settings_from_config(cfg: Config, k_max: int, segments: int = 0) -> tuple[Static, Params]:
    """Split a :class:`Config` into the static settings and the traced hyperparameters.

    Args:
        cfg: the run configuration.
        k_max: detections per segment of the log (from the segments' shape).
        segments: the segments the run covers (for ``filter.row_buckets: auto``; 0: unknown).
    """
    f, nz = cfg.filter, cfg.noise
    method = get_method(f.method)
    settings = static_of(method, cfg)
    static = Static(
        method=method,
        n_particles=f.n_particles,
        capacity=f.capacity,
        window=f.window,
        k_max=k_max,
        prior=COMPONENTS["prior"][f.prior](reset=f.prior_cov == "reset"),
        sequential=f.sequential,
        association=COMPONENTS["association"][f.association](),
        weight=COMPONENTS["weight"][f.weight](),
        resampler=COMPONENTS["resampler"][f.resampler](),
        estimate=COMPONENTS["estimate"][f.estimate](),
        manage=cfg.map.manage,
        occlusion=cfg.map.occlusion,
        row_buckets=row_buckets(f.row_buckets, f.n_particles, segments),
        devices=particle_devices(f.split_devices, f.n_particles, split_ok=shardable(method, settings)),
        adaptive_noise=nz.adaptive,
        method_settings=settings,
    )
    motion = motion_model_from_config(cfg)
    try:
        check_motion_model(motion)  # a user model's shapes, before any program is traced
    except ValueError as e:
        raise ValueError(f"key 'model.motion': {e}") from None
    params = hyperparameters(
        motion,
        measurement_model_from_config(cfg),
        max_range=cfg.data.max_range,
        filter=f,
        map=cfg.map,
        noise=nz,
        method=traced_of(method, cfg),
    )
    return static, params


def static_summary(static: Static) -> dict[str, Any]:
    """The static settings as plain values for a YAML or JSON record: the method and each component
    by its name (the prior's covariance as ``prior_cov``), each nested settings object as a mapping
    of its fields."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(static):
        value = getattr(static, f.name)
        if f.name == "prior":
            out["prior"], out["prior_cov"] = value.name, "reset" if value.reset else "carry"
        elif f.name == "method" or f.name in COMPONENTS:
            out[f.name] = value.name
        elif dataclasses.is_dataclass(value) and not isinstance(value, type):
            out[f.name] = dataclasses.asdict(value)
        else:
            out[f.name] = value
    return out
