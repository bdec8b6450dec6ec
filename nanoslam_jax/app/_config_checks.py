"""The consistency checks of a run configuration: the rules that tie keys of different sections.

Each check takes a :class:`~nanoslam_jax.app.config.Config` whose keys are each valid on their own
and returns the message of the first rule it breaks (naming the key, without the file), or
``None``. :data:`CHECKS` lists them in the order :func:`nanoslam_jax.app.config.config_from_dict`
applies them; the first message found is the error.
"""

from __future__ import annotations

from collections.abc import Callable

from nanoslam_jax.app._config_schema import Config

__all__ = ["CHECKS", "Check"]

#: A consistency check: the message of the rule a config breaks, or ``None``.
Check = Callable[[Config], str | None]

_LASER_VALUES = "laser, laser_lines, laser_beams, laser_circles, laser_features"


def _check_log_format(cfg: Config) -> str | None:
    """The range limits, and the detections, motion model and reference path a log format allows."""
    d = cfg.data
    if d.min_range >= d.max_range:
        return f"key 'data.min_range': expected a value < data.max_range ({d.max_range}), got {d.min_range}"
    if d.kind == "victoria_park" and d.format == "mrclam":
        if d.detections != "file":
            return (
                "key 'data.detections': an MRCLAM log has no laser scans, only its sightings; "
                f"expected 'file' with data.format mrclam, got {d.detections!r}"
            )
        if cfg.model.motion == "ackermann":
            return (
                "key 'model.motion': an MRCLAM log's odometry is (v, omega) of a differential-drive "
                "robot, not the car's (speed, steering); expected unicycle (or odometry, random_walk, or your "
                "own model) with data.format mrclam, got 'ackermann'"
            )
    if d.format == "carmen" and d.detections == "file":
        return (
            "key 'data.detections': a CARMEN log holds laser scans, no detections; expected one of "
            f"{_LASER_VALUES} with data.format carmen, got 'file'"
        )
    if d.format == "carmen" and cfg.model.motion == "ackermann":
        return (
            "key 'model.motion': a CARMEN log's odometry becomes (v, omega) controls of a "
            "differential-drive robot or pose increments; expected unicycle or odometry (or random_walk, or "
            "your own model) with data.format carmen, got 'ackermann'"
        )
    if d.reference is not None and d.format not in ("carmen", "rosbag"):
        return "key 'data.reference': a reference path is scored with data.format carmen or rosbag only"
    if d.kind == "victoria_park" and d.format == "rosbag" and d.detections == "file":
        return (
            "key 'data.detections': a ROS bag holds laser scans, not detections; expected one of the "
            "laser values (laser_lines, laser_beams, laser_circles, laser_features, laser) with data.format rosbag"
        )
    return None


def _check_detections_measurement(cfg: Config) -> str | None:
    """The measurement model each kind of laser detection needs, and the logs that have raw scans."""
    d, measurement = cfg.data, cfg.model.measurement
    lines_in = d.detections == "laser_lines"
    if lines_in and measurement != "line":
        return (
            "key 'model.measurement': data.detections laser_lines gives line segments "
            f"(rho, alpha); expected 'line', got {measurement!r}"
        )
    if measurement == "line" and not lines_in and (d.kind == "indoor" or d.detections == "laser"):
        return (
            "key 'data.detections': model.measurement line takes line segments; expected "
            f"'laser_lines' with data.kind {d.kind!r}, got {d.detections!r}"
        )
    circles_in = d.detections == "laser_circles"
    if circles_in != (measurement == "circle") and (circles_in or d.kind == "indoor"):
        return (
            "key 'model.measurement': data.detections laser_circles gives circles (range, bearing, "
            f"radius) and model.measurement circle takes them; got data.detections {d.detections!r} with "
            f"model.measurement {measurement!r}"
        )
    features_in = d.detections == "laser_features"
    if features_in != (measurement == "line+circle") and (features_in or d.kind == "indoor"):
        return (
            "key 'model.measurement': data.detections laser_features gives line segments and circles "
            "with their types and model.measurement line+circle takes them; got data.detections "
            f"{d.detections!r} with model.measurement {measurement!r}"
        )
    if "+" in measurement and cfg.noise.adaptive:
        return (
            "key 'noise.adaptive': the adaptive noise estimate is of one detection type; a map of several "
            f"types (model.measurement {measurement!r}) takes each type's configured noise"
        )
    if (lines_in or circles_in or features_in) and d.kind in ("simulated", "city"):
        return (
            f"key 'data.detections': the simulated {'park' if d.kind == 'simulated' else 'city'} log has "
            f"no raw scans; expected 'file' with data.kind {d.kind} (or data.kind indoor for line segments and "
            f"circles), got {d.detections!r}"
        )
    return None


