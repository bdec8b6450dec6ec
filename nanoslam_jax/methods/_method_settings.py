"""The built-in methods' own settings, nested in :class:`~._params.Static` and :class:`~._params.Params`.

A method (:class:`~nanoslam_jax.methods.Method`) has static settings (a frozen, hashable dataclass: they fix shapes or
branches, and changing them recompiles), kept in ``Static.method_settings``, and its traced ones
(a NamedTuple of scalar arrays; a dict for a method registered with ``defaults``), kept in
``Params.method``. A method without static settings has None there; one without traced settings
an empty dict.

The built-in methods' settings: :class:`NanoStatic` and :class:`NanoParams` (section ``nano``),
:class:`IteratedStatic` (``iterated``), :class:`NasrukfStatic` and :class:`NasrukfParams`
(``nasrukf``, with :class:`BeamParams` for its per-beam measurement).
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple, TypeVar

from jaxtyping import Array, Float


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
