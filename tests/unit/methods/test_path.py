"""``filter.estimate: path``: the final best particle's ancestral path.

The reference is the other way of keeping a particle's path, FastSLAM's textbook one: every
particle carries its whole history forward and resampling copies the histories. Following the
recorded ancestor indices back from the end must give exactly the history carried forward.
"""

import dataclasses

import jax
import numpy as np
import pytest

from nanoslam_jax.app.config import ConfigError, load_config
from nanoslam_jax.app.experiment import load_log
from nanoslam_jax.methods import AncestralPath, BestParticle, WeightedMean, ancestral_path, run_filter
from nanoslam_jax.app.filters import settings_from_config


def carried_forward(poses: np.ndarray, ancestors: np.ndarray, final: int) -> np.ndarray:
    """Each particle's history carried forward step by step, histories copied at resampling."""
    n = poses.shape[1]
    history = [[] for _ in range(n)]  # after the previous step, per particle
    for pose, parents in zip(poses, ancestors):
        before = [history[i] + [pose[i]] for i in range(n)]  # the proposal extends every path
        history = [list(before[parents[j]]) for j in range(n)]  # resampling copies whole paths
    return np.array(history[final])


def test_ancestral_path_equals_histories_carried_forward():
    rng = np.random.default_rng(3)
    t, n = 40, 7
    poses = rng.normal(size=(t, n, 3))
    ancestors = np.tile(np.arange(n), (t, 1))
    for step in rng.choice(t, size=12, replace=False):  # resampling at some steps only
        ancestors[step] = np.sort(rng.integers(0, n, size=n))
    for final in (0, 4, n - 1):
        got = np.asarray(ancestral_path(poses, ancestors, final))
        np.testing.assert_array_equal(got, carried_forward(poses, ancestors, final))
    # Without resampling a particle's path is its own column.
    ident = np.tile(np.arange(n), (t, 1))
    np.testing.assert_array_equal(np.asarray(ancestral_path(poses, ident, 2)), poses[:, 2])


def _sim(extra=()):
    cfg = load_config(None, ["data.t_end=60", "filter.n_particles=8", "filter.estimate=path", *extra])
    log = load_log(cfg)
    static, params = settings_from_config(cfg, log.segments.k_max)
    return cfg, log, static, params


@pytest.fixture(scope="module")
def sim_runs():
    """One simulated log; seed 5 run with ``estimate: path`` and with ``best``."""
    _, log, static, params = _sim()
    path = run_filter(static, params, log.segments, 5)
    plain = run_filter(dataclasses.replace(static, estimate=BestParticle()), params, log.segments, 5)
    return log, static, params, path, plain


@pytest.mark.slow
def test_path_runs_record_the_genealogy_without_changing_the_filter(sim_runs):
    """A run with ``estimate: path`` is the same filter (its per-segment estimate bit for bit),
    its path is the history carried forward of the final best particle, ends at the last best
    pose, and differs from the per-segment estimate (the comparison is not vacuous)."""
    log, _, _, run, plain = sim_runs
    o = run.outputs
    assert plain.outputs.poses is None and o.poses.shape == (log.segments.time.shape[0], 8, 3)
    np.testing.assert_array_equal(np.asarray(o.best_pose), np.asarray(plain.outputs.best_pose))
    assert int(run.state.resample_count) > 5  # the genealogy has branches to follow
    ident = np.arange(8)
    assert all(np.array_equal(a, ident) for r, a in zip(np.asarray(o.resampled), np.asarray(o.ancestors)) if not r)

    path = AncestralPath().trajectory(o, run.state)
    np.testing.assert_array_equal(
        path, carried_forward(np.asarray(o.poses), np.asarray(o.ancestors), int(run.state.best))
    )
    # Systematic resampling keeps the best particle, so the path ends at the last best pose.
    np.testing.assert_array_equal(path[-1], np.asarray(o.best_pose)[-1])
    assert np.abs(path[:, :2] - np.asarray(o.best_pose)[:, :2]).max() > 1e-3


def test_batched_paths_equal_each_members_path():
    """A batch's outputs (a leading batch axis, as ``run_batch`` returns them) give each member's path."""
    from types import SimpleNamespace

    rng = np.random.default_rng(4)
    b, t, n = 3, 25, 5
    poses = rng.normal(size=(b, t, n, 3))
    ancestors = np.sort(rng.integers(0, n, size=(b, t, n)), axis=-1)
    final = np.array([0, 3, 4])
    paths = AncestralPath().trajectory(SimpleNamespace(poses=poses, ancestors=ancestors), SimpleNamespace(best=final))
    assert paths.shape == (b, t, 3)
    for i in range(b):
        np.testing.assert_array_equal(paths[i], carried_forward(poses[i], ancestors[i], final[i]))


@pytest.mark.slow
def test_path_is_scored_and_written(sim_runs, tmp_path):
    """``nanoslam run`` scores the path and reports the filter's own estimate beside it."""
    from nanoslam_jax.app.experiment import run_experiment

    cfg, _, _, _ = _sim(["output.plots=false", "output.progress=false"])
    m = run_experiment(cfg, tmp_path)
    head = (tmp_path / "trajectory.csv").read_text().splitlines()[0].split(",")
    assert head[-3:] == ["best_x", "best_y", "best_phi"]
    table = np.loadtxt(tmp_path / "trajectory.csv", delimiter=",", skiprows=1)
    assert "rmse_fixed_best" in m and m["rmse_fixed"] != m["rmse_fixed_best"]
    assert np.abs(table[:, 1:3] - table[:, 7:9]).max() > 1e-3


@pytest.mark.parametrize("method", ["ekf_slam", "nasrukf", "dead_reckoning"])
def test_path_needs_particles(method):
    with pytest.raises(ConfigError, match="filter.estimate"):
        load_config(None, [f"filter.method={method}", "filter.estimate=path"])


@pytest.mark.slow
def test_reported_trajectory_needs_the_recorded_poses(sim_runs):
    _, _, _, _, plain = sim_runs
    with pytest.raises(ValueError, match="filter.estimate: path"):
        AncestralPath().trajectory(plain.outputs, plain.state)
    np.testing.assert_array_equal(WeightedMean().trajectory(plain.outputs), np.asarray(plain.outputs.mean_pose))


@pytest.mark.slow
def test_sweep_member_follows_the_path_inside_its_program(sim_runs):
    """A sweep's batch program follows the path back itself (the particles' poses never leave it)
    and scores the same path as a single run."""
    from tests.helpers.internals import sweep_batch as _batch

    log, static, params, alone, _ = sim_runs
    out = jax.jit(_batch._member, static_argnums=0)(static, params, 5, log.segments)
    np.testing.assert_allclose(
        np.asarray(out.path_pose), AncestralPath().trajectory(alone.outputs, alone.state), rtol=0, atol=1e-9
    )
