"""Motion models as plug-ins: the built-in unicycle and random walk against closed forms, a model
written in this module against the identical built-in one, the generic unscented prior against
the rate models' fast path, a simulated differential-drive log, and the filter driven scan by
scan against the batch run."""

import math
import subprocess
import sys
import textwrap
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import nanoslam_jax as ns
from nanoslam_jax.app import filters
from nanoslam_jax.app.cli import main as cli_main
from nanoslam_jax.app.config import ConfigError, load_config
from nanoslam_jax.app.experiment import load_log
from nanoslam_jax.methods import LinearisedPrior, UnscentedPrior, predict, run_filter
from nanoslam_jax.app.filters import settings_from_config
from tests.helpers.internals import ut_piece as _ut_piece
from nanoslam_jax.models import AbstractMotionModel, AbstractRateModel, Ackermann, Unicycle
from nanoslam_jax.data import make_segments
from nanoslam_jax.sim.park import simulate, simulate_config


class TestCar(AbstractMotionModel):
    """The Victoria Park car written out here from its equations (controls: encoder speed and
    steering), as a user would write a model: one ``step``, noise on the controls, no fast path."""

    __test__ = False  # not a test class
    control_dim: ClassVar[int] = 2
    noise: ClassVar[str] = "control"
    rigid: ClassVar[bool] = True

    wheelbase: jax.Array = eqx.field(default=2.83, converter=jnp.asarray)
    encoder_offset: jax.Array = eqx.field(default=0.76, converter=jnp.asarray)
    laser_a: jax.Array = eqx.field(default=3.78, converter=jnp.asarray)
    laser_b: jax.Array = eqx.field(default=0.50, converter=jnp.asarray)
    sigma_v: jax.Array = eqx.field(default=2.0, converter=jnp.asarray)
    sigma_alpha: jax.Array = eqx.field(default=math.radians(6.0), converter=jnp.asarray)

    def step(self, x, u, dt):
        ve, alpha = u[0], u[1]
        vc = ve / (1.0 - jnp.tan(alpha) * self.encoder_offset / self.wheelbase)
        w = vc / self.wheelbase * jnp.tan(alpha)
        s, c = jnp.sin(x[2]), jnp.cos(x[2])
        a, b = self.laser_a, self.laser_b
        phi = x[2] + dt * w
        phi = jnp.arctan2(jnp.sin(phi), jnp.cos(phi))
        return jnp.stack([x[0] + dt * (vc * c - w * (a * s + b * c)), x[1] + dt * (vc * s + w * (a * c - b * s)), phi])

    def noise_sqrt(self, dt):
        return jnp.diag(jnp.stack([self.sigma_v, self.sigma_alpha]))


class _ShapeBug(AbstractMotionModel):
    """TestCar's interface with one method returning the wrong shape (``bug`` names which)."""

    __test__ = False
    control_dim: ClassVar[int] = 2
    noise: ClassVar[str] = "control"
    bug: str = eqx.field(static=True, default="")

    def step(self, x, u, dt):
        return x[:2] + dt * u if self.bug == "step" else x + dt * jnp.r_[u, 0.0]

    def noise_sqrt(self, dt):
        return jnp.eye(3) if self.bug == "noise_sqrt" else jnp.eye(2) * dt


@pytest.mark.parametrize(
    "bug, expected, got",
    [("step", "a pose of shape (3,)", "shape (2,)"), ("noise_sqrt", "square root of shape (2, 2)", "shape (3, 3)")],
)
def test_a_model_of_the_wrong_shape_is_named_before_tracing(bug, expected, got):
    cfg = load_config(None, SHORT)
    filters.build(cfg, k_max=4, motion=_ShapeBug())  # the right shapes: accepted
    with pytest.raises(ConfigError) as e:
        filters.build(cfg, k_max=4, motion=_ShapeBug(bug=bug))
    msg = str(e.value)
    assert msg.startswith(f"motion: motion model _ShapeBug.{bug}(") and expected in msg and got in msg
    assert "Traceback" not in msg and len(msg.splitlines()) == 1


def test_a_model_that_raises_on_abstract_inputs_is_named():
    class Indexes(_ShapeBug):
        control_dim: ClassVar[int] = 1

        def step(self, x, u, dt):
            v, w = u.reshape(2)  # written for two controls: u has one
            return x + dt * jnp.stack([v, w, 0.0])

        def noise_sqrt(self, dt):
            return jnp.eye(1)

    with pytest.raises(ConfigError, match=r"motion model Indexes\.step\(x, u, dt\) failed .*u \(1,\).*TypeError"):
        filters.build(load_config(None, SHORT), k_max=4, motion=Indexes())