def _check_map_management(cfg: Config) -> str | None:
    """The order of the detection rates and existence probabilities of landmark management."""
    mp = cfg.map
    if not mp.manage:
        return None
    if mp.p_false >= mp.p_detect:
        return f"key 'map.p_false': expected a value < map.p_detect ({mp.p_detect}), got {mp.p_false}"
    if not mp.remove_probability < mp.birth_probability <= mp.max_probability:
        return (
            "key 'map.birth_probability': expected map.remove_probability "
            f"({mp.remove_probability}) < map.birth_probability <= map.max_probability "
            f"({mp.max_probability}), got {mp.birth_probability}"
        )
    if not mp.confirm_probability <= mp.max_probability:
        return (
            "key 'map.confirm_probability': expected a value <= map.max_probability "
            f"({mp.max_probability}), got {mp.confirm_probability}"
        )
    return None


def _check_simulated_worlds(cfg: Config) -> str | None:
    """The ranges of the simulated indoor world and the city's turn radius."""
    ind, cty = cfg.indoor, cfg.city
    if ind.speed_min > ind.speed_max:
        return f"key 'indoor.speed_min': expected a value <= indoor.speed_max ({ind.speed_max}), got {ind.speed_min}"
    if ind.pillar_radius_min > ind.pillar_radius_max:
        return (
            "key 'indoor.pillar_radius_min': expected a value <= indoor.pillar_radius_max "
            f"({ind.pillar_radius_max}), got {ind.pillar_radius_min}"
        )
    if cty.turn_radius > 0.5 * cty.street_width + 0.25 * cty.block_size:
        return (
            "key 'city.turn_radius': expected a value <= city.street_width / 2 + city.block_size / 4 "
            f"({0.5 * cty.street_width + 0.25 * cty.block_size:g}), got {cty.turn_radius}"
        )
    return None


def _check_forgetting(cfg: Config) -> str | None:
    """The forgetting factors of the adaptive noise estimates (below 1)."""
    if cfg.noise.forgetting >= 1.0:
        return f"key 'noise.forgetting': expected a value < 1, got {cfg.noise.forgetting}"
    if cfg.nasrukf.process_forgetting >= 1.0:
        return f"key 'nasrukf.process_forgetting': expected a value < 1, got {cfg.nasrukf.process_forgetting}"
    return None


def _check_nasrukf(cfg: Config) -> str | None:
    """Per-beam measurements (laser_beams with NASRUKF's beams), and NASRUKF's own adaptive process noise."""
    d, method = cfg.data, cfg.filter.method
    beams_in, beams_filter = d.detections == "laser_beams", cfg.nasrukf.measurement == "beams"
    if beams_in and not (beams_filter and method == "nasrukf"):
        return (
            "key 'data.detections': laser_beams gives one range per beam, which only NASRUKF's "
            "per-beam measurement takes; expected filter.method nasrukf with nasrukf.measurement beams, got "
            f"filter.method {method!r} and nasrukf.measurement {cfg.nasrukf.measurement!r}"
        )
    if beams_filter and method == "nasrukf" and not beams_in:
        return (
            "key 'nasrukf.measurement': 'beams' measures line and arc features beam by beam; expected "
            f"data.detections laser_beams (raw scans), got {d.detections!r}"
        )
    if beams_in and d.kind in ("simulated", "city"):
        return (
            f"key 'data.detections': the simulated {'park' if d.kind == 'simulated' else 'city'} log has "
            "no raw scans; expected data.kind indoor "
            "(or a log directory with raw scans) for laser_beams"
        )
    if cfg.nasrukf.adaptive_process and method != "nasrukf":
        return (
            "key 'nasrukf.adaptive_process': the adaptive process-noise estimate is "
            f"NASRUKF's, not filter.method {method!r}'s; set it to false or use nasrukf"
        )
    return None


