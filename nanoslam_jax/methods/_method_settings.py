"""The built-in methods' own settings, nested in :class:`~._params.Static` and :class:`~._params.Params`.

A method (:class:`~nanoslam_jax.methods.Method`) has static settings (a frozen, hashable dataclass: they fix shapes or
branches, and changing them recompiles), kept in ``Static.method_settings``, and its traced ones
(a NamedTuple of scalar arrays; a dict for a method registered with ``defaults``), kept in
``Params.method``. A method without static settings has None there; one without traced settings
an empty dict.

The built-in methods' settings: :class:`NanoStatic` and :class:`NanoParams` (section ``nano``),
:class:`IteratedStatic` (``iterated``), :class:`NasrukfStatic` and :class:`NasrukfParams`
(``nasrukf``, with :class:`BeamParams` for its per-beam measurement). The sections themselves,
with every key's default, range and meaning, are :class:`NanoConfig`, :class:`IteratedConfig` and
:class:`NasrukfConfig`; their ``static()`` and ``params()`` build the settings above.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Literal, NamedTuple, TypeVar

import jax.numpy as jnp
from jaxtyping import Array, Float

from nanoslam_jax.lib._fields import _f


@dataclasses.dataclass(frozen=True)
class NanoStatic:
    """NANO-SLAM's static settings (the ``nano`` section).

    Attributes:
        quadrature: rule for the expectations over the proposal (``nano.quadrature``).
        gh_order: Gauss-Hermite order (``nano.gh_order``).
        hessian: ``"gauss_newton"`` or ``"exact"`` expected Hessian (``nano.hessian``).
        max_iter: natural-gradient iteration cap (``nano.max_iter``).
        landmark_noise: the likelihood uses ``R + Gm Sigma Gm'`` (``nano.landmark_noise``).
        init: where the iteration starts, ``"prior"`` or ``"gauss_newton"`` (``nano.init``).
        solver: ``"optimistix"`` or ``"while_loop"`` iteration (``nano.solver``).
    """

    quadrature: str = "cubature"
    gh_order: int = 3
    hessian: str = "gauss_newton"
    max_iter: int = 10
    landmark_noise: bool = False
    init: str = "prior"
    solver: str = "while_loop"


class NanoParams(NamedTuple):
    """NANO-SLAM's traced hyperparameters (the ``nano`` section).

    Attributes:
        gamma: KL stopping threshold (``nano.gamma``).
        step: natural-gradient step, 1 undamped (``nano.step``).
        alpha, beta, kappa: unscented parameters of the quadrature (``nano.ut_alpha``, ``ut_beta``,
            ``ut_kappa``).
    """

    gamma: Float[Array, ""]
    step: Float[Array, ""]
    alpha: Float[Array, ""]
    beta: Float[Array, ""]
    kappa: Float[Array, ""]


@dataclasses.dataclass(frozen=True)
class IteratedStatic:
    """The iterated proposal's static settings (the ``iterated`` section).

    Attributes:
        solver: optimistix least-squares solver, ``"gauss_newton"`` or ``"levenberg_marquardt"``.
        max_iter: solver step cap.
        tol: solver relative and absolute tolerance.
        landmark_noise: the likelihood uses ``R + Gm Sigma Gm'``.
    """

    solver: str = "gauss_newton"
    max_iter: int = 10
    tol: float = 1e-8
    landmark_noise: bool = True


@dataclasses.dataclass(frozen=True)
class NasrukfStatic:
    """NASRUKF's static settings (the ``nasrukf`` section).

    Attributes:
        feature: ``"point"`` (a tree's centre) or ``"arc"`` (centre and radius) features.
        adaptive_process: the adaptive process-noise estimate is on.
        measurement: ``"detections"`` or ``"beams"`` (per-beam measurements).
        line_form: line parametrisation of the per-beam measurement, ``"normal"`` or
            ``"slope_intercept"``.
        beams_per_feature: beams a feature's measurement stacks at most.
        arc_capacity: arc feature slots of the per-beam measurement.
        groups: candidate groups of unmatched data (``nasrukf.max_groups``).
        noise_residual: residual the adaptive noise estimate of the per-beam measurement uses.
    """

    feature: str = "point"
    adaptive_process: bool = False
    measurement: str = "detections"
    line_form: str = "normal"
    beams_per_feature: int = 16
    arc_capacity: int = 8
    groups: int = 32
    noise_residual: str = "projected"


class BeamParams(NamedTuple):
    """Traced hyperparameters of NASRUKF's per-beam measurement (``nasrukf.measurement: beams``).

    Attributes:
        sigma_beam: range noise of one beam (m).
        beam_gate: largest difference of a beam's range from a feature's predicted range (m).
        n_new: stored unmatched data of a line or arc before a feature is created.
        merge_gate: distance under which unmatched data are of the same line or arc (m).
        static_scans: scans of static initialisation at most.
    """

    sigma_beam: Float[Array, ""]
    beam_gate: Float[Array, ""]
    n_new: Float[Array, ""]
    merge_gate: Float[Array, ""]
    static_scans: Float[Array, ""]


class NasrukfParams(NamedTuple):
    """NASRUKF's traced hyperparameters (the ``nasrukf`` section).

    Attributes:
        new_feature_hits: ``N_new``: detections a feature needs before it updates the pose.
        process_forgetting: forgetting factor ``b`` of the adaptive process-noise estimate.
        process_floor: smallest eigenvalue of that estimate's scale, a fraction of the configured noise.
        beams: the per-beam measurement's settings (:class:`BeamParams`), or None when it is not used.
    """

    new_feature_hits: Float[Array, ""]
    process_forgetting: Float[Array, ""]
    process_floor: Float[Array, ""]
    beams: BeamParams | None = None


def _a(x: float) -> Any:
    """A traced scalar: ``x`` as a float array."""
    return jnp.asarray(x, dtype=float)


def _same_names(cls: Any, section: Any, skip: tuple[str, ...] = ()) -> dict[str, Any]:
    """The fields of the dataclass ``cls`` taken from the keys of the same name of ``section``."""
    return {f.name: getattr(section, f.name) for f in dataclasses.fields(cls) if f.name not in skip}


#: The built-in methods' static defaults, which their sections take.
_NANO, _ITERATED, _NASRUKF = NanoStatic(), IteratedStatic(), NasrukfStatic()


@dataclass(frozen=True)
class NanoConfig:
    """The NANO proposal (the docs, page method/proposals.md)."""

    quadrature: Literal["cubature", "unscented", "gauss_hermite"] = _f(
        _NANO.quadrature,
        static=True,
        doc="rule for the expectations over the proposal: cubature (6 points), unscented (7), gauss_hermite (gh_order^3)",
    )
    gh_order: int = _f(_NANO.gh_order, lo=1, hi=10, static=True, doc="Gauss-Hermite order p (p^3 points)")
    ut_alpha: float = _f(1.0, lo=0.0, lo_open=True, doc="unscented alpha (nano.quadrature: unscented)")
    ut_beta: float = _f(2.0, lo=0.0, doc="unscented beta (nano.quadrature: unscented)")
    ut_kappa: float = _f(0.0, doc="unscented kappa (nano.quadrature: unscented)")
    hessian: Literal["gauss_newton", "exact"] = _f(
        _NANO.hessian,
        static=True,
        doc="expected Hessian of the log-likelihood: Gauss-Newton (J' R^-1 J, positive semi-definite) or exact (autodiff)",
    )
    gamma: float = _f(1e-4, lo=0.0, lo_open=True, doc="KL stopping threshold")
    max_iter: int = _f(_NANO.max_iter, lo=1, static=True, doc="iteration cap")
    step: float = _f(1.0, lo=0.0, lo_open=True, hi=1.0, doc="natural-gradient step beta (damping below 1)")
    landmark_noise: bool = _f(_NANO.landmark_noise, static=True, doc="use R + Gm Sigma Gm' in the likelihood")
    init: Literal["prior", "gauss_newton"] = _f(
        _NANO.init, static=True, doc="start from the prior or the Gauss-Newton MAP"
    )
    solver: Literal["optimistix", "while_loop"] = _f(
        _NANO.solver,
        static=True,
        doc="the iteration as a plain lax.while_loop (default, the faster) or as an optimistix "
        "fixed-point solve with a KL stopping rule (same iterates)",
    )

    def static(self) -> NanoStatic:
        """The static settings (:class:`NanoStatic`)."""
        return NanoStatic(**_same_names(NanoStatic, self))

    def params(self) -> NanoParams:
        """The traced hyperparameters (:class:`NanoParams`)."""
        return NanoParams(
            gamma=_a(self.gamma),
            step=_a(self.step),
            alpha=_a(self.ut_alpha),
            beta=_a(self.ut_beta),
            kappa=_a(self.ut_kappa),
        )


@dataclass(frozen=True)
class IteratedConfig:
    """The iterated (Gauss-Newton / Levenberg-Marquardt MAP) proposal, method ``iterated``."""

    solver: Literal["gauss_newton", "levenberg_marquardt"] = _f(
        _ITERATED.solver, static=True, doc="optimistix least-squares solver for the MAP of prior x likelihood"
    )
    max_iter: int = _f(_ITERATED.max_iter, lo=1, static=True, doc="solver step cap")
    tol: float = _f(_ITERATED.tol, lo=0.0, lo_open=True, static=True, doc="solver rtol = atol")
    landmark_noise: bool = _f(
        _ITERATED.landmark_noise,
        static=True,
        doc="weigh residuals with (R + Gm Sigma Gm')^-1 as FastSLAM 2.0 does (one step = FastSLAM 2.0)",
    )

    def static(self) -> IteratedStatic:
        """The static settings (:class:`IteratedStatic`)."""
        return IteratedStatic(**_same_names(IteratedStatic, self))

    def params(self) -> dict:
        """The traced hyperparameters: none of its own (an empty dict, as for a method without)."""
        return {}


@dataclass(frozen=True)
class NasrukfConfig:
    """NASRUKF FastSLAM (the second paper), method ``nasrukf``: per-feature joint states (pose and
    one tree), each a square-root unscented Kalman filter, with an information-weighted global pose.

    Its unscented transforms use ``filter.ut_alpha``, ``ut_beta``, ``ut_kappa``; association uses
    ``filter.gate``, ``filter.new_landmark``, ``filter.window``; ``filter.capacity`` feature slots."""

    feature: Literal["point", "arc"] = _f(
        _NASRUKF.feature,
        static=True,
        doc="'point': a tree is its centre, a 5-D joint state (pose + centre); 'arc': the paper's arc "
        "feature, a 6-D joint state (pose + centre + radius) with the detection's diameter as a third "
        "measurement (diameter = 2 radius, noise map.sigma_diameter)",
    )
    new_feature_hits: int = _f(
        1,
        lo=1,
        doc="the paper's 'enough new feature data' count N_new: a feature's detections update the pose "
        "only once it has been detected this many times (1: from its second detection on, as the "
        "other methods' landmarks); until then they refine the feature only",
    )
    adaptive_process: bool = _f(
        _NASRUKF.adaptive_process,
        static=True,
        doc="estimate the process noise Q of the time update online (eq. 9's estimated Q): a Sage-Husa "
        "estimate from the pose corrections K nu and covariance changes of each scan's fused joint states, "
        "with the weights d_k = (1 - b) / (1 - b^(k+1)) of process_forgetting, scaling the motion model's "
        "configured noise "
        "(noise.sigma_v and sigma_alpha_deg, unicycle or random_walk sigmas, the odometry model's "
        "rotation-translation-rotation noise) by a matrix Lambda, Q = S Lambda "
        "S'. A run reports process_noise_ratio_<j> (estimated over configured standard deviation of each noise "
        "component) in metrics.json; method nasrukf only",
    )
    process_forgetting: float = _f(
        0.99,
        lo=0.0,
        lo_open=True,
        doc="forgetting factor b of the adaptive process-noise estimate, 0 < b < 1 (its memory is about "
        "1 / (1 - b) scans with an update)",
    )
    process_floor: float = _f(
        0.01,
        lo=0.0,
        lo_open=True,
        hi=1.0,
        doc="smallest eigenvalue of the adaptive process-noise scale Lambda: the estimate stays at or above this "
        "fraction of the configured noise in every direction",
    )
    measurement: Literal["detections", "beams"] = _f(
        _NASRUKF.measurement,
        static=True,
        doc="'detections': a feature's measurement is a detection (a tree's range and bearing, data.detections "
        "file or laser); 'beams': the paper's per-beam range rho(k) along the beam angle phi(k) against line "
        "and arc features (eq. 14-17; data.detections laser_beams), each feature's beams stacked as one "
        "vector measurement; docs/method/nasrukf-beams.md",
    )
    line_form: Literal["normal", "slope_intercept"] = _f(
        _NASRUKF.line_form,
        static=True,
        doc="measurement beams: a line's state, 'normal' (rho, alpha), every line alike; 'slope_intercept': the "
        "paper's y = a x + b (eq. 14), or x = c (eq. 15) for a line steeper than 1000",
    )
    sigma_beam: float = _f(
        0.01,
        lo=0.0,
        lo_open=True,
        doc="measurement beams: the range noise of one beam (m); the adaptive estimate (noise.adaptive) starts here",
    )
    beam_gate: float = _f(
        0.06,
        lo=0.0,
        lo_open=True,
        doc="measurement beams: a beam is associated with the feature whose predicted range (eq. 14-16, at the "
        "prior pose) is nearest its measured range, if nearer than this (m)",
    )
    beams_per_feature: int = _f(
        _NASRUKF.beams_per_feature,
        lo=1,
        static=True,
        doc="measurement beams: a feature's update stacks at most this many of its associated beams of a scan "
        "(evenly spread over them)",
    )
    arc_capacity: int = _f(
        _NASRUKF.arc_capacity, lo=1, static=True, doc="measurement beams: arc feature slots (lines: filter.capacity)"
    )
    max_groups: int = _f(
        _NASRUKF.groups,
        lo=1,
        static=True,
        doc="measurement beams: front-end features (line segments and arcs) a scan holds at most; also the slots "
        "of the buffer of unmatched features (n_new)",
    )
    noise_residual: Literal["innovation", "posterior", "projected"] = _f(
        _NASRUKF.noise_residual,
        static=True,
        doc="measurement beams, noise.adaptive: the beam noise estimate with eq. 11's weights d_k from each "
        "updated feature's residuals: 'projected' (the default): before its update, the innovations with the "
        "part the state's uncertainty explains projected out, whose mean square is the beam noise whatever "
        "that uncertainty; 'innovation': eq. 11 as printed, before its update, the innovations' mean square "
        "less their predicted variance (falls to noise.adaptive_floor when the state's covariance is "
        "overestimated, e.g. a too large process noise); 'posterior': after its update, mean (z - h(x+))^2 "
        "plus the predicted variance there. With nasrukf.adaptive_process the last two trade the beam noise "
        "against the estimated process noise and the two estimates run away (docs/method/nasrukf-beams-results.md)",
    )
    n_new: int = _f(
        1,
        lo=1,
        doc="measurement beams: the paper's N_new: a front-end segment or arc that no feature explains is stored, "
        "and a feature is created once this many such data of the same line or arc have been stored (1: at once)",
    )
    merge_gate: float = _f(
        0.15,
        lo=0.0,
        lo_open=True,
        doc="measurement beams: unmatched segments (arcs) are data of the same stored line (arc) when their "
        "lines differ by less than this, |d rho| + 1 m |d alpha| (centres by less than this, m)",
    )
    static_scans: int = _f(
        40,
        lo=0,
        doc="measurement beams: static initialisation: the first scans, at most this many and only while the "
        "odometry reports no motion, hold the pose at the origin and build the initial features (0: none)",
    )

    def static(self) -> NasrukfStatic:
        """The static settings (:class:`NasrukfStatic`)."""
        return NasrukfStatic(**{**_same_names(NasrukfStatic, self, skip=("groups",)), "groups": self.max_groups})

    def params(self) -> NasrukfParams:
        """The traced hyperparameters (:class:`NasrukfParams`; its per-beam ones only for
        ``measurement: beams``)."""
        beams = None
        if self.measurement == "beams":
            beams = BeamParams(**{n: _a(getattr(self, n)) for n in BeamParams._fields})
        return NasrukfParams(
            new_feature_hits=_a(self.new_feature_hits),
            process_forgetting=_a(self.process_forgetting),
            process_floor=_a(self.process_floor),
            beams=beams,
        )


_S = TypeVar("_S")


def settings_of(static: Any, kind: type[_S]) -> _S:
    """``static.method_settings`` checked to be a ``kind`` (e.g. :class:`NasrukfStatic`).

    Raises:
        TypeError: naming the method, when its static settings are not a ``kind``.
    """
    s = static.method_settings
    if not isinstance(s, kind):
        raise TypeError(f"method {static.method.name!r}: expected {kind.__name__} settings, got {type(s).__name__}")
    return s


def nasrukf_static(static: Any) -> NasrukfStatic:
    """NASRUKF's static settings of ``static`` (:func:`settings_of`)."""
    return settings_of(static, NasrukfStatic)


def nasrukf_params(params: Any) -> NasrukfParams:
    """NASRUKF's traced hyperparameters of ``params`` (``params.method``).

    Raises:
        TypeError: when ``params.method`` is not a :class:`NasrukfParams`.
    """
    p = params.method
    if not isinstance(p, NasrukfParams):
        raise TypeError(f"expected NasrukfParams in params.method, got {type(p).__name__}")
    return p
