"""The built-in methods' own settings, nested in :class:`~._params.Static` and :class:`~._params.Params`.

A method (:class:`~nanoslam_jax.app.registry.Method`) declares the config section it reads and builds
from a configuration its static settings (a frozen, hashable dataclass: they fix shapes or
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
from typing import TYPE_CHECKING, Any, NamedTuple, TypeVar

import jax.numpy as jnp
from jaxtyping import Array, Float

if TYPE_CHECKING:
    from nanoslam_jax.app.config import Config


def _a(x: float) -> Array:
    """A traced scalar: ``x`` as a float array."""
    return jnp.asarray(x, dtype=float)


def _fields_from(cls: Any, section: Any, rename: dict[str, str] | None = None, convert: Any = None) -> dict[str, Any]:
    """Each field of ``cls`` (a dataclass or NamedTuple) from the config ``section``'s key of the same
    name (or the one ``rename`` gives), passed through ``convert`` when given."""
    names = cls._fields if hasattr(cls, "_fields") else tuple(f.name for f in dataclasses.fields(cls))
    rename = rename or {}
    value = (lambda v: v) if convert is None else convert
    return {n: value(getattr(section, rename.get(n, n))) for n in names}


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

    quadrature: str
    gh_order: int
    hessian: str
    max_iter: int
    landmark_noise: bool
    init: str
    solver: str

    @classmethod
    def from_config(cls, cfg: Config) -> NanoStatic:
        """The settings of ``cfg.nano``."""
        return cls(**_fields_from(cls, cfg.nano))


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

    @classmethod
    def from_config(cls, cfg: Config) -> NanoParams:
        """The hyperparameters of ``cfg.nano``, as traced scalars."""
        ut = {"alpha": "ut_alpha", "beta": "ut_beta", "kappa": "ut_kappa"}
        return cls(**_fields_from(cls, cfg.nano, ut, _a))


@dataclasses.dataclass(frozen=True)
class IteratedStatic:
    """The iterated proposal's static settings (the ``iterated`` section).

    Attributes:
        solver: optimistix least-squares solver, ``"gauss_newton"`` or ``"levenberg_marquardt"``.
        max_iter: solver step cap.
        tol: solver relative and absolute tolerance.
        landmark_noise: the likelihood uses ``R + Gm Sigma Gm'``.
    """

    solver: str
    max_iter: int
    tol: float
    landmark_noise: bool

    @classmethod
    def from_config(cls, cfg: Config) -> IteratedStatic:
        """The settings of ``cfg.iterated``."""
        return cls(**_fields_from(cls, cfg.iterated))


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

    feature: str
    adaptive_process: bool
    measurement: str
    line_form: str
    beams_per_feature: int
    arc_capacity: int
    groups: int
    noise_residual: str

    @classmethod
    def from_config(cls, cfg: Config) -> NasrukfStatic:
        """The settings of ``cfg.nasrukf``."""
        return cls(**_fields_from(cls, cfg.nasrukf, {"groups": "max_groups"}))


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

    @classmethod
    def from_config(cls, cfg: Config) -> NasrukfParams:
        """The hyperparameters of ``cfg.nasrukf``, as traced scalars."""
        n = cfg.nasrukf
        beams = BeamParams(**_fields_from(BeamParams, n, convert=_a)) if n.measurement == "beams" else None
        return cls(
            new_feature_hits=_a(n.new_feature_hits),
            process_forgetting=_a(n.process_forgetting),
            process_floor=_a(n.process_floor),
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
        raise TypeError(f"method {static.method!r}: expected {kind.__name__} settings, got {type(s).__name__}")
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
