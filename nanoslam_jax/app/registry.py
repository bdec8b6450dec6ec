"""The method registry: every SLAM method the filter runs, by its ``filter.method`` name.

A :class:`Method` says how a method is built and run: for a particle method its proposal (the
Gaussian over the pose each particle samples from; the shared Rao-Blackwellised step does the
rest: association, landmark updates, weights, management, resampling), for a Gaussian method its
own ``init`` and ``step``. Adding a proposal is one module that defines an
:class:`~nanoslam_jax.methods.proposals.AbstractProposal` and one :func:`register` call::

    from nanoslam_jax.app.registry import Method, register
    from my_package.proposal import MyProposal

    register(Method(
        name="mine",
        proposal=lambda static, params, cfg: MyProposal(step=cfg["step"]),
        defaults={"step": 0.5},
        description="my proposal",
    ))

after which ``filter.method: mine`` runs it (``nanoslam run``, ``compare``, ``sweep`` and the
Python API), with its parameters from ``filter.method_params`` (traced: a sweep over them
compiles once). A method with a config section of its own (the built-in ones) declares it
(:attr:`Method.section`) and builds its settings from the configuration: its static ones
(:attr:`Method.static_settings`, a frozen dataclass kept in ``Static.method_settings``) and its
traced ones (:attr:`Method.traced_settings`, a NamedTuple kept in ``Params.method`` and passed to
its proposal), e.g. :class:`~nanoslam_jax.methods.NanoStatic` and
:class:`~nanoslam_jax.methods.NanoParams`. A config file can name a method that a module registers
by import path, ``filter.method: my_package.proposal:METHOD`` (the module is imported, ``METHOD``
must be a :class:`Method`, and it is registered under that name). A proposal that evaluates the
detections takes the run's measurement model from ``params.measurement`` (an
:class:`~nanoslam_jax.models.AbstractMeasurementModel`), as the built-in ones do.
"""

from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Callable, Hashable, Mapping
from typing import TYPE_CHECKING, Any, Literal, Optional

if TYPE_CHECKING:
    from nanoslam_jax.app.config import Config
    from nanoslam_jax.methods._params import Params, Static

__all__ = ["Method", "register", "get_method", "method_names", "METHOD_KINDS"]

#: What a method is: a particle filter with its own proposal, a Gaussian filter with its own state
#: and step, or the motion model alone.
METHOD_KINDS = ("particle", "gaussian", "dead_reckoning")


@dataclasses.dataclass(frozen=True)
class Method:
    """A registered method.

    Attributes:
        name: its ``filter.method`` name.
        kind: ``"particle"`` (built on the shared particle step, with :attr:`proposal`),
            ``"gaussian"`` (its own :attr:`init` and :attr:`step`) or ``"dead_reckoning"``.
        proposal: ``proposal(static, params, settings) -> AbstractProposal`` for a particle
            method: the proposal with its traced hyperparameters (``settings``: its traced
            settings ``params.method``, see :attr:`traced_settings`).
        init: ``init(static, params) -> state`` of a Gaussian method: its first state, a
            :class:`~nanoslam_jax.methods.GaussianState` (a pytree offering ``pose``,
            ``pose_cov``, ``landmark_map()``, ``overflow`` and ``scan``). It takes no key: a
            Gaussian method does not sample, and the driver keeps the run's key.
        step: ``step(static, params, state, segment, valid) -> (state, GaussianStepOutput)`` of
            a Gaussian method: one segment (``valid`` False: padding, the state unchanged), and
            its record, a :class:`~nanoslam_jax.methods.GaussianStepOutput` (the pose mean and
            covariance and the map's counts), which the driver turns into the common per-scan
            :class:`~nanoslam_jax.methods.StepOutput` (one hypothesis: best pose = mean pose,
            ESS 1, never resampled).
        landmark_update: how a particle method updates its landmarks: ``"ekf"`` (linearised) or
            ``"unscented"``.
        shardable: ``shardable(static) -> bool``: whether its per-particle work may be split over
            devices (``shard_map``), given the static settings (its own in
            ``static.method_settings``).
        adaptive_noise: it offers the adaptive measurement-noise estimate (``noise.adaptive``).
        defaults: its traced parameters and their defaults (``filter.method_params`` overrides
            them; unknown names are refused), for a method without :attr:`traced_settings`.
        description: one line for the config reference and error messages.
        section: the config section its settings are read from (``"nano"``, ``"iterated"``,
            ``"nasrukf"``), None for none.
        static_settings: ``static_settings(cfg) -> settings``: its static settings from the
            configuration, a hashable value (a frozen dataclass) kept in
            ``Static.method_settings``; changing them recompiles. It must not compute with JAX
            (it runs before the devices are set up). None: it has none (``method_settings`` None).
        traced_settings: ``traced_settings(cfg) -> settings``: its traced hyperparameters from the
            configuration, a pytree of scalar arrays (a NamedTuple) kept in ``Params.method`` and
            passed to :attr:`proposal`; a sweep over them compiles once. None: the mapping of
            :attr:`defaults` updated by ``filter.method_params``, as traced scalars (a dict).
    """

    name: str
    kind: Literal["particle", "gaussian", "dead_reckoning"] = "particle"
    proposal: Optional[Callable[..., Any]] = None
    init: Optional[Callable[..., Any]] = None
    step: Optional[Callable[..., Any]] = None
    landmark_update: Literal["ekf", "unscented"] = "ekf"
    shardable: Callable[["Static"], bool] = lambda static: True
    adaptive_noise: bool = False
    defaults: Mapping[str, float] = dataclasses.field(default_factory=dict)
    description: str = ""
    section: Optional[str] = None
    static_settings: Optional[Callable[["Config"], Hashable]] = None
    traced_settings: Optional[Callable[["Config"], Any]] = None

    def __post_init__(self):
        if self.kind not in METHOD_KINDS:
            raise ValueError(f"Method {self.name!r}: kind must be one of {', '.join(METHOD_KINDS)}, got {self.kind!r}")
        if self.kind == "particle" and self.proposal is None:
            raise ValueError(f"Method {self.name!r}: a particle method needs a proposal")
        if self.kind == "gaussian" and (self.init is None or self.step is None):
            raise ValueError(f"Method {self.name!r}: a Gaussian method needs init and step")
        if self.landmark_update not in ("ekf", "unscented"):
            raise ValueError(f"Method {self.name!r}: landmark_update must be 'ekf' or 'unscented'")

    def method_params(self, given: Optional[Mapping[str, float]]) -> dict[str, float]:
        """:attr:`defaults` updated by ``filter.method_params`` (``given``).

        Raises:
            ValueError: naming the key, for a name the method does not take.
        """
        out = dict(self.defaults)
        for k, v in (given or {}).items():
            if k not in out:
                takes = ", ".join(sorted(out)) or "none"
                raise ValueError(
                    f"key 'filter.method_params.{k}': method {self.name!r} takes no parameter {k!r} (it takes: {takes})"
                )
            out[k] = float(v)
        return out

    def static_of(self, cfg: "Config") -> Hashable:
        """Its static settings under ``cfg`` (:attr:`static_settings`; None when it has none)."""
        return None if self.static_settings is None else self.static_settings(cfg)

    def traced_of(self, cfg: "Config") -> Any:
        """Its traced hyperparameters under ``cfg`` (:attr:`traced_settings`; without, the dict of
        :attr:`method_params` of ``filter.method_params`` as float arrays)."""
        if self.traced_settings is not None:
            return self.traced_settings(cfg)
        import jax.numpy as jnp

        return {k: jnp.asarray(v, dtype=float) for k, v in self.method_params(cfg.filter.method_params).items()}


