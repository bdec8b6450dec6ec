"""The filter as a pair of functions a user drives: :func:`build` gives a :class:`Filter` with
``init(key)`` and ``step(state, segment)``.

``step`` is the step the batch run scans over the log (``filter_scan``), jit-compiled on its own:
calling it segment by segment from a robot's loop gives the batch run's numbers.

Example::

    import jax
    import nanoslam_jax as ns
    from nanoslam_jax.data import make_segments
    from nanoslam_jax.sim.park import simulate

    cfg = ns.load_config(None, ["sim.duration=30"])
    raw = simulate(cfg.sim, cfg.vehicle)
    segments = make_segments(raw, max_range=cfg.data.max_range)
    flt = ns.filters.build(cfg, k_max=segments.k_max)
    state = flt.init(jax.random.key(cfg.seed))
    for t in range(segments.n_segments):
        state, out = flt.step(state, jax.tree.map(lambda a: a[t], segments))
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple, Optional, Union

import jax
import jax.numpy as jnp
from jaxtyping import Array, Key

from nanoslam_jax.app.config import Config, ConfigError, apply_overrides, config_from_dict, config_to_dict, load_config
from nanoslam_jax.data import Segments
from nanoslam_jax.methods._params import Params, Static
from nanoslam_jax.app._build import method_static as method_static, settings_from_config as settings_from_config
from nanoslam_jax.methods.particle._prior import relative_prior
from nanoslam_jax.methods._scan import _check_filter_method, _masked_step, initial_state, is_gaussian
from nanoslam_jax.lib._precision import require_float64
from nanoslam_jax.models import (
    AbstractMeasurementModel,
    AbstractMotionModel,
    check_measurement_model,
    check_motion_model,
)

__all__ = ["Filter", "build"]


class Filter(NamedTuple):
    """A built filter.

    Attributes:
        static: the settings that fix shapes and program structure.
        params: the traced hyperparameters, the motion and measurement models among them
            (``params.motion``, ``params.measurement``).
        init: ``init(key) -> state``: the state a run starts from (a particle filter's, which
            carries ``key`` on, or a Gaussian method's, EKF-SLAM's or NASRUKF's, a
            :class:`~nanoslam_jax.methods.GaussianState` that does not use it), jit-compiled.
        step: ``step(state, segment) -> (state, output)``: one segment of the log (a row of
            :class:`~nanoslam_jax.data.Segments`, without the leading axis), jit-compiled; the
            output holds the segment's estimates and diagnostics.
    """

    static: Static
    params: Params
    init: Callable[[Key[Array, ""]], Any]
    step: Callable[[Any, Segments], tuple[Any, Any]]


@functools.partial(jax.jit, static_argnames=("static",))
def _init(static: Static, params: Params, key):
    return initial_state(static, params, key)


@functools.partial(jax.jit, static_argnames=("static",))
def _step(static: Static, params: Params, state, segment: Segments):
    rel = None
    if not is_gaussian(static.method) and static.prior.reset and params.motion.rigid:
        rel = relative_prior(segment.dt, segment.u, segment.dr_mask, params, static.prior)
    return _masked_step(static, params, state, (segment, jnp.asarray(True), rel))


def build(
    config: Union[Config, str, None] = None,
    *,
    k_max: int,
    method: Optional[str] = None,
    motion: Optional[AbstractMotionModel] = None,
    measurement: Optional[AbstractMeasurementModel] = None,
    n_particles: Optional[int] = None,
    capacity: Optional[int] = None,
    overrides: Sequence[str] = (),
) -> Filter:
    """Build a filter from a configuration, with the most common settings as arguments.

    Args:
        config: a :class:`~nanoslam_jax.Config`, the path of a YAML config, or None (the embedded
            default).
        k_max: detections per segment (the ``k_max`` of the segments the filter will be fed).
        method: ``filter.method`` (e.g. ``"nano"``, ``"fastslam2"``, ``"ekf_slam"``).
        motion: a motion model object (an :class:`~nanoslam_jax.models.AbstractMotionModel`
            with its parameters) instead of the one ``model.motion`` names.
        measurement: a measurement model object (an
            :class:`~nanoslam_jax.models.AbstractMeasurementModel` with its parameters) instead of
            the one ``model.measurement`` names.
        n_particles: ``filter.n_particles``.
        capacity: ``filter.capacity`` (landmark slots per particle).
        overrides: other ``key=value`` settings, as ``--set`` takes them.

    Returns:
        The :class:`Filter`; its ``step`` compiles on the first call.
    """
    require_float64("nanoslam_jax.app.filters.build")
    sets = list(overrides)
    if method is not None:
        sets.append(f"filter.method={method}")
    if n_particles is not None:
        sets.append(f"filter.n_particles={n_particles}")
    if capacity is not None:
        sets.append(f"filter.capacity={capacity}")
    if isinstance(config, Config):
        cfg = config_from_dict(apply_overrides(config_to_dict(config), sets), source="build") if sets else config
    else:
        cfg = load_config(config, sets)
    static, params = settings_from_config(cfg, k_max)
    if motion is not None:
        if not isinstance(motion, AbstractMotionModel):
            raise TypeError(f"motion: expected a nanoslam_jax.models.AbstractMotionModel, got {type(motion).__name__}")
        try:
            check_motion_model(motion)
        except ValueError as e:
            raise ConfigError(f"motion: {e}") from None
        params = params._replace(motion=motion)
    if measurement is not None:
        if not isinstance(measurement, AbstractMeasurementModel):
            raise TypeError(
                f"measurement: expected a nanoslam_jax.models.AbstractMeasurementModel, got "
                f"{type(measurement).__name__}"
            )
        try:
            check_measurement_model(measurement, static.method.name, cfg.smoother.enabled)
        except ValueError as e:
            raise ConfigError(str(e)) from None
        params = params._replace(measurement=measurement)
    _check_filter_method(static)
    static = dataclasses.replace(static, devices=1)
    compiled = functools.partial(_step, static, params)

    def step(state, segment: Segments):
        got = tuple(jnp.shape(segment.z_mask))
        if got != (static.k_max,):
            extra = " (a whole Segments; pass one row, jax.tree.map(lambda a: a[t], segments))" if len(got) > 1 else ""
            raise ConfigError(
                f"k_max: the filter was built with k_max={static.k_max}, and the segment holds "
                f"{got[-1] if got else 0} detection slots (z_mask of shape {got}){extra}; build it with "
                "k_max=segments.k_max"
            )
        return compiled(state, segment)

    return Filter(static=static, params=params, init=functools.partial(_init, static, params), step=step)
