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

from jaxtyping import Array, Bool, Float

from nanoslam_jax.lib._resampling import AbstractResampler, Systematic
from nanoslam_jax.methods.maps._association import AbstractAssociation, NearestAssociation
from nanoslam_jax.methods.particle._methods import NANO
from nanoslam_jax.methods.particle._path import AbstractEstimate, BestParticle
from nanoslam_jax.methods.particle._prior import AbstractPrior, UnscentedPrior
from nanoslam_jax.methods.particle._rows import AbstractWeight, ProductWeight
from nanoslam_jax.methods._method import Method
from nanoslam_jax.methods._method_settings import BeamParams as BeamParams
from nanoslam_jax.models import AbstractMeasurementModel, AbstractMotionModel, RangeBearing, is_range_bearing

#: ``filter.row_buckets: auto`` splits the per-row work (proposal, weight, landmark updates) and the
#: association's window from this many particles up (per call of the program)...
ROW_BUCKETS_FROM = 64
#: ...and only for a program that runs at least this many particle-segments over all its calls: the
#: split compiles the per-row work three times, which costs more than it saves on less work.
ROW_BUCKETS_WORK = 5_000_000
#: ``filter.split_devices: auto`` splits a run's particles over the CPU devices from this many up.
SPLIT_DEVICES_FROM = 64


class _FromMethod:
    """The default of :attr:`Static.method_settings`: the method's :attr:`~Method.static_default`."""

    def __repr__(self) -> str:
        return "<the method's default settings>"


_FROM_METHOD = _FromMethod()


_COMPONENTS = {
    "prior": AbstractPrior,
    "association": AbstractAssociation,
    "weight": AbstractWeight,
    "resampler": AbstractResampler,
    "estimate": AbstractEstimate,
}


@dataclasses.dataclass(frozen=True)
class Static:
    """Settings that fix array shapes or program structure (hashable).

    The configuration's ``filter`` and ``map`` sections take their defaults from these.

    Attributes:
        method: the method (:class:`~nanoslam_jax.methods.Method`; ``filter.method`` names one).
        n_particles: ``filter.n_particles``.
        capacity: landmark slots per particle (``filter.capacity``).
        window: landmarks per particle considered for association in a scan (``filter.window``).
        k_max: detections per segment of the log.
        row_buckets: detection-row counts the per-row work may run over (:func:`row_buckets`).
        devices: JAX devices a run's particles are split over (:func:`particle_devices`).
        prior: how a particle's pose is predicted through a segment and the covariance it starts
            from (:class:`~nanoslam_jax.methods.AbstractPrior`; ``filter.prior`` and
            ``filter.prior_cov``).
        sequential: ``filter.sequential``.
        association: which landmark each detection is
            (:class:`~nanoslam_jax.methods.AbstractAssociation`; ``filter.association``).
        weight: where the importance weight evaluates the detections
            (:class:`~nanoslam_jax.methods.AbstractWeight`; ``filter.weight``).
        resampler: the resampling scheme (:class:`~nanoslam_jax.methods.AbstractResampler`;
            ``filter.resampler``).
        estimate: the reported trajectory (:class:`~nanoslam_jax.methods.AbstractEstimate`;
            ``filter.estimate``).
        manage, occlusion: ``map.manage`` and ``map.occlusion``.
        adaptive_noise: the adaptive measurement-noise estimate is on (``noise.adaptive``).
        method_settings: the method's own static settings: a frozen dataclass such as
            :class:`~nanoslam_jax.methods.NanoStatic`, or None for a method without. Left out, the
            method's :attr:`~nanoslam_jax.methods.Method.static_default`.
    """

    method: Method = NANO
    n_particles: int = 10
    capacity: int = 512
    window: int = 64
    k_max: int = 14
    row_buckets: tuple[int, ...] = ()
    devices: int = 1
    prior: AbstractPrior = UnscentedPrior()
    sequential: bool = True
    association: AbstractAssociation = NearestAssociation()
    weight: AbstractWeight = ProductWeight()
    resampler: AbstractResampler = Systematic()
    estimate: AbstractEstimate = BestParticle()
    manage: bool = True
    occlusion: bool = True
    adaptive_noise: bool = False
    method_settings: Hashable = _FROM_METHOD

    def __post_init__(self):
        if not isinstance(self.method, Method):
            raise TypeError(
                f"Static.method: expected a nanoslam_jax.methods.Method, got {self.method!r} "
                "(nanoslam_jax.app.registry.get_method(name) gives the method of a filter.method name)"
            )
        for name, base in _COMPONENTS.items():
            if not isinstance(getattr(self, name), base):
                raise TypeError(f"Static.{name}: expected a {base.__name__}, got {getattr(self, name)!r}")
        if self.method_settings is _FROM_METHOD:
            object.__setattr__(self, "method_settings", self.method.static_default)

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
            configuration (:attr:`~nanoslam_jax.app.registry.Method.traced_settings`): a NamedTuple such
            as :class:`~nanoslam_jax.methods.NanoParams`, or for a method registered with
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


def row_buckets(setting: str, particles: int, segments: int = 0, calls: int = 1) -> tuple[int, ...]:
    """The row buckets for ``filter.row_buckets``.

    Args:
        setting: ``"auto"``, ``"always"`` or ``"never"``.
        particles: the particles one call of the program carries (for a vmapped sweep batch:
            particles times runs).
        segments: the segments one call runs over (0: unknown, and ``auto`` is off).
        calls: how many times the compiled program is called (a sweep's batches).

    ``auto`` is on from :data:`ROW_BUCKETS_FROM` particles per call and
    :data:`ROW_BUCKETS_WORK` particle-segments over all calls.
    """
    work = particles * segments * calls
    on = setting == "always" or (setting == "auto" and particles >= ROW_BUCKETS_FROM and work >= ROW_BUCKETS_WORK)
    return ROW_BUCKETS if on else ()


def shardable(method: Method, settings: Hashable = _FROM_METHOD) -> bool:
    """Whether a method's per-particle work may run under ``shard_map`` (split over devices), as
    the method says (:attr:`~nanoslam_jax.methods.Method.shardable`), given its static settings
    (``Static.method_settings``; left out, the method's default ones).

    optimistix's least-squares solvers (method ``iterated``; NANO-SLAM with ``nano.init:
    gauss_newton``) cannot: lineax compares the residual's structure with its operator's, and
    inside ``shard_map`` the operator's carries a sharding the residual's lacks. Such runs stay on
    one device: a single run's particles are not split, nor is a sweep batch of them.
    """
    return bool(method.shardable(Static(method=method, method_settings=settings)))


def particle_devices(setting: str, particles: int, devices: int | None = None, *, split_ok: bool = True) -> int:
    """JAX devices a single run's particles are split over for ``filter.split_devices``: for
    ``always``, and for ``auto`` from :data:`SPLIT_DEVICES_FROM` particles
    up, the most of the ``devices`` available (default: JAX's device count) that divide the
    particles evenly; else 1. ``split_ok`` False (a method that is not :func:`shardable`): 1."""
    if not split_ok or setting == "never" or (setting == "auto" and particles < SPLIT_DEVICES_FROM):
        return 1
    if devices is None:
        import jax

        devices = len(jax.devices())
    return next((d for d in range(devices, 1, -1) if particles % d == 0), 1)