_REGISTRY: dict[str, Method] = {}


def register(method: Method, *, replace: bool = False) -> Method:
    """Register ``method`` under its name (``replace``: allow redefining a name).

    Returns:
        The method (so a module can write ``METHOD = register(Method(...))``).
    """
    if not isinstance(method, Method):
        raise TypeError(f"register: expected a nanoslam_jax.app.registry.Method, got {type(method).__name__}")
    if method.name in _REGISTRY and not replace and _REGISTRY[method.name] is not method:
        raise ValueError(f"a method named {method.name!r} is registered already (pass replace=True to redefine it)")
    _REGISTRY[method.name] = method
    return method


def method_names() -> tuple[str, ...]:
    """The names of the registered methods."""
    return tuple(_REGISTRY)


def get_method(name: str) -> Method:
    """The method registered as ``name``; a name ``module:attr`` imports ``module`` and registers
    its :class:`Method` ``attr`` under that name.

    Raises:
        ValueError: naming ``filter.method``, when there is no such method.
    """
    if name in _REGISTRY:
        return _REGISTRY[name]
    if ":" in name:
        module, _, attr = name.partition(":")
        try:
            obj = getattr(importlib.import_module(module), attr)
        except (ImportError, AttributeError) as e:
            raise ValueError(f"key 'filter.method': cannot load {name!r}: {e}") from None
        if not isinstance(obj, Method):
            raise ValueError(f"key 'filter.method': {name!r} is not a nanoslam_jax.app.registry.Method")
        return register(dataclasses.replace(obj, name=name), replace=True)
    raise ValueError(
        f"key 'filter.method': {name!r} is not a registered method; expected one of "
        f"{', '.join(map(repr, _REGISTRY))} (or one by import path 'module:METHOD')"
    )


# --------------------------------------------------------------------------- built-in methods


def _nano(static: "Static", params: "Params", mp: Any):
    from nanoslam_jax.methods._method_settings import NanoStatic, settings_of
    from nanoslam_jax.methods.proposals import NanoProposal
    from nanoslam_jax.lib.quadrature import make_rule

    ns: NanoStatic = settings_of(static, NanoStatic)
    rule = make_rule(ns.quadrature, alpha=mp.alpha, beta=mp.beta, kappa=mp.kappa, order=ns.gh_order)
    return NanoProposal(
        rule,
        mp.gamma,
        mp.step,
        max_iter=ns.max_iter,
        hessian=ns.hessian,
        landmark_noise=ns.landmark_noise,
        init=ns.init,
        solver=ns.solver,
        measurement=params.measurement,
    )


