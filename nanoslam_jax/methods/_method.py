"""A SLAM method as an object: what the scan driver runs for it.

A :class:`Method` says how a method is built and run: for a particle method its proposal (the
Gaussian over the pose each particle samples from; the shared Rao-Blackwellised step does the
rest: association, landmark updates, weights, management, resampling), for a Gaussian method its
own ``init`` and ``step``. The filter's :class:`~nanoslam_jax.methods.Static` holds the method
object itself, so the driver calls its parts directly; the names a configuration uses
(``filter.method``) are the application's registry (:mod:`nanoslam_jax.app.registry`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Hashable, Mapping
from typing import Any, Literal, Optional

from nanoslam_jax.methods.maps._updates import AbstractLandmarkUpdate, EkfLandmarkUpdate

__all__ = ["Method", "METHOD_KINDS"]

#: What a method is: a particle filter with its own proposal, a Gaussian filter with its own state
#: and step, or the motion model alone.
METHOD_KINDS = ("particle", "gaussian", "dead_reckoning")


def _always(static: Any) -> bool:
    return True


@dataclasses.dataclass(frozen=True, repr=False)
class Method:
    """A method: its parts, and how a configuration reaches its settings.

    Two methods are equal when their parts are (name, kind, proposal, init, step, landmark update,
    shardability, adaptive noise); the fields that only say how its settings are read from a
    configuration and described do not enter the comparison (nor the hash).

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
        landmark_update: how a particle method starts and updates its landmarks, an
            :class:`~nanoslam_jax.methods.AbstractLandmarkUpdate`: the EKF
            (:class:`~nanoslam_jax.methods.EkfLandmarkUpdate`) or the unscented transform
            (:class:`~nanoslam_jax.methods.UnscentedLandmarkUpdate`).
        shardable: ``shardable(static) -> bool``: whether its per-particle work may be split over
            devices (``shard_map``), given the static settings (its own in
            ``static.method_settings``).
        adaptive_noise: it offers the adaptive measurement-noise estimate (``noise.adaptive``).
        static_default: its static settings when none are given (``Static.method_settings``): a
            hashable value such as a frozen dataclass, or None for a method without.
        defaults: its traced parameters and their defaults (``filter.method_params`` overrides
            them; unknown names are refused), for a method without :attr:`traced_settings`.
        description: one line for the config reference and error messages.
        section: the config section its settings are read from (``"nano"``, ``"iterated"``,
            ``"nasrukf"``), None for none.
        static_settings: ``static_settings(cfg) -> settings``: its static settings from a run
            configuration, a hashable value (a frozen dataclass) kept in
            ``Static.method_settings``; changing them recompiles. It must not compute with JAX
            (it runs before the devices are set up). None: it has none, or the application
            knows how to read them (the built-in methods).
        traced_settings: ``traced_settings(cfg) -> settings``: its traced hyperparameters from a
            run configuration, a pytree of scalar arrays (a NamedTuple) kept in ``Params.method``
            and passed to :attr:`proposal`; a sweep over them compiles once. None: the mapping of
            :attr:`defaults` updated by ``filter.method_params``, as traced scalars (a dict).
    """

    name: str
    kind: Literal["particle", "gaussian", "dead_reckoning"] = "particle"
    proposal: Optional[Callable[..., Any]] = None
    init: Optional[Callable[..., Any]] = None
    step: Optional[Callable[..., Any]] = None
    landmark_update: AbstractLandmarkUpdate = EkfLandmarkUpdate()
    shardable: Callable[[Any], bool] = _always
    adaptive_noise: bool = False
    static_default: Hashable = dataclasses.field(default=None, compare=False)
    defaults: Mapping[str, float] = dataclasses.field(default_factory=dict, compare=False)
    description: str = dataclasses.field(default="", compare=False)
    section: Optional[str] = dataclasses.field(default=None, compare=False)
    static_settings: Optional[Callable[[Any], Hashable]] = dataclasses.field(default=None, compare=False)
    traced_settings: Optional[Callable[[Any], Any]] = dataclasses.field(default=None, compare=False)

    def __post_init__(self):
        if self.kind not in METHOD_KINDS:
            raise ValueError(f"Method {self.name!r}: kind must be one of {', '.join(METHOD_KINDS)}, got {self.kind!r}")
        if self.kind == "particle" and self.proposal is None:
            raise ValueError(f"Method {self.name!r}: a particle method needs a proposal")
        if self.kind == "gaussian" and (self.init is None or self.step is None):
            raise ValueError(f"Method {self.name!r}: a Gaussian method needs init and step")
        if not isinstance(self.landmark_update, AbstractLandmarkUpdate):
            raise TypeError(
                f"Method {self.name!r}: landmark_update must be an AbstractLandmarkUpdate "
                f"(EkfLandmarkUpdate() or UnscentedLandmarkUpdate()), got {self.landmark_update!r}"
            )

    def __repr__(self) -> str:
        return f"Method({self.name!r}, kind={self.kind!r})"

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