def _check_method(cfg: Config) -> str | None:
    """The filter method is registered, takes its parameters, and has the noise estimate and the
    estimate (and so the smoother) the config asks of it."""
    from nanoslam_jax.app.registry import get_method, method_names

    try:
        method = get_method(cfg.filter.method)
        method.method_params(cfg.filter.method_params)
    except ValueError as e:
        return str(e)
    if cfg.noise.adaptive and not method.adaptive_noise:
        adaptive = [m for m in method_names() if get_method(m).adaptive_noise]
        return (
            "key 'noise.adaptive': the adaptive noise estimate is available for "
            f"filter.method {', '.join(adaptive)}, not {cfg.filter.method!r}; "
            "set noise.adaptive to false"
        )
    if cfg.filter.estimate == "path" and method.kind != "particle":
        return (
            "key 'filter.estimate': 'path' follows the particles' ancestry; filter.method "
            f"{cfg.filter.method!r} has no particles; use best (or mean)"
        )
    if cfg.smoother.enabled and cfg.filter.estimate != "path":
        return (
            "key 'smoother.enabled': the smoother starts from the final best particle's "
            "ancestral path, which a run records only with filter.estimate: path (got "
            f"{cfg.filter.estimate!r}); set filter.estimate to path"
        )
    return None


def _check_models(cfg: Config) -> str | None:
    """The motion and measurement models load, take their parameters, and suit the filter method."""
    from nanoslam_jax.app._models import (
        has_own_section,
        measurement_model_class,
        measurement_model_of,
        motion_model_class,
        motion_model_of,
    )
    from nanoslam_jax.models import Composite, check_measurement_model

    try:
        motion = motion_model_class(cfg.model.motion)
        if cfg.model.motion_params and has_own_section(motion):
            return (
                f"key 'model.motion_params': the built-in model {cfg.model.motion!r} takes its "
                f"parameters from its own section; model.motion_params is for a model named by import path"
            )
        motion_model_of(motion, cfg)
        measurement = measurement_model_class(cfg.model.measurement)
        if (
            cfg.model.measurement_params
            and has_own_section(measurement)
            and not issubclass(measurement, Composite)  # one mapping of parameters per type
        ):
            return (
                f"key 'model.measurement_params': the built-in model {cfg.model.measurement!r} takes "
                "its parameters from its own sections; model.measurement_params is for a model named "
                "by import path"
            )
        measurement_model_of(measurement, cfg)
        check_measurement_model(measurement, cfg.filter.method, cfg.smoother.enabled)
    except ValueError as e:
        return str(e)
    return None


def _check_gates(cfg: Config) -> str | None:
    """The new-landmark threshold is at least the association gate."""
    if cfg.filter.new_landmark < cfg.filter.gate:
        return (
            f"key 'filter.new_landmark': expected a value >= filter.gate ({cfg.filter.gate}), "
            f"got {cfg.filter.new_landmark}"
        )
    return None


#: The consistency checks, in the order they apply.
CHECKS: tuple[Check, ...] = (
    _check_log_format,
    _check_detections_measurement,
    _check_map_management,
    _check_simulated_worlds,
    _check_forgetting,
    _check_nasrukf,
    _check_method,
    _check_models,
    _check_gates,
)
