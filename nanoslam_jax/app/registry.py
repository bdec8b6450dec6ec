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
import functools
import importlib
from collections.abc import Hashable
from typing import TYPE_CHECKING, Any

import jax.numpy as jnp

from nanoslam_jax.methods import METHOD_KINDS, Method
from nanoslam_jax.methods import _builtin as builtin

if TYPE_CHECKING:
    from nanoslam_jax.app.config import Config

__all__ = ["Method", "register", "get_method", "method_names", "METHOD_KINDS", "static_of", "traced_of"]


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


def static_of(method: Method, cfg: "Config") -> Hashable:
    """The static settings of ``method`` under ``cfg`` (:attr:`Method.static_settings`; None when it
    has none)."""
    return None if method.static_settings is None else method.static_settings(cfg)


def traced_of(method: Method, cfg: "Config") -> Any:
    """The traced hyperparameters of ``method`` under ``cfg`` (:attr:`Method.traced_settings`;
    without, the dict of :meth:`Method.method_params` of ``filter.method_params`` as float arrays)."""
    if method.traced_settings is not None:
        return method.traced_settings(cfg)
    return {k: jnp.asarray(v, dtype=float) for k, v in method.method_params(cfg.filter.method_params).items()}


# --------------------------------------------------------------------------- the built-in methods' settings


def section_static(section: str, cfg: "Config") -> Hashable:
    """A built-in method's static settings: ``static()`` of its section of ``cfg``."""
    return getattr(cfg, section).static()


def section_traced(section: str, cfg: "Config") -> Any:
    """A built-in method's traced hyperparameters: ``params()`` of its section of ``cfg``."""
    return getattr(cfg, section).params()


for _m in builtin.BUILTIN_METHODS:  # a built-in method with a section reads it (NanoConfig, ...)
    if _m.section is not None:
        _m = dataclasses.replace(
            _m,
            static_settings=functools.partial(section_static, _m.section),
            traced_settings=functools.partial(section_traced, _m.section),
        )
    register(_m)