def test_step_with_segments_of_another_k_max_names_both_values():
    cfg = load_config(None, SHORT)
    segments = make_segments(simulate(cfg.sim, cfg.vehicle), max_range=cfg.data.max_range)
    flt = filters.build(cfg, k_max=segments.k_max + 3)
    row = jax.tree.map(lambda a: a[0], segments)
    with pytest.raises(ConfigError, match=rf"k_max=({segments.k_max + 3}).* holds {segments.k_max} detection slots"):
        flt.step(None, row)
    with pytest.raises(ConfigError, match=r"a whole Segments; pass one row"):
        flt.step(None, segments)


@pytest.mark.slow
def test_unicycle_step_and_jacobians():
    m = Unicycle(sensor_x=0.2, sensor_y=-0.1, sigma_v=0.1, sigma_omega=0.05)
    x, u, dt = jnp.array([1.0, -2.0, 0.7]), jnp.array([0.8, 0.3]), 0.05
    y = m.step(x, u, dt)
    # closed form of the Euler step of the sensor: p' = p + dt (v R e_x + omega R J s)
    c, s = math.cos(0.7), math.sin(0.7)
    ex = np.array([c, s])
    Js = np.array([[c, -s], [s, c]]) @ np.array([0.1, 0.2])  # R(phi) J (0.2, -0.1)
    np.testing.assert_allclose(np.asarray(y[:2]), np.array([1.0, -2.0]) + dt * (0.8 * ex + 0.3 * Js), atol=1e-14)
    assert float(y[2]) == pytest.approx(0.7 + dt * 0.3, abs=1e-14)
    F, G = m.jacobians(x, u, dt)
    eps = 1e-6
    for i in range(3):
        e = jnp.zeros(3).at[i].set(eps)
        np.testing.assert_allclose(
            np.asarray((m.step(x + e, u, dt) - m.step(x - e, u, dt)) / (2 * eps)), np.asarray(F[:, i]), atol=1e-8
        )
    for i in range(2):
        e = jnp.zeros(2).at[i].set(eps)
        np.testing.assert_allclose(
            np.asarray((m.step(x, u + e, dt) - m.step(x, u - e, dt)) / (2 * eps)), np.asarray(G[:, i]), atol=1e-8
        )


@pytest.mark.parametrize("kind", [UnscentedPrior(), LinearisedPrior()], ids=["unscented", "linearized"])
@pytest.mark.slow
def test_random_walk_prior_adds_dt_times_the_noise(kind):
    """With no motion, the prior's mean stays and its covariance grows by dt diag(s_xy^2, s_xy^2, s_phi^2)
    per piece: exactly, for both priors (the model is linear)."""
    _, params = settings_from_config(
        load_config(None, ["model.motion=random_walk", "random_walk.sigma_xy=0.3", "random_walk.sigma_phi_deg=4"]), 4
    )
    x, P = jnp.array([2.0, 1.0, 3.0]), jnp.diag(jnp.array([0.04, 0.01, 0.002]))
    dt = jnp.array([0.1, 0.2, 0.05, 0.0])
    mask = jnp.array([True, True, True, False])
    m, C = predict(x, P, dt, jnp.zeros((4, 2)), mask, params, kind)
    q = 0.35 * np.array([0.3**2, 0.3**2, math.radians(4) ** 2])
    np.testing.assert_allclose(np.asarray(m), np.asarray(x), atol=1e-12)
    np.testing.assert_allclose(np.asarray(C), np.asarray(P) + np.diag(q), atol=1e-12)


@pytest.mark.parametrize("model", [Ackermann(sigma_v=0.7, sigma_alpha=0.05), Unicycle(0.3, 0.1, 0.2, 0.1)])
@pytest.mark.slow
def test_generic_unscented_prior_equals_the_rate_models_fast_path(model):
    """The unscented piece through noisy_step on every sigma point (what a user's model gets)
    equals the fast path of the rate models (rates once per distinct control)."""
    _, params = settings_from_config(load_config(None), 4)
    x, P, u, dt = jnp.array([3.0, -1.0, 2.5]), jnp.diag(jnp.array([0.3, 0.2, 0.01])), jnp.array([2.0, 0.2]), 0.1
    fast = _ut_piece(x, P, u, dt, params._replace(motion=model))
    # the same model seen as a plain AbstractMotionModel: no rates/move split
    plain = _Plain(model)
    generic = _ut_piece(x, P, u, dt, params._replace(motion=plain))
    np.testing.assert_allclose(np.asarray(generic[0]), np.asarray(fast[0]), atol=1e-12)
    np.testing.assert_allclose(np.asarray(generic[1]), np.asarray(fast[1]), atol=1e-12)


