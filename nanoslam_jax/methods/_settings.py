"""The settings of the filter shared by every method, with their defaults, valid ranges and meaning:
the ``noise``, ``filter`` and ``map`` sections of the configuration, which takes them from here.

:func:`hyperparameters` turns them, with the models, into the traced :class:`~._params.Params`
of a run; :meth:`MapConfig.params` gives the landmark-management part, :class:`~._params.MapParams`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal, Optional

import jax.numpy as jnp

from nanoslam_jax.lib._fields import _f
from nanoslam_jax.methods._method_settings import _a
from nanoslam_jax.methods._params import (
    ROW_BUCKETS_FROM,
    ROW_BUCKETS_WORK,
    SPLIT_DEVICES_FROM,
    MapParams,
    Params,
    Static,
    _logit,
)
from nanoslam_jax.models import AbstractMeasurementModel, AbstractMotionModel
from nanoslam_jax.models._settings import SensorDefaults

__all__ = ["NoiseConfig", "FilterConfig", "MapConfig", "hyperparameters"]

#: The built-in models' noise and sensor defaults, which the noise and map sections take.
_SENSOR = SensorDefaults()
#: The filter's static defaults, which the filter, map and noise sections take.
_STATIC = Static()


def _fraction(default: float, doc: str) -> Any:
    """A field in ``(0, 1]``: a probability or a fraction (:func:`~nanoslam_jax.lib._fields._f`)."""
    return _f(default, lo=0.0, lo_open=True, hi=1.0, doc=doc)


@dataclass(frozen=True)
class NoiseConfig:
    """Control and measurement noise (published setting by default)."""

    sigma_v: float = _f(_SENSOR.sigma_v, lo=0.0, lo_open=True, doc="encoder speed noise (m/s) per DR sample")
    sigma_alpha_deg: float = _f(_SENSOR.sigma_alpha_deg, lo=0.0, lo_open=True, doc="steering noise (deg) per DR sample")
    sigma_r: float = _f(_SENSOR.sigma_r, lo=0.0, lo_open=True, doc="range noise (m)")
    sigma_beta_deg: float = _f(_SENSOR.sigma_beta_deg, lo=0.0, lo_open=True, doc="bearing noise (deg)")
    adaptive: bool = _f(
        _STATIC.adaptive_noise,
        static=True,
        doc="re-estimate the measurement noise online from the residuals of the associated detections (the "
        "NASRUKF paper's eq. 11: R_k = (1 - d_k) R_k-1 + d_k diag(nu nu' - predicted covariance), "
        "d_k = (1 - b) / (1 - b^(k+1))), starting from sigma_r, sigma_beta (and nasrukf.sigma_diameter); "
        "for nasrukf, nano, fastslam2, ufastslam. It credits the sensor with the residuals' variance less the "
        "predicted one, so it is only as good as the predicted pose and landmark covariances: where they "
        "exceed the residuals' spread it falls to adaptive_floor and detections of mapped trees then fail the "
        "gate. A run reports noise_sigma_*_final and noise_at_floor_* in metrics.json and warns when most "
        "particles end at the floor",
    )
    forgetting: float = _f(
        0.99,
        lo=0.0,
        lo_open=True,
        doc="forgetting factor b of the adaptive estimate, 0 < b < 1 (its memory is about 1 / (1 - b) detections)",
    )
    adaptive_floor: float = _fraction(
        0.01,
        doc="smallest variance the adaptive estimate may reach, as a fraction of the configured one",
    )


@dataclass(frozen=True)
class FilterConfig:
    """The Rao-Blackwellised particle filter shared by all particle methods."""

    method: str = _f(
        _STATIC.method.name,
        static=True,
        doc="the method: a particle filter with the proposal of nano, fastslam1 (the prior), fastslam2 "
        "(EKF-linearised), ufastslam (unscented) or iterated (Gauss-Newton MAP); ekf_slam (one joint "
        "Gaussian); nasrukf; dead_reckoning (the motion model alone); or a method registered with "
        "nanoslam_jax.app.registry.register (by its name, or by import path 'module:METHOD')",
    )
    method_params: Optional[dict] = _f(
        None, doc="parameters of a registered method that declares them: a mapping of name to number (traced)"
    )
    n_particles: int = _f(_STATIC.n_particles, lo=1, static=True, doc="particles")
    capacity: int = _f(_STATIC.capacity, lo=1, static=True, doc="landmark slots per particle")
    window: int = _f(
        _STATIC.window,
        lo=1,
        static=True,
        doc="landmarks per particle considered for association in a scan (local window)",
    )
    window_margin: float = _f(5.0, lo=0.0, doc="the window holds landmarks within max_range + this (m)")
    prior: Literal["unscented", "linearized"] = _f(
        _STATIC.prior.name, static=True, doc="how control noise is mapped to the pose covariance"
    )
    prior_cov: Literal["reset", "carry"] = _f(
        "reset" if _STATIC.prior.reset else "carry",
        static=True,
        doc="'reset': start each segment from the sampled pose with init_cov; 'carry': from the last proposal covariance",
    )
    init_cov: float = _f(1e-8, lo=0.0, lo_open=True, doc="near-zero pose variance at the start and after a reset")
    ut_alpha: float = _f(0.9, lo=0.0, lo_open=True, doc="unscented alpha of the prior (and of UFastSLAM)")
    ut_beta: float = _f(2.0, lo=0.0, doc="unscented beta of the prior (and of UFastSLAM); 2 is optimal for Gaussians")
    ut_kappa: float = _f(0.0, doc="unscented kappa of the prior (and of UFastSLAM)")
    gate: float = _f(5.991, lo=0.0, lo_open=True, doc="chi-square (2 dof) association gate on d2")
    new_landmark: float = _f(
        9.21,
        lo=0.0,
        lo_open=True,
        doc="a detection whose best d2 exceeds this starts a landmark (9.21: chi-square 99 %, 2 dof; "
        "with landmark management a spurious one is removed again)",
    )
    sequential: bool = _f(_STATIC.sequential, static=True, doc="associate detections one after another within a scan")
    association: Literal["nearest", "known"] = _f(
        _STATIC.association.name,
        static=True,
        doc="'nearest': nearest neighbour within filter.gate, a new landmark above filter.new_landmark; 'known': "
        "the log's landmark ids (e.g. MRCLAM's barcodes): a detection matches the landmark started by its "
        "id and starts one when none has it; detections without an id are ignored",
    )
    weight: Literal["product", "marginal"] = _f(
        _STATIC.weight.name, static=True, doc="'product': eq. 17 at the proposal; 'marginal': likelihood at the prior"
    )
    p0: float = _f(0.05, lo=0.0, lo_open=True, doc="likelihood factor of a new landmark")
    resampler: Literal["systematic", "stratified", "multinomial", "residual"] = _f(
        _STATIC.resampler.name, static=True, doc="resampling scheme"
    )
    resample_threshold: float = _f(0.5, lo=0.0, hi=1.0, doc="resample when ESS < threshold * N")
    estimate: Literal["best", "mean", "path"] = _f(
        _STATIC.estimate.name,
        static=True,
        doc="reported trajectory: at each segment the highest-weight particle's pose (best, the paper's) or the "
        "weighted mean (mean); or path: the history of the particle that is best at the end of the log, "
        "followed back through the resampling steps (the path its final map was built along; an offline, "
        "smoothed estimate; particle methods only; records every particle's pose per segment)",
    )
    row_buckets: Literal["auto", "always", "never"] = _f(
        "auto",
        static=True,
        doc="run the proposal, the weight's likelihoods and the landmarks' updates over only 4, 8 or k_max "
        "detection rows, the fewest that hold the scan's detections, and the association over the "
        "16, 32 or all window slots that hold the particles' landmarks (the same results to rounding; "
        "compiled three times, so compilation takes longer): 'auto' from "
        f"{ROW_BUCKETS_FROM} particles per call up, for a program that runs at least {ROW_BUCKETS_WORK:,} "
        "particle-segments over all its calls (a sweep's batches): below that the longer compilation costs more "
        "than the split saves",
    )
    split_devices: Literal["auto", "always", "never"] = _f(
        "auto",
        static=True,
        doc="split a single run's particles over the JAX CPU devices (one per core; `nanoslam run` sets them "
        f"up) when they divide evenly; the same results to rounding. 'auto': from {SPLIT_DEVICES_FROM} particles up "
        "(below that the devices' exchange at every scan outweighs the split work); never for "
        "filter.method iterated or nano.init gauss_newton (optimistix's least squares cannot run split)",
    )


@dataclass(frozen=True)
class MapConfig:
    """Landmark management: tentative and confirmed landmarks, existence by negative evidence, tree
    diameters (all particle methods, EKF-SLAM and NASRUKF).

    How the defaults were chosen: docs/method/landmarks.md, "Settings and how they were chosen".

    A detection that starts a landmark makes it *tentative*, with existence log-odds
    ``logit(birth_probability)``. Every detection associated with it adds ``log(p_detect / p_false)``;
    every scan in which it lay inside the sensor's footprint (shrunk by the view margins) at the
    particle's pose, was not hidden behind a nearer object, and was not detected adds
    ``log((1 - p_detect) / (1 - p_false))``. The log-odds are clamped at ``logit(max_probability)``.
    A tentative landmark is confirmed once its existence probability reaches
    ``confirm_probability`` with at least ``confirm_hits`` detections, and dropped if that has not
    happened within ``tentative_scans`` scans of its birth. Any landmark whose existence probability
    falls below ``remove_probability`` is removed and its slot reused.
    """

    manage: bool = _f(
        _STATIC.manage,
        static=True,
        doc="landmark management on; false: every detection beyond filter.new_landmark starts a permanent "
        "landmark that is used at once (the published methods' rule), and the other keys here are ignored",
    )
    p_detect: float = _fraction(
        0.75,
        doc="probability that a landmark inside the sensor footprint is detected in a scan",
    )
    p_false: float = _fraction(
        0.075,
        doc="probability that a landmark that does not exist (clutter) is 'detected' again in a scan "
        "(a clutter detection falling in its gate); must be below p_detect",
    )
    birth_probability: float = _fraction(
        0.5,
        doc="existence probability of a landmark right after the detection that starts it",
    )
    confirm_probability: float = _fraction(
        0.9,
        doc="a tentative landmark is confirmed when its existence probability reaches this ...",
    )
    confirm_hits: int = _f(4, lo=1, doc="... and it has at least this many detections (its first included)")
    tentative_scans: int = _f(
        40, lo=1, doc="a tentative landmark not confirmed within this many scans after its birth is dropped"
    )
    remove_probability: float = _f(
        0.02, lo=0.0, hi=1.0, doc="a landmark whose existence probability falls below this is removed (its slot reused)"
    )
    max_probability: float = _fraction(
        0.99,
        doc="existence probabilities are capped here, so a tree that has gone can still be removed after a few misses",
    )
    fov_deg: float = _f(_SENSOR.fov_deg, lo=0.0, lo_open=True, hi=360.0, doc="the sensor's field of view (deg)")
    view_margin: float = _f(
        _SENSOR.view_margin,
        lo=0.0,
        doc="a miss is counted only when the landmark is at least this far (m) inside the sensor's range "
        "limits (data.min_range, data.max_range)",
    )
    view_margin_deg: float = _f(_SENSOR.view_margin_deg, lo=0.0, doc="... and this far (deg) inside the field of view")
    occlusion: bool = _f(
        _STATIC.occlusion,
        static=True,
        doc="no miss for a landmark hidden behind a nearer object at a similar bearing (a detection of "
        "the scan or a confirmed landmark)",
    )
    occlusion_width: float = _f(
        1.0, lo=0.0, doc="half-width (m) added to an occluder's radius (half its diameter) in the occlusion test"
    )
    use_tentative: bool = _f(
        True,
        doc="tentative landmarks also shape the proposal and the weight; false: only confirmed ones do "
        "(a detection matching a tentative landmark then weighs as a new one, filter.p0)",
    )
    use_diameter: bool = _f(
        False,
        doc="add the tree-diameter term (d - d_j)^2 / (var_j + sigma_diameter^2) to the association "
        "distance (then filter.gate and filter.new_landmark apply to a 3-dof chi-square: 7.815 and "
        "16.266 at 95 % and 99.9 %)",
    )
    sigma_diameter: float = _f(
        0.05,
        lo=0.0,
        lo_open=True,
        doc="diameter measurement noise (m): the per-landmark diameter filter and the association term",
    )

    def params(self) -> MapParams:
        """The traced landmark-management hyperparameters: the existence probabilities as the log-odds
        the filter adds and compares (:class:`~nanoslam_jax.methods.MapParams`)."""
        miss = math.log1p(-self.p_detect) - math.log1p(-self.p_false) if self.p_detect < 1.0 else -math.inf
        return MapParams(
            log_odds_hit=_a(math.log(self.p_detect / self.p_false)),
            log_odds_miss=_a(miss),
            log_odds_birth=_a(_logit(self.birth_probability)),
            log_odds_confirm=_a(_logit(self.confirm_probability)),
            confirm_hits=_a(self.confirm_hits),
            tentative_scans=_a(self.tentative_scans),
            log_odds_remove=_a(_logit(self.remove_probability)),
            log_odds_max=_a(_logit(self.max_probability)),
            occlusion_width=_a(self.occlusion_width),
            use_tentative=jnp.asarray(self.use_tentative),
            use_diameter=jnp.asarray(self.use_diameter),
            sigma_diameter=_a(self.sigma_diameter),
        )


def hyperparameters(
    motion: AbstractMotionModel,
    measurement: AbstractMeasurementModel,
    *,
    max_range: float,
    filter: FilterConfig = FilterConfig(),
    map: MapConfig = MapConfig(),
    noise: NoiseConfig = NoiseConfig(),
    method: Any = None,
) -> Params:
    """A run's traced hyperparameters (:class:`~nanoslam_jax.methods.Params`), every one from the
    settings given (left out: their defaults).

    Args:
        motion: the motion model with its parameters and process noise.
        measurement: the measurement model with its noise and field of view.
        max_range: the sensor's range (m).
        filter: the shared filter's settings (its traced keys: gate, new_landmark, p0, init_cov,
            ut_alpha, ut_beta, ut_kappa, resample_threshold, window_margin).
        map: landmark management (:meth:`MapConfig.params`).
        noise: the adaptive measurement-noise estimate's forgetting factor and floor (its
            ``sigma_*`` keys configure the models, which are given here already built).
        method: the method's own traced hyperparameters, e.g.
            :meth:`~nanoslam_jax.methods.NanoConfig.params` (None: a method without; an empty dict).
    """
    return Params(
        motion=motion,
        measurement=measurement,
        init_cov=_a(filter.init_cov),
        ut_alpha=_a(filter.ut_alpha),
        ut_beta=_a(filter.ut_beta),
        ut_kappa=_a(filter.ut_kappa),
        gate=_a(filter.gate),
        new_landmark=_a(filter.new_landmark),
        log_p0=_a(math.log(filter.p0)),
        resample_threshold=_a(filter.resample_threshold),
        max_range=_a(max_range),
        window_margin=_a(filter.window_margin),
        map=map.params(),
        forgetting=_a(noise.forgetting),
        noise_floor=_a(noise.adaptive_floor),
        method={} if method is None else method,
    )
