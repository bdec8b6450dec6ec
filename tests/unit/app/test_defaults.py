"""One source for every default: the objects the library builds from a configuration default to
what the configuration's own defaults build, so that a default changed in the configuration
reaches every object and no parallel default can drift."""

import dataclasses
import inspect

import jax
import numpy as np
import pytest

from nanoslam_jax.eval import metrics
from nanoslam_jax.app.config import Config, MetricsConfig
from nanoslam_jax.methods import Static
from nanoslam_jax.app.filters import settings_from_config
from nanoslam_jax.app._models import MOTION_MODELS, measurement_model_of, motion_model_of
from nanoslam_jax.models import Ackermann, RangeBearing
from nanoslam_jax.models import VehicleParams


def _leaves_equal(a, b) -> bool:
    la, lb = jax.tree.leaves(a), jax.tree.leaves(b)
    return jax.tree.structure(a) == jax.tree.structure(b) and all(
        np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(la, lb)
    )


@pytest.mark.parametrize("name", sorted(MOTION_MODELS))
def test_motion_models_default_to_the_config(name):
    cls = MOTION_MODELS[name]
    assert _leaves_equal(cls(), motion_model_of(cls, Config()))


def test_range_bearing_defaults_to_the_config():
    assert _leaves_equal(RangeBearing(), measurement_model_of(RangeBearing, Config()))


def test_vehicle_params_default_to_the_config():
    assert _leaves_equal(VehicleParams(), motion_model_of(Ackermann, Config()).vehicle)


def test_static_settings_default_to_the_config():
    static, _ = settings_from_config(Config(), Static().k_max)
    assert Static() == static


def test_a_changed_config_default_reaches_the_models():
    """The models read the configuration's defaults: a non-default section changes them, and the
    class's own defaults stay those of a default configuration."""
    cfg = Config()
    cfg = dataclasses.replace(cfg, noise=dataclasses.replace(cfg.noise, sigma_r=0.25))
    assert float(measurement_model_of(RangeBearing, cfg).sigma_r) == 0.25
    assert float(RangeBearing().sigma_r) == Config().noise.sigma_r != 0.25


def test_metric_defaults_are_the_metrics_section():
    m = MetricsConfig()
    default = lambda f, k: inspect.signature(f).parameters[k].default  # noqa: E731
    assert default(metrics.relative_gps, "rotation_deg") == m.gps_rotation_deg
    assert default(metrics.error_over_time, "rotation_deg") == m.gps_rotation_deg
    assert default(metrics.evaluate, "rotation_deg") == m.gps_rotation_deg
    assert default(metrics.jump_mask, "max_speed") == m.jump_speed
    assert default(metrics.map_quality, "radius") == m.map_radius
