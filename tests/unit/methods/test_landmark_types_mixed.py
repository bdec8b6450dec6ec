"""Several landmark types in one map (a :class:`~nanoslam_jax.models.Composite` measurement
model): association only within a type, a composite of one type equal to its plain model, and walls
and pillars mapped together from a simulated indoor log against the simulator's truth."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nanoslam_jax.app.config import ConfigError, load_config
from nanoslam_jax.app.experiment import execute, load_log, map_columns
from nanoslam_jax.methods import reported_map, run_filter
from nanoslam_jax.app.filters import settings_from_config
from nanoslam_jax.methods.maps._association import Gating, ScanDetections, associate
from nanoslam_jax.methods.gaussian._joint_gaussian import association_distances
from nanoslam_jax.methods._state import LandmarkMap
from nanoslam_jax.models import PAD_VARIANCE, Circle, Composite, LineSegment

LINE_CIRCLE = Composite((LineSegment(), Circle()), ("line", "circle"))

#: The settings of the indoor runs: the front end's segments and arcs of a simulated room.
SENSOR = "min_range: 0.2, max_range: 9.5, half_fov: 1.4835"
INDOOR = [
    "detector.circle_max_radius=0.5",
    "indoor.pillars=3",
    "indoor.duration=60",
    "indoor.seed=1",
    "filter.n_particles=20",
    "output.plots=false",
    "output.progress=false",
]


def _local_map(means, kinds):
    lm = LandmarkMap.empty(4, dim=3, kinds=True)
    n = len(means)
    return lm._replace(
        mean=lm.mean.at[:n].set(jnp.asarray(means, float)),
        cov=lm.cov.at[:n].set(0.01 * jnp.eye(3)),
        active=lm.active.at[:n].set(True),
        kind=lm.kind.at[:n].set(jnp.asarray(kinds, jnp.int32)),
    )


@pytest.mark.slow
@pytest.mark.parametrize("sequential", [True, False])
def test_a_detection_is_never_associated_with_a_landmark_of_another_type(sequential):
    """A circle detection whose values equal a line landmark's prediction exactly (and are far from
    the circle landmark's) matches no landmark; a line detection equal to the same prediction
    matches the line."""
    x, P = jnp.array([0.0, 0.0, 0.0]), 1e-6 * jnp.eye(3)
    line = [2.0, 0.3, 0.0]  # a wall 2 m away, its normal at 0.3 rad
    circle = [-3.0, 4.0, 0.2]  # a pillar far from the line's values
    local = _local_map([line, circle], [0, 1])
    z_line = LINE_CIRCLE.of_kind(0).h(x, jnp.asarray(line))
    z = jnp.stack([z_line, z_line])
    dets = ScanDetections(z, jnp.array([True, True]), kind=jnp.array([1, 0]))
    # A gate that takes anything of the right type.
    gating = Gating(jnp.asarray(1e6), jnp.asarray(1e7), sequential)
    assoc = jax.jit(associate)(local, x, P, dets, LINE_CIRCLE.noise_cov(), gating, LINE_CIRCLE)
    slot = np.asarray(assoc.slot)
    assert slot[0] != 0  # the circle detection does not take the line
    assert slot[1] == 0 and float(assoc.d2[1]) < 1e-9  # the line detection does

    # EKF-SLAM: a slot of another type is at infinite distance.
    mean = jnp.concatenate([x, jnp.asarray(line), jnp.asarray(circle)])
    cov = jnp.eye(9) * 0.01
    d2 = association_distances(
        mean, cov, z_line, LINE_CIRCLE.noise_cov(), jnp.array([True, True]), 0.0, LINE_CIRCLE, (local.kind[:2], 1)
    )
    assert np.isinf(d2[0]) and np.isfinite(d2[1])


def test_padding_adds_nothing_to_a_detection():
    """A line's padded third value: zero innovation, zero Jacobian rows and columns, the padding's
    noise of unit density, and a new landmark's padding started with that noise."""
    x = jnp.array([0.5, -0.2, 0.1])
    m = jnp.array([2.0, 0.3, 0.0])
    line = LINE_CIRCLE.of_kind(0)
    Gx, Gm = jax.jit(lambda x, m: line.jacobians(x, m))(x, m)
    assert np.all(np.asarray(Gx)[2] == 0) and np.all(np.asarray(Gm)[2] == 0) and np.all(np.asarray(Gm)[:, 2] == 0)
    R = np.asarray(line.noise_cov())
    np.testing.assert_allclose(R[:2, :2], LineSegment().noise_cov())
    assert R[2, 2] == PAD_VARIANCE and -0.5 * np.log(2 * np.pi * R[2, 2]) == pytest.approx(0.0, abs=1e-15)
    np.testing.assert_allclose(np.asarray(line.h(x, m))[:2], LineSegment().h(x, m[:2]))
    assert float(line.h(x, m)[2]) == 0.0


