"""Filter settings split into static ones (shapes, branches) and traced hyperparameters.

:class:`Static` is hashable and is a static argument of the compiled program: changing it
recompiles. :class:`Params` holds every hyperparameter a sweep may vary as a traced scalar,
so one compilation serves a whole sweep (and ``jax.vmap`` over a batch of :class:`Params`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Hashable
from typing import Any, NamedTuple

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from ..config import ROW_BUCKETS_FROM, SPLIT_DEVICES_FROM, Config
from ..methods import get_method
from ._method_settings import BeamParams as BeamParams
from ..models import (
    AbstractMeasurementModel,
    AbstractMotionModel,
    RangeBearing,
    is_range_bearing,
    measurement_model_from_config,
    check_motion_model,
    motion_model_from_config,
)


#: The configuration's defaults, the one source of :class:`Static`'s.
_C = Config()


class _FromMethod:
    """The default of :attr:`Static.method_settings`: the method's settings under :data:`_C`."""

    def __repr__(self) -> str:
        return "<the method's settings under the default configuration>"


_FROM_METHOD = _FromMethod()


@dataclasses.dataclass(frozen=True)
class Static:
    """Settings that fix array shapes or program structure (hashable).

    Its defaults are the configuration's: ``Static()`` equals the static part of
    ``settings_from_config(Config(), Static().k_max)``.

    Attributes:
        method: ``filter.method``.
        n_particles: ``filter.n_particles``.
        capacity: landmark slots per particle (``filter.capacity``).
        window: landmarks per particle considered for association in a scan (``filter.window``).
        k_max: detections per segment of the log.
        row_buckets: detection-row counts the per-row work may run over (:func:`row_buckets`).
        devices: JAX devices a run's particles are split over (:func:`particle_devices`).
        prior, prior_cov, sequential, association, weight, resampler, estimate: the ``filter``
            section's keys of those names.
        manage, occlusion: ``map.manage`` and ``map.occlusion``.
        landmark_update: ``"ekf"`` or ``"unscented"`` landmark updates (the method's).
        adaptive_noise: the adaptive measurement-noise estimate is on (``noise.adaptive``).
        method_settings: the method's own static settings, as its registration builds them from
            the configuration (:attr:`~nanoslam_jax.methods.Method.static_settings`): a frozen
            dataclass such as :class:`~nanoslam_jax.filter.NanoStatic`, or None for a method without.
            Left out, those of the default configuration.
    """

    method: str = _C.filter.method
    n_particles: int = _C.filter.n_particles
    capacity: int = _C.filter.capacity
    window: int = _C.filter.window
    k_max: int = 14
    row_buckets: tuple[int, ...] = ()
    devices: int = 1
    prior: str = _C.filter.prior
    prior_cov: str = _C.filter.prior_cov
    sequential: bool = _C.filter.sequential
    association: str = _C.filter.association
    weight: str = _C.filter.weight
    resampler: str = _C.filter.resampler
    estimate: str = _C.filter.estimate
    manage: bool = _C.map.manage
    occlusion: bool = _C.map.occlusion
    landmark_update: str = "ekf"
    adaptive_noise: bool = _C.noise.adaptive
    method_settings: Hashable = _FROM_METHOD

    def __post_init__(self):
        if self.method_settings is _FROM_METHOD:
            object.__setattr__(self, "method_settings", get_method(self.method).static_of(_C))

    @property
    def window_size(self) -> int:
        """Local slots: the window plus one provisional slot per detection."""
        return min(self.window, self.capacity) + self.k_max

    @property
    def slot_buckets(self) -> tuple[int, ...]:
        """Map prefixes the local-window search runs over (the smallest holding every active
        landmark is searched): powers of two from 64 below the capacity, then the capacity."""
        sizes, b = [], 64
        while b < self.capacity:
            sizes.append(b)
            b *= 2
        return (*sizes, self.capacity)