def _nano_static(cfg):
    from nanoslam_jax.methods._method_settings import NanoStatic

    return NanoStatic.from_config(cfg)


def _nano_traced(cfg):
    from nanoslam_jax.methods._method_settings import NanoParams

    return NanoParams.from_config(cfg)


def _nano_shardable(static) -> bool:
    from nanoslam_jax.methods._method_settings import NanoStatic, settings_of

    return settings_of(static, NanoStatic).init != "gauss_newton"


def _fastslam1(static, params, mp):
    from nanoslam_jax.methods.proposals import PriorProposal

    return PriorProposal()


def _fastslam2(static, params, mp):
    from nanoslam_jax.methods.proposals import LinearizedProposal

    return LinearizedProposal(landmark_noise=True, measurement=params.measurement)


def _ufastslam(static, params, mp):
    from nanoslam_jax.methods.proposals._ufastslam import UnscentedProposal

    return UnscentedProposal(
        alpha=params.ut_alpha, beta=params.ut_beta, kappa=params.ut_kappa, measurement=params.measurement
    )


def _iterated(static, params, mp):
    from nanoslam_jax.methods._method_settings import IteratedStatic, settings_of
    from nanoslam_jax.methods.proposals._iterated import IteratedProposal

    it: IteratedStatic = settings_of(static, IteratedStatic)
    return IteratedProposal(
        solver=it.solver,
        max_iter=it.max_iter,
        tol=it.tol,
        landmark_noise=it.landmark_noise,
        measurement=params.measurement,
    )


def _iterated_static(cfg):
    from nanoslam_jax.methods._method_settings import IteratedStatic

    return IteratedStatic.from_config(cfg)


def _ekf_init(static, params):
    from nanoslam_jax.methods.gaussian._ekf_slam import init_ekf_state

    return init_ekf_state(static, params)


def _ekf_step(static, params, state, seg, valid):
    from nanoslam_jax.methods.gaussian._ekf_slam import ekf_slam_step

    return ekf_slam_step(static, params, state, seg, valid)


def _nasrukf_beams(static) -> bool:
    from nanoslam_jax.methods._method_settings import nasrukf_static

    return nasrukf_static(static).measurement == "beams"


def _nasrukf_static(cfg):
    from nanoslam_jax.methods._method_settings import NasrukfStatic

    return NasrukfStatic.from_config(cfg)


def _nasrukf_traced(cfg):
    from nanoslam_jax.methods._method_settings import NasrukfParams

    return NasrukfParams.from_config(cfg)


def _nasrukf_init(static, params):
    if _nasrukf_beams(static):
        from nanoslam_jax.methods.gaussian._nasrukf_beams_state import init_beam_state

        return init_beam_state(static, params)
    from nanoslam_jax.methods.gaussian._nasrukf_state import init_nasrukf_state

    return init_nasrukf_state(static, params)


def _nasrukf_step(static, params, state, seg, valid):
    if _nasrukf_beams(static):
        from nanoslam_jax.methods.gaussian._nasrukf_beams import beam_step

        return beam_step(static, params, state, seg, valid)
    from nanoslam_jax.methods.gaussian._nasrukf import nasrukf_step

    return nasrukf_step(static, params, state, seg, valid)


# optimistix's least-squares solvers cannot run under shard_map (lineax compares the residual's
# structure with its operator's, whose sharding differs there): such runs stay on one device.
register(Method("dead_reckoning", kind="dead_reckoning", description="the motion model alone"))
register(
    Method(
        "nano",
        proposal=_nano,
        adaptive_noise=True,
        shardable=_nano_shardable,
        section="nano",
        static_settings=_nano_static,
        traced_settings=_nano_traced,
        description="NANO-SLAM: the KL-optimal Gaussian proposal by natural-gradient iteration",
    )
)
register(Method("fastslam1", proposal=_fastslam1, description="FastSLAM 1.0: the prior as proposal"))
register(
    Method(
        "fastslam2", proposal=_fastslam2, adaptive_noise=True, description="FastSLAM 2.0: the linearised (EKF) proposal"
    )
)
register(
    Method(
        "ufastslam",
        proposal=_ufastslam,
        landmark_update="unscented",
        adaptive_noise=True,
        description="Unscented FastSLAM: unscented proposal and landmark updates",
    )
)
register(
    Method(
        "iterated",
        proposal=_iterated,
        shardable=lambda s: False,
        section="iterated",
        static_settings=_iterated_static,
        description="the iterated (Gauss-Newton / Levenberg-Marquardt MAP) proposal",
    )
)
register(Method("ekf_slam", kind="gaussian", init=_ekf_init, step=_ekf_step, description="EKF-SLAM"))
register(
    Method(
        "nasrukf",
        kind="gaussian",
        init=_nasrukf_init,
        step=_nasrukf_step,
        adaptive_noise=True,
        section="nasrukf",
        static_settings=_nasrukf_static,
        traced_settings=_nasrukf_traced,
        description="NASRUKF FastSLAM: adaptive square-root UKF per feature",
    )
)
