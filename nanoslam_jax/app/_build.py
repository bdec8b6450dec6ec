"""Core objects from a configuration: the filter's static settings and traced hyperparameters of a
run (:func:`settings_from_config`), the method's static settings (:func:`method_static`)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Hashable
from typing import Any

import jax.numpy as jnp

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
from nanoslam_jax.methods._params import MapParams, Params, Static, _logit, particle_devices, row_buckets, shardable
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
    a = lambda x: jnp.asarray(x, dtype=float)  # noqa: E731
    mp = cfg.map
    map_params = MapParams(
        log_odds_hit=a(math.log(mp.p_detect / mp.p_false)),
        log_odds_miss=a(math.log1p(-mp.p_detect) - math.log1p(-mp.p_false) if mp.p_detect < 1.0 else -math.inf),
        log_odds_birth=a(_logit(mp.birth_probability)),
        log_odds_confirm=a(_logit(mp.confirm_probability)),
        confirm_hits=a(mp.confirm_hits),
        tentative_scans=a(mp.tentative_scans),
        log_odds_remove=a(_logit(mp.remove_probability)),
        log_odds_max=a(_logit(mp.max_probability)),
        occlusion_width=a(mp.occlusion_width),
        use_tentative=jnp.asarray(mp.use_tentative),
        use_diameter=jnp.asarray(mp.use_diameter),
        sigma_diameter=a(mp.sigma_diameter),
    )
    motion = motion_model_from_config(cfg)
    try:
        check_motion_model(motion)  # a user model's shapes, before any program is traced
    except ValueError as e:
        raise ValueError(f"key 'model.motion': {e}") from None
    params = Params(
        motion=motion,
        measurement=measurement_model_from_config(cfg),
        init_cov=a(f.init_cov),
        ut_alpha=a(f.ut_alpha),
        ut_beta=a(f.ut_beta),
        ut_kappa=a(f.ut_kappa),
        gate=a(f.gate),
        new_landmark=a(f.new_landmark),
        log_p0=a(math.log(f.p0)),
        resample_threshold=a(f.resample_threshold),
        max_range=a(cfg.data.max_range),
        window_margin=a(f.window_margin),
        map=map_params,
        forgetting=a(nz.forgetting),
        noise_floor=a(nz.adaptive_floor),
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