class MapParams(NamedTuple):
    """Traced landmark-management hyperparameters (``map`` config section), in the form the filter
    uses them: existence as log-odds, angles in radians.

    Attributes:
        log_odds_hit: added to a landmark's existence log-odds by a detection associated with it,
            ``log(p_detect / p_false)``.
        log_odds_miss: added in a scan where it was in view, not hidden and not detected,
            ``log((1 - p_detect) / (1 - p_false))``.
        log_odds_birth: log-odds of a landmark right after the detection that starts it.
        log_odds_confirm: a tentative landmark is confirmed at or above this ...
        confirm_hits: ... with at least this many detections.
        tentative_scans: a tentative landmark older than this (scans) is dropped.
        log_odds_remove: a landmark below this is removed.
        log_odds_max: the log-odds are clamped at this.
        occlusion_width: half-width (m) added to an occluder's radius.
        use_tentative: tentative landmarks shape the proposal and weight (a traced boolean).
        use_diameter: the diameter term enters the association distance (a traced boolean).
        sigma_diameter: diameter measurement noise (m).
    """

    log_odds_hit: Float[Array, ""]
    log_odds_miss: Float[Array, ""]
    log_odds_birth: Float[Array, ""]
    log_odds_confirm: Float[Array, ""]
    confirm_hits: Float[Array, ""]
    tentative_scans: Float[Array, ""]
    log_odds_remove: Float[Array, ""]
    log_odds_max: Float[Array, ""]
    occlusion_width: Float[Array, ""]
    use_tentative: Bool[Array, ""]
    use_diameter: Bool[Array, ""]
    sigma_diameter: Float[Array, ""]


def _logit(p: float) -> float:
    """``log(p / (1 - p))`` with the limits 0 -> -inf and 1 -> inf."""
    if p <= 0.0:
        return -math.inf
    if p >= 1.0:
        return math.inf
    return math.log(p / (1.0 - p))


class Params(NamedTuple):
    """Traced hyperparameters (all scalars; angles in radians).

    Attributes:
        motion: the motion model with its parameters and process noise (``model.motion``).
        measurement: the measurement model with its noise and field of view (``model.measurement``).
        init_cov: near-zero pose variance at the start and after a reset.
        ut_alpha, ut_beta, ut_kappa: unscented parameters of the prior (and UFastSLAM).
        gate: chi-square association gate on d2.
        new_landmark: d2 above which a detection starts a landmark.
        log_p0: log of the likelihood factor of a new landmark.
        resample_threshold: resample when ESS < threshold * N.
        max_range: sensor range (m), used by the local window and the miss rule.
        window_margin: landmarks within ``max_range + window_margin`` of a particle's prior
            position enter its local window (m).
        map: landmark-management hyperparameters (see :class:`MapParams`).
        forgetting: forgetting factor ``b`` of the adaptive measurement-noise estimate.
        noise_floor: smallest adaptive noise variance, as a fraction of the configured one.
        method: the method's own traced hyperparameters, as its registration builds them from the
            configuration (:attr:`~nanoslam_jax.methods.Method.traced_settings`): a NamedTuple such
            as :class:`~nanoslam_jax.filter.NanoParams`, or for a method registered with
            ``defaults`` the dict of them updated by ``filter.method_params`` (empty for a method
            without).
    """

    motion: AbstractMotionModel
    measurement: AbstractMeasurementModel
    init_cov: Float[Array, ""]
    ut_alpha: Float[Array, ""]
    ut_beta: Float[Array, ""]
    ut_kappa: Float[Array, ""]
    gate: Float[Array, ""]
    new_landmark: Float[Array, ""]
    log_p0: Float[Array, ""]
    resample_threshold: Float[Array, ""]
    max_range: Float[Array, ""]
    window_margin: Float[Array, ""]
    map: "MapParams"
    forgetting: Float[Array, ""]
    noise_floor: Float[Array, ""]
    method: Any = {}

    @property
    def R(self) -> Float[Array, "d d"]:
        """Measurement noise covariance (the measurement model's)."""
        return self.measurement.noise_cov()

    @property
    def sigma_r(self) -> Float[Array, ""]:
        """Range noise (m) of a range-bearing measurement model."""
        return self._range_bearing().sigma_r

    @property
    def sigma_beta(self) -> Float[Array, ""]:
        """Bearing noise (rad) of a range-bearing measurement model."""
        return self._range_bearing().sigma_beta

    def _range_bearing(self) -> RangeBearing:
        if not is_range_bearing(self.measurement):
            raise AttributeError(
                f"the measurement model {type(self.measurement).__name__} is not range-bearing: "
                "it has no sigma_r or sigma_beta"
            )
        return self.measurement