def _circle_log(method):
    cfg = load_config(
        "configs/indoor_lines.yaml",
        INDOOR
        + [
            "data.detections=laser_circles",
            "model.measurement=circle",
            "model.measurement_params={sigma_r: 0.02, sigma_beta: 0.01, sigma_radius: 0.02, " + SENSOR + "}",
            "data.k_max=8",
            "indoor.duration=30",
            f"filter.method={method}",
        ],
    )
    return cfg, load_log(cfg)


@pytest.mark.slow
@pytest.mark.parametrize("method", ["ekf_slam", "fastslam2"])
def test_a_composite_of_one_type_gives_the_run_of_its_model(method):
    cfg, log = _circle_log(method)
    static, params = settings_from_config(cfg, log.segments.k_max)
    plain = run_filter(static, params, log.segments, 0)
    composite = Composite((params.measurement,), ("circle",))
    run = run_filter(static, params._replace(measurement=composite), log.segments, 0)
    np.testing.assert_array_equal(run.outputs.n_new, plain.outputs.n_new)
    np.testing.assert_allclose(run.outputs.best_pose, plain.outputs.best_pose, atol=1e-9)
    a, b = reported_map(run.state), reported_map(plain.state)
    act = np.asarray(b.active)
    assert act.sum() >= 3
    np.testing.assert_array_equal(a.active, act)
    np.testing.assert_allclose(np.asarray(a.mean)[act], np.asarray(b.mean)[act], atol=1e-9)
    np.testing.assert_allclose(np.asarray(a.cov)[act], np.asarray(b.cov)[act], atol=1e-12)
    assert np.all(np.asarray(a.kind)[act] == 0)


@pytest.mark.slow
@pytest.mark.parametrize("method", ["ekf_slam", "fastslam2"])
def test_walls_and_pillars_in_one_map_match_the_truth(method):
    """The front end's segments and arcs of a simulated room with three pillars, with their types, in
    one map of lines and circles: every true wall and pillar is mapped (the second paper's Table 1
    against the simulator's truth)."""
    overrides = INDOOR + [
        "data.detections=laser_features",
        "model.measurement=line+circle",
        "model.measurement_params={line: {sigma_rho: 0.01, sigma_alpha: 0.005, " + SENSOR + "}, "
        "circle: {sigma_r: 0.02, sigma_beta: 0.01, sigma_radius: 0.02, " + SENSOR + "}}",
        "data.k_max=16",
        f"filter.method={method}",
    ]
    res = execute(load_config("configs/indoor_lines.yaml", overrides))
    m = res.metrics
    assert m["n_lines_matched"] == m["n_lines"] >= 4 and m["n_arcs_matched"] == m["n_arcs"] == 3, m
    assert m["line_rho_worst"] < 0.02 and m["line_alpha_worst"] < 0.01 and m["corner_worst"] < 0.05, m
    assert m["arc_centre_worst"] < 0.05 and m["arc_radius_worst"] < 0.01, m
    assert m["rmse_heading_deg"] < 0.5 * m["dr_rmse_heading_deg"], m
    cols = map_columns(3, kinds=True)
    kinds = res.landmarks[:, cols.index("kind")]
    assert set(np.unique(kinds)) == {0.0, 1.0}
    # A line's padded third value stays 0.
    np.testing.assert_array_equal(res.landmarks[kinds == 0, 2], 0.0)


@pytest.mark.parametrize(
    "overrides, match",
    [
        (["model.measurement=line"], "data.detections.*laser_lines"),
        (["filter.method=ufastslam"], "model.measurement.*not with ufastslam"),
        (["model.measurement_params={line: {sigma_r: 1}}"], r"model.measurement_params\.line.*sigma_r"),
        (["model.measurement_params={arc: {sigma_r: 1}}"], "model.measurement_params.*one mapping per type"),
        (["noise.adaptive=true"], "noise.adaptive"),
    ],
)
def test_a_map_of_several_types_refuses_what_it_cannot_run_naming_the_key(overrides, match):
    base = ["data.kind=indoor", "data.detections=laser_features", "model.measurement=line+circle"]
    with pytest.raises(ConfigError, match=match):
        load_config(None, base + overrides)
    with pytest.raises(ConfigError, match="model.measurement.*'arc' is not a built-in"):
        load_config(None, ["model.measurement=line+arc"])
    cfg = load_config(None, base + ["model.measurement_params={circle: {sigma_radius: 0.05}}"])
    _, params = settings_from_config(cfg, 4)
    assert isinstance(params.measurement, Composite) and params.measurement.names == ("line", "circle")
    assert float(params.measurement.types[1].sigma_radius) == 0.05
