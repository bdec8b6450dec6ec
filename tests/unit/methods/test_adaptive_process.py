"""NASRUKF's estimated process noise (docs/method/nasrukf.md, "The estimated process noise").

Independent truths: the closed form of the forgetting weights (the normalised exponentially weighted
mean); the pose covariance a square-root unscented time update adds for small noise (the linearised
basis must reproduce it); a linear random walk with a known process noise, filtered by a Kalman
filter written here, whose adaptive estimate must converge to it; simulated logs whose
control noise (a car) or whole motion (a random walk) is known.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nanoslam_jax.app.config import ConfigError, load_config
from nanoslam_jax.data import make_segments
from nanoslam_jax.data import RawLog
from nanoslam_jax.app.experiment import execute
from nanoslam_jax.methods import (
    adaptive_process_summary,
    adaptive_process_update,
    forgetting_weight,
    process_noise_basis,
    run_filter,
)
from nanoslam_jax.app.filters import settings_from_config
from nanoslam_jax.methods.gaussian._nasrukf import pose_time_update
from nanoslam_jax.models import Ackermann, RandomWalk, Unicycle

# --------------------------------------------------------------------------- the forgetting weight


@pytest.mark.parametrize("b", [0.5, 0.9, 0.99, 0.999])
def test_forgetting_weight_is_the_normalised_exponential_weight(b):
    """d_k = (1 - b) / (1 - b^(k+1)) = 1 / sum_{i<=k} b^i: the recursion s_k = (1 - d_k) s_(k-1) + d_k x_k
    is the exponentially weighted mean sum b^(k-i) x_i / sum b^(k-i) from the first sample on (d_0 = 1),
    and d_k -> 1 - b."""
    ks = np.arange(0, 200, 9)
    d = np.array([float(forgetting_weight(b, int(k))) for k in ks])
    np.testing.assert_allclose(d, [1.0 / np.sum(b ** np.arange(k + 1)) for k in ks], rtol=1e-12)
    assert d[0] == 1.0
    x = np.random.default_rng(0).normal(size=ks[-1] + 1)
    s = 123.0  # the starting value drops out
    for k in range(ks[-1] + 1):
        dk = (1 - b) / (1 - b ** (k + 1))
        s = (1 - dk) * s + dk * x[k]
    w = b ** (ks[-1] - np.arange(ks[-1] + 1))
    assert s == pytest.approx(w @ x / w.sum(), rel=1e-10)
    assert float(forgetting_weight(b, 100_000)) == pytest.approx(1 - b, rel=1e-9)


# --------------------------------------------------------------------------- the estimator's pieces


@pytest.mark.slow
def test_random_walk_basis_is_the_noise_of_each_piece():
    """Random walk: F = I, so the map Lambda -> added covariance is sum_i S(dt_i) Lambda S(dt_i)'
    over the real pieces (masked pieces add nothing); the basis accumulates onto a given one."""
    rw = RandomWalk(0.4, 0.1)
    dt = jnp.array([0.1, 0.25, 0.3, 0.0])
    mask = jnp.array([True, True, False, False])
    rng = np.random.default_rng(1)
    B0 = jnp.asarray(rng.normal(size=(3, 3, 3, 3)))
    B = process_noise_basis(B0, jnp.array([1.0, 2.0, 3.0]), dt, jnp.zeros((4, 2)), mask, rw)
    lam = rng.normal(size=(3, 3))
    lam = lam @ lam.T
    S2 = np.diag([0.4, 0.4, 0.1]) ** 2 * 0.35  # two real pieces of 0.1 s and 0.25 s
    got = np.einsum("ab,abij->ij", lam, np.asarray(B) - np.asarray(B0))
    np.testing.assert_allclose(got, np.sqrt(S2) @ lam @ np.sqrt(S2), rtol=1e-12, atol=1e-15)


@pytest.mark.slow
@pytest.mark.parametrize(
    "model", [Ackermann(sigma_v=2e-3, sigma_alpha=1e-4), Unicycle(0.2, 0.05, 1e-4, 5e-5), RandomWalk(3e-4, 5e-5)]
)
def test_basis_reproduces_the_unscented_time_update(model):
    """The linearised map Lambda -> Q_pose equals the covariance the square-root unscented time update
    adds with the noise S Lambda^(1/2), for a near-certain start pose and small noise (where the
    unscented transform is the linearisation). Several DR pieces, a turning vehicle."""
    _, params = settings_from_config(load_config(None, ["filter.method=nasrukf"]), 4)
    params = params._replace(motion=model)
    n = 5
    dt = jnp.full(n, 0.025)
    u = jnp.tile(jnp.array([[3.0, 0.2]]), (n, 1))
    mask = jnp.ones(n, bool)
    x = jnp.array([1.0, -2.0, 0.7])
    w = model.noise_dim
    lam = jnp.eye(w) * 0.5 + 0.2
    _, Sp, _, _ = pose_time_update(x, 1e-9 * jnp.eye(3), dt, u, mask, params, jnp.linalg.cholesky(lam))
    B = process_noise_basis(jnp.zeros((w, w, 3, 3)), x, dt, u, mask, model)
    added = np.asarray(Sp @ Sp.T)
    np.testing.assert_allclose(
        np.einsum("ab,abij->ij", np.asarray(lam), np.asarray(B)), added, rtol=1e-4, atol=1e-6 * np.abs(added).max()
    )


@pytest.mark.slow
def test_update_inverts_the_basis_and_keeps_the_scale_positive_definite():
    """A change that is exactly Q_pose(Delta) moves Lambda by d_k Delta (least squares in the
    whitened frame is exact then); a change that would make it indefinite is held at the floor."""
    rng = np.random.default_rng(4)
    A = rng.normal(size=(3, 3, 3))  # three pieces' noise maps
    B = jnp.asarray(np.einsum("pia,pjb->abij", A, A))
    prior = np.linalg.cholesky(np.einsum("pia,pja->ij", A, A) + np.eye(3))
    lam = np.array([[1.0, 0.2, 0.0], [0.2, 0.8, 0.1], [0.0, 0.1, 1.2]])
    delta = np.array([[0.3, -0.1, 0.05], [-0.1, 0.2, 0.0], [0.05, 0.0, -0.4]])
    change = np.einsum("ab,abij->ij", delta, np.asarray(B))
    for k in (0, 7):
        got = adaptive_process_update(jnp.asarray(lam), k, jnp.asarray(change), jnp.asarray(prior), B, 0.95, 0.01)
        np.testing.assert_allclose(np.asarray(got), lam + float(forgetting_weight(0.95, k)) * delta, rtol=1e-10)
    # d_0 = 1 with a change of -5 Lambda's worth: the scale would be -4 Lambda; it is held at 0.05 I.
    change = np.einsum("ab,abij->ij", -5 * lam, np.asarray(B))
    got = np.asarray(
        adaptive_process_update(jnp.asarray(lam), 0, jnp.asarray(change), jnp.asarray(prior), B, 0.9, 0.05)
    )
    np.testing.assert_allclose(got, got.T, atol=0)
    np.testing.assert_allclose(np.linalg.eigvalsh(got), 0.05, rtol=1e-10)


def _adaptive_random_walk(lam_true, lam0, steps, b, seed):
    """A 3-D random walk x_k = x_(k-1) + w, w ~ N(0, S Lambda_true S'), measured directly,
    z = x + v: a Kalman filter with the adaptive scale (the project's update), written here."""
    rw = RandomWalk(0.2, 0.05)
    dt = 0.2
    S = np.asarray(rw.noise_sqrt(dt))
    R = np.diag([0.08, 0.08, 0.02]) ** 2
    rng = np.random.default_rng(seed)
    w = rng.multivariate_normal(np.zeros(3), S @ lam_true @ S.T, size=steps)
    x_true = np.cumsum(w, axis=0)
    z = x_true + rng.multivariate_normal(np.zeros(3), R, size=steps)
    Sj, Rj = jnp.asarray(S), jnp.asarray(R)
    basis = process_noise_basis(
        jnp.zeros((3, 3, 3, 3)), jnp.zeros(3), jnp.array([dt]), jnp.zeros((1, 2)), jnp.array([True]), rw
    )

    def step(carry, zk):
        x, P, lam, k = carry
        Pm = P + Sj @ lam @ Sj.T
        K = Pm @ jnp.linalg.inv(Pm + Rj)
        dx = K @ (zk - x)
        Pn = (jnp.eye(3) - K) @ Pm
        Pn = 0.5 * (Pn + Pn.T)
        change = jnp.outer(dx, dx) + Pn - Pm
        lam = adaptive_process_update(lam, k, change, jnp.linalg.cholesky(Pm), basis, b, 0.01)
        return (x + dx, Pn, lam, k + 1), jnp.diagonal(lam)

    init = (jnp.zeros(3), 1e-6 * jnp.eye(3), jnp.asarray(lam0), jnp.asarray(0))
    (x, P, lam, k), history = jax.jit(lambda c, zs: jax.lax.scan(step, c, zs))(init, jnp.asarray(z))
    return np.asarray(lam), np.asarray(history)


@pytest.mark.slow
@pytest.mark.parametrize(
    "lam_true, lam0",
    [
        (np.eye(3) / 3.0, np.eye(3)),  # the configured Q 3x too large
        (3.0 * np.eye(3), np.eye(3)),  # 3x too small
        (np.array([[0.6, 0.25, 0.0], [0.25, 0.5, 0.1], [0.0, 0.1, 1.5]]), np.eye(3)),  # correlated
    ],
)
def test_estimate_converges_to_the_process_noise_of_a_random_walk(lam_true, lam0):
    """20,000 steps with b = 0.999 (about 1,000 steps of memory); process noise comparable to the
    measurement noise. Measured: every element of the final Lambda within 7.2 % of Lambda_true's
    diagonal scale, the last 2,000 steps' diagonals within 10 %. Bounds: within 15 % (the issue's
    target), and the last 2,000 steps' estimates too (converged, not passing through)."""
    lam, history = _adaptive_random_walk(lam_true, lam0, 20_000, 0.999, seed=5)
    scale = np.sqrt(np.outer(np.diag(lam_true), np.diag(lam_true)))
    assert np.all(np.abs(lam - lam_true) <= 0.15 * scale), (lam, lam_true)
    assert np.all(np.abs(history[-2000:] / np.diag(lam_true) - 1) <= 0.15)


# --------------------------------------------------------------------------- in NASRUKF


SIM = [
    "sim.duration=120",
    "filter.method=nasrukf",
    "filter.capacity=256",
    "data.k_max=12",
    "output.progress=false",
    "sim.clutter_rate=0",
    "sim.steering_bias_deg=0",
    "sim.sigma_v=0.3",
    "sim.sigma_alpha_deg=2.0",
    "output.plots=false",
]


@pytest.mark.slow
def test_wrong_process_noise_is_corrected_on_a_simulated_log():
    """The simulator's car has white control noise (0.3 m/s, 2 deg per DR sample); the filter is told
    3x the variance of each (120 s, 559 scans with an update). Off, the filter keeps the 3x; on, the
    estimate moves towards the truth and the path stays as good. Measured (b = 0.99): estimated
    over true variance 1.87 (speed) and 1.77 (steering) against 3; position RMSE 0.363 m against
    0.361 m off, heading RMSE 0.678 deg against 0.644 deg. Bounds: both ratios below 2.3 and above
    0.5 (closer to 1 than the configured 3, in log terms by a quarter at least); position RMSE
    within 5 % and heading RMSE within 15 % of the fixed-noise run's."""
    wrong = [f"noise.sigma_v={0.3 * math.sqrt(3)}", f"noise.sigma_alpha_deg={2.0 * math.sqrt(3)}"]
    runs = {}
    for on in (False, True):
        runs[on] = execute(load_config(None, SIM + wrong + [f"nasrukf.adaptive_process={str(on).lower()}"])).metrics
    off, on = runs[False], runs[True]
    assert "process_noise_ratio_0" not in off
    ratio = np.array([on["process_noise_ratio_0"], on["process_noise_ratio_1"]]) ** 2 * 3.0  # estimated / true
    assert on["process_noise_updates"] > 500
    assert np.all((ratio > 0.5) & (ratio < 2.3)), ratio
    assert on["rmse_fixed"] <= 1.05 * off["rmse_fixed"], (on["rmse_fixed"], off["rmse_fixed"])
    assert on["rmse_heading_deg"] <= 1.15 * off["rmse_heading_deg"], (on["rmse_heading_deg"], off["rmse_heading_deg"])


def _random_walk_log(sigma_xy, sigma_phi, seconds, rate, seed):
    """A pose that follows a random walk (no odometry: zero controls) among 40 point landmarks in a
    40 m square, range and bearing detections (0.05 m, 0.5 deg) of those within 8 m ahead (a 180 deg
    field of view) at every step."""
    rng = np.random.default_rng(seed)
    n = int(seconds * rate)
    dt = 1.0 / rate
    t = dt * np.arange(1, n + 1)
    steps = rng.normal(size=(n, 3)) * np.sqrt(dt) * np.array([sigma_xy, sigma_xy, sigma_phi])
    poses = np.cumsum(steps, axis=0)
    trees = rng.uniform(-20, 20, size=(40, 2))
    rows = []
    for ti, p in zip(t, poses):
        d = trees - p[:2]
        r = np.hypot(d[:, 0], d[:, 1])
        b = np.mod(np.arctan2(d[:, 1], d[:, 0]) - p[2] + np.pi, 2 * np.pi) - np.pi
        keep = (r < 8.0) & (np.abs(b) < np.pi / 2)
        zr = r[keep] + 0.05 * rng.normal(size=keep.sum())
        zb = b[keep] + math.radians(0.5) * rng.normal(size=keep.sum())
        rows += [[ti, ri, bi, 0.3] for ri, bi in zip(zr, zb)]
    dr = np.column_stack([np.concatenate([[0.0], t]), np.zeros(n + 1), np.zeros(n + 1)])
    truth = np.column_stack([np.concatenate([[0.0], t]), np.vstack([np.zeros(3), poses])])
    return RawLog(
        dr=dr,
        detections=np.asarray(rows),
        gps=truth[:, :3],
        truth_poses=truth,
        truth_landmarks=trees,
        source="random walk",
    )


@pytest.mark.slow
def test_nasrukf_runs_the_random_walk_model_and_estimates_its_noise():
    """NASRUKF with model.motion random_walk (no odometry: the paper's random-walk state model, where
    Q is all the motion there is) on a 300 s log whose pose is a random walk (0.3 m/sqrt(s),
    3 deg/sqrt(s)), configured with 3x the true variance. Measured: estimated over true variance
    0.54 (x), 0.67 (y), 0.92 (heading) against 3; position RMSE 0.97 m, heading 9.9 deg, where the
    pose that stays at the origin is 5.25 m off (the 3x noise fixed: 0.44 m and 0.59 deg; the true
    noise fixed: 0.35 m). In SLAM the estimate runs below the truth and the filter loses accuracy
    (the method page says why). Bounds: every ratio between 0.3 and 2 (closer to 1 than the
    configured 3); the path tracks the truth (RMSE below 0.3 of the pose left at the origin)."""
    raw = _random_walk_log(0.3, math.radians(3.0), 300.0, 10.0, seed=2)
    seg = make_segments(raw, max_range=8.0)
    f = math.sqrt(3.0)
    cfg = load_config(
        None,
        [
            "filter.method=nasrukf",
            "model.motion=random_walk",
            f"random_walk.sigma_xy={0.3 * f}",
            f"random_walk.sigma_phi_deg={3.0 * f}",
            "noise.sigma_r=0.05",
            "noise.sigma_beta_deg=0.5",
            "nasrukf.adaptive_process=true",
            "nasrukf.process_forgetting=0.998",
            "filter.capacity=128",
            "data.max_range=8",
            "output.progress=false",
        ],
    )
    static, params = settings_from_config(cfg, seg.k_max)
    run = run_filter(static, params, seg, 0, chunk=500)
    ratio = np.diag(np.asarray(run.state.process_scale)) * 3.0
    assert int(run.state.process_count) > 2500
    assert np.all((ratio > 0.3) & (ratio < 2.0)), ratio
    est = np.asarray(run.outputs.best_pose)
    assert np.all(np.isfinite(est))
    t = np.asarray(seg.time)
    truth = np.stack([np.interp(t, raw.truth_poses[:, 0], raw.truth_poses[:, i]) for i in (1, 2)], axis=1)
    err = np.hypot(*(est[:, :2] - truth).T)
    still = np.hypot(*truth.T)
    assert np.sqrt(np.mean(err**2)) < 0.3 * np.sqrt(np.mean(still**2))


# --------------------------------------------------------------------------- config and report


@pytest.mark.parametrize(
    "overrides, words",
    [
        (["nasrukf.process_forgetting=1.0"], ["nasrukf.process_forgetting", "< 1"]),
        (["nasrukf.process_forgetting=0"], ["nasrukf.process_forgetting", "> 0"]),
        (["nasrukf.process_floor=0"], ["nasrukf.process_floor"]),
        (["nasrukf.process_floor=1.5"], ["nasrukf.process_floor"]),
        (["nasrukf.adaptive_process=true", "filter.method=nano"], ["nasrukf.adaptive_process", "nano"]),
    ],
)
def test_config_rejects_bad_process_noise_settings(overrides, words):
    with pytest.raises(ConfigError) as e:
        load_config(None, overrides)
    for w in words:
        assert w in str(e.value)


def test_off_by_default_and_static():
    cfg = load_config(None, ["filter.method=nasrukf"])
    static, params = settings_from_config(cfg, 4)
    assert static.method_settings.adaptive_process is False
    assert float(params.method.process_forgetting) == cfg.nasrukf.process_forgetting
    assert float(params.method.process_floor) == cfg.nasrukf.process_floor


def test_summary_reports_the_ratios_and_the_floor():
    lam = np.array([[4.0, 0.1], [0.1, 0.25]])
    m, w = adaptive_process_summary(lam, 12, 0.01)
    assert m["process_noise_ratio_0"] == 2.0 and m["process_noise_ratio_1"] == 0.5
    assert m["process_noise_updates"] == 12 and m["process_noise_at_floor"] is False and w == []
    m, w = adaptive_process_summary(np.diag([1.0, 0.01]), 3, 0.01)
    assert m["process_noise_at_floor"] is True and "nasrukf.process_floor" in w[0]