#: Detection-row counts the per-row work (proposal, weight, landmark updates) may run over (then
#: ``k_max``): see ``filter.row_buckets``.
ROW_BUCKETS = (4, 8)


def row_buckets(setting: str, particles: int) -> tuple[int, ...]:
    """The row buckets for ``filter.row_buckets`` and the particles one program
    carries (for a vmapped sweep batch: particles times runs)."""
    on = setting == "always" or (setting == "auto" and particles >= ROW_BUCKETS_FROM)
    return ROW_BUCKETS if on else ()


def shardable(method: str, settings: Hashable = _FROM_METHOD) -> bool:
    """Whether a method's per-particle work may run under ``shard_map`` (split over devices), as
    its registration says (:attr:`~nanoslam_jax.methods.Method.shardable`), given its static
    settings (``Static.method_settings``; :func:`method_static` of a configuration; left out,
    those of the default configuration).

    optimistix's least-squares solvers (method ``iterated``; NANO-SLAM with ``nano.init:
    gauss_newton``) cannot: lineax compares the residual's structure with its operator's, and
    inside ``shard_map`` the operator's carries a sharding the residual's lacks. Such runs stay on
    one device: a single run's particles are not split, nor is a sweep batch of them.
    """
    return bool(get_method(method).shardable(Static(method=method, method_settings=settings)))


def method_static(cfg: Config) -> Hashable:
    """The static settings of ``cfg``'s method (``Static.method_settings``), built by its
    registration from ``cfg`` without any JAX computation."""
    return get_method(cfg.filter.method).static_of(cfg)


def particle_devices(setting: str, particles: int, devices: int | None = None, *, split_ok: bool = True) -> int:
    """JAX devices a single run's particles are split over for ``filter.split_devices``: for
    ``always``, and for ``auto`` from :data:`~nanoslam_jax.config.SPLIT_DEVICES_FROM` particles
    up, the most of the ``devices`` available (default: JAX's device count) that divide the
    particles evenly; else 1. ``split_ok`` False (a method that is not :func:`shardable`): 1."""
    if not split_ok or setting == "never" or (setting == "auto" and particles < SPLIT_DEVICES_FROM):
        return 1
    if devices is None:
        import jax

        devices = len(jax.devices())
    return next((d for d in range(devices, 1, -1) if particles % d == 0), 1)


def settings_from_config(cfg: Config, k_max: int) -> tuple[Static, Params]:
    """Split a :class:`Config` into the static settings and the traced hyperparameters.

    Args:
        cfg: the run configuration.
        k_max: detections per segment of the log (from the segments' shape).
    """
    f, nz = cfg.filter, cfg.noise
    method = get_method(f.method)
    settings = method.static_of(cfg)
    static = Static(
        method=f.method,
        n_particles=f.n_particles,
        capacity=f.capacity,
        window=f.window,
        k_max=k_max,
        prior=f.prior,
        prior_cov=f.prior_cov,
        sequential=f.sequential,
        association=f.association,
        weight=f.weight,
        resampler=f.resampler,
        estimate=f.estimate,
        manage=cfg.map.manage,
        occlusion=cfg.map.occlusion,
        landmark_update=method.landmark_update,
        row_buckets=row_buckets(f.row_buckets, f.n_particles),
        devices=particle_devices(f.split_devices, f.n_particles, split_ok=shardable(f.method, settings)),
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
        method=method.traced_of(cfg),
    )
    return static, params