class _Plain(AbstractMotionModel):
    inner: AbstractRateModel
    control_dim: ClassVar[int] = 2
    noise: ClassVar[str] = "control"

    def step(self, x, u, dt):
        return self.inner.step(x, u, dt)

    def noise_sqrt(self, dt):
        return self.inner.noise_sqrt(dt)


#: The short simulated run of this module's filter tests: the built-in car's NANO-SLAM program on
#: it is compiled once and shared by them (in this process: the run through the CLI too).
SHORT = ["sim.duration=15", "filter.n_particles=5", "output.plots=false"]


def _short_real_like_config(extra=()):
    return load_config(None, [*SHORT, *extra])


@pytest.mark.slow
def test_model_written_in_a_test_module_equals_the_builtin_car():
    """A user's model passed as an object gives the built-in car's run (to rounding: its step is
    written with other trigonometric functions)."""
    cfg = _short_real_like_config()
    seg = load_log(cfg).segments
    static, params = settings_from_config(cfg, seg.k_max)
    mine = TestCar(sigma_v=params.motion.sigma_v, sigma_alpha=params.motion.sigma_alpha)
    a = run_filter(static, params, seg, 3)
    b = run_filter(static, params._replace(motion=mine), seg, 3)
    np.testing.assert_allclose(np.asarray(b.outputs.best_pose), np.asarray(a.outputs.best_pose), atol=1e-6)


@pytest.mark.slow
def test_model_named_by_import_path_runs_through_the_cli(tmp_path):
    """A model in a file outside the package, named in YAML by import path with its parameters,
    runs through ``nanoslam run`` (a fresh process, as a user runs it) and gives the numbers of
    the built-in car's run (this process)."""
    (tmp_path / "my_robot.py").write_text(
        textwrap.dedent("""
        import math
        from typing import ClassVar
        import equinox as eqx
        import jax.numpy as jnp
        from nanoslam_jax.models import AbstractRateModel, vehicle_move, vehicle_rates, VehicleParams

        class Car(AbstractRateModel):
            control_dim: ClassVar[int] = 2
            sigma_v: object = eqx.field(default=1.0, converter=jnp.asarray)
            sigma_alpha: object = eqx.field(default=0.1, converter=jnp.asarray)

            def rates(self, u):
                return vehicle_rates(u, VehicleParams())

            def move(self, x, r, dt):
                return vehicle_move(x, r, dt, VehicleParams())

            def noise_sqrt(self, dt):
                return jnp.diag(jnp.stack([self.sigma_v, self.sigma_alpha]))
        """)
    )
    common = [*(a for o in SHORT for a in ("--set", o)), "--quiet"]
    env = {**__import__("os").environ, "PYTHONPATH": str(tmp_path)}
    mine = [
        "--set",
        "model.motion=my_robot:Car",
        "--set",
        "model.motion_params.sigma_v=0.5",
        "--set",
        f"model.motion_params.sigma_alpha={math.radians(6.0)}",
    ]
    subprocess.run(
        [sys.executable, "-m", "nanoslam_jax.app.cli", "run", *common, *mine, "--out", str(tmp_path / "mine")],
        check=True,
        env=env,
        capture_output=True,
        text=True,
    )
    assert cli_main(["run", *common, "--out", str(tmp_path / "builtin")]) == 0
    out = {
        name: np.loadtxt(tmp_path / name / "trajectory.csv", delimiter=",", skiprows=1) for name in ("mine", "builtin")
    }
    np.testing.assert_allclose(out["mine"], out["builtin"], atol=2e-6)
    # the TUM export beside it: time x y z qx qy qz qw, heading as a yaw quaternion
    tum = np.loadtxt(tmp_path / "mine" / "trajectory.tum")
    np.testing.assert_allclose(tum[:, [0, 1, 2]], out["mine"][:, :3], atol=2e-6)
    np.testing.assert_allclose(2 * np.arctan2(tum[:, 6], tum[:, 7]), out["mine"][:, 3], atol=1e-6)


def test_bad_model_names_are_config_errors(tmp_path):
    with pytest.raises(ConfigError, match="model.motion"):
        load_config(None, ["model.motion=no_such_model"])
    with pytest.raises(ConfigError, match="model.motion"):
        load_config(None, ["model.motion=json:loads"])  # importable, not a motion model
    with pytest.raises(ConfigError, match="model.motion_params"):
        load_config(None, ["model.motion=unicycle", "model.motion_params.sigma_v=1"])


