"""Checks shared by the tests of the methods without particles (EKF-SLAM, NASRUKF): a run on a
simulated log against its true path and trees, and padding segments that leave the state as it was.

The padding check drives the scan driver's chunk step itself (``nanoslam_jax.methods._scan``, private:
no public function scans one chunk of padding segments)."""

import jax
import jax.numpy as jnp
import numpy as np

from nanoslam_jax.app.config import load_config
from nanoslam_jax.app.experiment import load_log
from nanoslam_jax.methods import _scan, reported_map
from nanoslam_jax.app.filters import settings_from_config
from nanoslam_jax.eval.metrics import landmark_errors
from tests.helpers.paths import REPO_ROOT


def simulated(overrides):
    """The log of the embedded default config with ``overrides`` and the filter settings for it."""
    cfg = load_config(None, overrides)
    log = load_log(cfg)
    return (log, *settings_from_config(cfg, log.segments.k_max))


def dead_reckoning_rmse(log, params) -> float:
    """RMSE of noise-free dead reckoning on ``log`` against its truth (the baseline)."""
    from nanoslam_jax.methods import dead_reckoning

    poses = np.asarray(dead_reckoning(params, jax.tree.map(np.asarray, log.segments)))
    err = np.hypot(*(poses[:, :2] - true_positions(log)).T)
    return float(np.sqrt(np.mean(err**2)))


def float_leaves(tree):
    return [
        np.asarray(a)
        for a in jax.tree.leaves(tree)
        if not jnp.issubdtype(jnp.asarray(a).dtype, jax.dtypes.prng_key)
        and np.issubdtype(np.asarray(a).dtype, np.floating)
    ]


def true_positions(log):
    """The simulated log's true laser positions at its segments' times."""
    t = np.asarray(log.segments.time)
    tp = log.raw.truth_poses
    return np.stack([np.interp(t, tp[:, 0], tp[:, 1]), np.interp(t, tp[:, 0], tp[:, 2])], axis=1)


def assert_tracks_truth_and_maps_trees(
    log, params, run, *, rmse: float, max_error: float, associations: float, median: float, dr_factor: float = 5.0
):
    """Everything finite; position RMSE and largest error against the truth below the bounds and
    ``dr_factor`` times below noise-free dead reckoning's RMSE on the same log; the reported
    estimate is the mean; at least 15 confirmed landmarks, >= 90 % of them within 1 m of a true
    tree and their median error below ``median``. Returns the reported map."""
    for a in float_leaves(run.outputs) + float_leaves(run.state):
        assert np.all(np.isfinite(a))
    o = run.outputs
    assert int(np.sum(o.n_nonfinite)) == 0 and int(run.state.overflow) == 0
    err = np.hypot(*(np.asarray(o.best_pose)[:, :2] - true_positions(log)).T)
    got = float(np.sqrt(np.mean(err**2)))
    assert got < rmse and err.max() < max_error, (got, err.max())
    dr = dead_reckoning_rmse(log, params)
    assert got * dr_factor <= dr, f"RMSE {got:.3f} m is not {dr_factor}x below dead reckoning's {dr:.3f} m"
    np.testing.assert_array_equal(np.asarray(o.best_pose), np.asarray(o.mean_pose))
    assert np.mean(o.n_associated) > associations  # the filter really associates
    lm = reported_map(run.state)
    sel = np.asarray(lm.active) & np.asarray(lm.confirmed)
    assert sel.sum() >= 15
    e2t = landmark_errors(np.asarray(lm.mean)[sel], log.raw.truth_landmarks)["est_to_true"]
    assert np.mean(e2t < 1.0) >= 0.9 and np.median(e2t) < median, e2t
    return lm


def assert_padding_is_noop(static, params, state, segments, chunk: int, pose):
    """Padding (valid False), whether zero segments or real ones, leaves ``state`` bit for bit and
    reports ``pose`` with no associations when scanned (:func:`filter_scan`); the driver's chunk
    program (``skip_padding``) skips it and returns ``state`` as it was."""
    seg = jax.tree.map(lambda a: jnp.asarray(np.asarray(a)[:chunk]), segments)
    invalid = jnp.zeros(chunk, bool)
    scan = jax.jit(_scan.filter_scan, static_argnums=0)
    for s in (seg, jax.tree.map(jnp.zeros_like, seg)):
        new, out = scan(static, params, s, None, state, invalid)
        skipped, _ = _scan._chunk(static, params, state, s, invalid)
        for result in (new, skipped):
            assert type(result) is type(state)
            for a, b in zip(jax.tree.leaves(state), jax.tree.leaves(result)):
                if jnp.issubdtype(a.dtype, jax.dtypes.prng_key):
                    a, b = jax.random.key_data(a), jax.random.key_data(b)
                np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
        assert np.all(np.asarray(out.n_associated) == 0) and np.all(np.asarray(out.n_new) == 0)
        np.testing.assert_array_equal(np.asarray(out.best_pose), np.broadcast_to(np.asarray(pose), (chunk, 3)))


def run_real_log_start(
    config_name: str,
    vp_dir,
    *,
    fixed: tuple[float, float],
    aligned: float,
    dr_factor: float,
    confirmed: tuple[int, int],
    what: str,
):
    """Run ``configs/<config_name>`` over the real log's first 300 s and check it against GPS and
    against dead reckoning on the same span: everything finite, no overflow, detections
    associate, ``rmse_fixed`` inside the band ``fixed``, ``rmse_aligned`` below ``aligned``, at
    least ``dr_factor`` times below dead reckoning's ``rmse_fixed``, and a confirmed-landmark count
    inside ``confirmed``. Returns the run."""

    from tests.helpers.baselines import assert_beats_dead_reckoning, dead_reckoning_metrics
    from nanoslam_jax.methods import run_filter
    from nanoslam_jax.eval.metrics import evaluate

    cfg = load_config(REPO_ROOT / "configs" / config_name, [f"data.path={vp_dir}", "data.t_end=300"])
    log = load_log(cfg)
    static, params = settings_from_config(cfg, log.segments.k_max)
    run = run_filter(static, params, log.segments, 0, chunk=500)
    for a in float_leaves(run.outputs) + float_leaves(run.state):
        assert np.all(np.isfinite(a))
    o = run.outputs
    assert int(np.sum(o.n_nonfinite)) == 0 and int(run.state.overflow) == 0
    assert np.mean(o.n_associated) > 1.0
    m = evaluate(
        np.asarray(log.segments.time),
        np.asarray(o.best_pose)[:, :2],
        log.raw.gps,
        frame=log.frame,
        rotation_deg=cfg.metrics.gps_rotation_deg,
        jump_speed=cfg.metrics.jump_speed,
    )
    assert fixed[0] < m["rmse_fixed"] < fixed[1] and m["rmse_aligned"] < aligned, m
    assert_beats_dead_reckoning(m["rmse_fixed"], dead_reckoning_metrics(cfg, log)["rmse_fixed"], dr_factor, what)
    lm = reported_map(run.state)
    assert confirmed[0] <= int(np.sum(np.asarray(lm.active) & np.asarray(lm.confirmed))) <= confirmed[1]
    return run