@pytest.mark.slow
def test_simulated_differential_drive_log_slam_beats_dead_reckoning():
    """The simulator drives a differential-drive robot (logged controls v, omega with noise and a
    turn-rate bias); NANO-SLAM with the unicycle model is at least 5x better than dead reckoning."""
    result = ns.run(
        overrides=[
            "model.motion=unicycle",
            "unicycle.sensor_x=0.3",
            "unicycle.sigma_v=0.5",
            "unicycle.sigma_omega_deg=10",
            "sim.duration=120",
            "sim.sigma_v=0.1",
            "sim.sigma_omega_deg=1",
            "sim.omega_bias_deg=1",
            "output.plots=false",
        ],
        seed=1,
    )
    m = result.metrics
    assert m["dr_rmse_fixed"] > 5.0  # the bias makes dead reckoning drift
    assert m["rmse_fixed"] * 5 <= m["dr_rmse_fixed"], m
    # the logged controls are the unicycle's: integrating the true ones gives the truth
    cfg = load_config(
        None,
        [
            "model.motion=unicycle",
            "unicycle.sensor_x=0.3",
            "sim.duration=30",
            "sim.sigma_v=0",
            "sim.sigma_omega_deg=0",
            "sim.omega_bias_deg=0",
        ],
    )
    raw = simulate_config(cfg)
    model = Unicycle(sensor_x=0.3)
    x = jnp.zeros(3)
    step = jax.jit(lambda x, u, dt: model.step(x, u, dt))
    for k in range(raw.dr.shape[0] - 1):
        x = step(x, jnp.asarray(raw.dr[k, 1:3]), raw.dr[k + 1, 0] - raw.dr[k, 0])
    truth = raw.truth_poses[np.argmin(np.abs(raw.truth_poses[:, 0] - raw.dr[-1, 0]))]
    np.testing.assert_allclose(np.asarray(x), truth[1:], atol=1e-6)


@pytest.mark.parametrize("method", ["nano", "ekf_slam"])
@pytest.mark.slow
def test_stepping_the_built_filter_equals_the_batch_run(method):
    cfg = load_config(None, [*SHORT, f"filter.method={method}"])
    seg = load_log(cfg).segments
    flt = filters.build(cfg, k_max=seg.k_max)
    state = flt.init(jax.random.key(cfg.seed))
    poses = []
    for t in range(seg.n_segments):
        state, out = flt.step(state, jax.tree.map(lambda a: a[t], seg))
        poses.append(np.asarray(out.best_pose))
    batch = run_filter(flt.static, flt.params, seg, cfg.seed)
    np.testing.assert_allclose(np.stack(poses), np.asarray(batch.outputs.best_pose), atol=1e-9)


@pytest.mark.slow
def test_cache_never_serves_a_program_compiled_for_another_model(tmp_path):
    """The same model class name and parameters, its code changed between two runs sharing a
    compilation cache: the second run traces the new code (its trajectory differs), and a third run
    of the unchanged new code is served from the cache with the second's numbers."""
    env = {**__import__("os").environ, "PYTHONPATH": str(tmp_path), "NANOSLAM_CACHE_DIR": str(tmp_path / "cache")}
    source = textwrap.dedent("""
        from typing import ClassVar
        import equinox as eqx
        import jax.numpy as jnp
        from nanoslam_jax.models import Unicycle

        class Robot(Unicycle):
            def rates(self, u):
                return jnp.asarray(u)[:2] * SCALE
        SCALE = {scale}
        """)
    args = [
        "--set",
        "model.motion=robot_model:Robot",
        "--set",
        "sim.duration=15",
        "--set",
        "filter.n_particles=3",
        "--set",
        "output.plots=false",
        "--quiet",
    ]
    paths = []
    for i, scale in enumerate((1.0, 1.05, 1.05)):
        (tmp_path / "robot_model.py").write_text(source.format(scale=scale))
        out = tmp_path / f"run{i}"
        subprocess.run(
            [sys.executable, "-m", "nanoslam_jax.app.cli", "run", *args, "--out", str(out)],
            check=True,
            env=env,
            capture_output=True,
            text=True,
        )
        paths.append(np.loadtxt(out / "trajectory.csv", delimiter=",", skiprows=1))
    assert np.abs(paths[1] - paths[0]).max() > 1e-3  # the changed code ran
    np.testing.assert_array_equal(paths[2], paths[1])
    assert len(list((tmp_path / "cache" / "exported").glob("*.bin"))) >= 2
