"""NASRUKF with per-beam range measurements on line and arc features (nasrukf.measurement: beams):
the stacked update against a Kalman filter and against sequential single-beam updates, the fits of a
group's beams against a room ray-cast here, the paper's N_new rule, static initialisation on a room
scan built here, and the whole filter on a short simulated indoor log against its truth."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nanoslam_jax.app.config import ConfigError, load_config
from nanoslam_jax.data import Segments
from nanoslam_jax.methods import run_filter
from nanoslam_jax.app.filters import settings_from_config
from nanoslam_jax.methods.gaussian._nasrukf_beams_update import stacked_update
from nanoslam_jax.methods.gaussian._nasrukf_beams_state import ARC, EMPTY, LINE, Candidates, candidate_update, fit_group
from nanoslam_jax.lib.quadrature import Unscented

CONFIG = "configs/nasrukf_indoor.yaml"
RULE = Unscented(1.0, 2.0, 0.0)
_candidate_update = jax.jit(candidate_update)
_fit_group = jax.jit(fit_group)


@jax.jit
def _linear_update(y, L, H, z, use, var):
    return stacked_update(y, L, lambda s: H @ s, z, use, var, RULE)[:2]


def _lower(n, seed):
    a = np.random.default_rng(seed).normal(size=(n, n))
    return np.linalg.cholesky(a @ a.T + n * np.eye(n))


def test_stacked_update_of_a_linear_measurement_is_the_kalman_filter():
    rng = np.random.default_rng(0)
    n, b = 5, 8
    y, L = rng.normal(size=n), _lower(n, 1) * 0.1
    H = rng.normal(size=(b, n))
    z = rng.normal(size=b)
    var = 0.04
    use = np.array([True] * 6 + [False] * 2)
    yn, Ln = _linear_update(y, L, H, z, use, var)
    Hu, zu = H[use], z[use]
    P = L @ L.T
    S = Hu @ P @ Hu.T + var * np.eye(use.sum())
    K = P @ Hu.T @ np.linalg.inv(S)
    np.testing.assert_allclose(np.asarray(yn), y + K @ (zu - Hu @ y), atol=1e-10)
    np.testing.assert_allclose(np.asarray(Ln @ Ln.T), P - K @ S @ K.T, atol=1e-10)


@pytest.mark.slow
def test_stacked_update_equals_single_beam_updates_in_sequence_for_a_linear_measurement():
    rng = np.random.default_rng(3)
    n, b = 6, 5
    y, L = rng.normal(size=n), _lower(n, 2) * 0.2
    H = rng.normal(size=(b, n))
    z = rng.normal(size=b)
    var = jnp.asarray(0.01)
    all_in = jnp.ones(b, bool)
    y_all, L_all = _linear_update(y, L, H, z, all_in, var)
    ys, Ls = jnp.asarray(y), jnp.asarray(L)
    for k in range(b):  # one beam at a time: the same program, the other beams unused
        ys, Ls = _linear_update(ys, Ls, H, z, jnp.arange(b) == k, var)
    np.testing.assert_allclose(np.asarray(y_all), np.asarray(ys), atol=1e-10)
    np.testing.assert_allclose(np.asarray(L_all @ L_all.T), np.asarray(Ls @ Ls.T), atol=1e-10)


def _ray_cast_room(pose, phi, walls, pillar=None):
    """Ranges from ``pose`` (sensor pose) along beam angles ``phi`` to segments ``walls`` (x0, y0,
    x1, y1) and an optional circle: the nearest intersection ahead, computed here."""
    out = np.full(phi.shape, np.inf)
    px, py, th = pose
    d = np.stack([np.cos(th + phi), np.sin(th + phi)], 1)
    for x0, y0, x1, y1 in walls:
        e = np.array([x1 - x0, y1 - y0])
        A = np.stack([d, np.broadcast_to(-e, d.shape)], 2)  # r d - t e = p0 - s
        rhs = np.array([x0 - px, y0 - py])
        det = A[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] * A[:, 1, 0]
        ok = np.abs(det) > 1e-12
        det = np.where(ok, det, 1.0)
        r = (rhs[0] * A[:, 1, 1] - rhs[1] * A[:, 0, 1]) / det
        t = (A[:, 0, 0] * rhs[1] - A[:, 1, 0] * rhs[0]) / det
        hit = ok & (r > 0) & (t >= 0) & (t <= 1)
        out = np.where(hit & (r < out), r, out)
    if pillar is not None:
        xc, yc, R = pillar
        w = np.array([xc - px, yc - py])
        along = d @ w
        disc = along**2 - (w @ w - R * R)
        r = np.where(disc > 0, along - np.sqrt(np.maximum(disc, 0)), np.inf)
        out = np.where((r > 0) & (r < out), r, out)
    return out


@pytest.mark.slow
def test_group_fits_recover_a_wall_and_a_pillar_from_a_ray_cast():
    rng = np.random.default_rng(5)
    pose = np.array([0.3, -0.2, 0.4])
    phi = np.linspace(-1.2, 1.2, 120)
    r = _ray_cast_room(pose, phi, [(3.0, -5.0, 3.0, 5.0)]) + rng.normal(0, 0.002, phi.size)
    fit = _fit_group(jnp.asarray(r), jnp.asarray(phi), jnp.isfinite(jnp.asarray(r)), jnp.asarray(0.002**2))
    # the wall x = 3 in the sensor frame: normal at -theta, distance 3 - n . s
    rho_true = 3.0 - pose[0]
    assert abs(float(fit.line[0]) * math.cos(float(fit.line[1]) + pose[2]) - rho_true) < 0.01
    assert abs(((float(fit.line[1]) + pose[2] + math.pi) % (2 * math.pi)) - math.pi) < 0.01
    pillar = (1.5, 0.7, 0.25)
    r2 = _ray_cast_room(np.zeros(3), phi, [], pillar)
    on = np.isfinite(r2)
    r2 = np.where(on, r2 + rng.normal(0, 0.002, phi.size), 1.0)
    fit2 = _fit_group(jnp.asarray(r2), jnp.asarray(phi), jnp.asarray(on), jnp.asarray(0.002**2))
    np.testing.assert_allclose(np.asarray(fit2.arc), pillar, atol=0.02)
    assert np.all(np.linalg.eigvalsh(np.asarray(fit2.arc_cov)) > 0)


def _empty(g=4):
    return Candidates(jnp.full(g, EMPTY), jnp.zeros((g, 3)), jnp.zeros(g, jnp.int32), jnp.zeros(g, jnp.int32))


@pytest.mark.slow
def test_n_new_rule_creates_no_feature_from_fewer_than_n_new_data():
    g, n_new, gate = 4, jnp.asarray(3.0), jnp.asarray(0.15)
    wall = jnp.array([2.0, 0.3, 0.0])
    other = jnp.array([5.0, -1.2, 0.0])
    kind = jnp.array([LINE, LINE, ARC, LINE])
    cand = _empty(g)
    started = []
    for scan in range(5):
        # the same wall (jittered) every scan; another line and an arc only once
        params = jnp.stack([wall + 0.01 * scan, other, jnp.array([1.0, 1.0, 0.2]), wall + 0.02])
        new = jnp.array([True, scan == 0, scan == 1, scan == 0])  # row 3: the wall's second piece in scan 0
        cand, starts = _candidate_update(cand, new, kind, params, jnp.asarray(scan), n_new, gate)
        started.append(np.asarray(starts))
    started = np.array(started)
    # the wall is stored in scans 0, 1 and starts in scan 2 (its third datum), then starts anew from scan 3
    assert started[:2].sum() == 0
    assert started[2, 0] and started[2].sum() == 1
    assert not started[:, 1:].any()  # the line and the arc seen once never start a feature
    cand1, starts1 = _candidate_update(
        _empty(g),
        jnp.array([True, True, False, False]),
        kind,
        jnp.stack([wall, other, wall, wall]),
        jnp.asarray(0),
        jnp.asarray(1.0),
        gate,
    )
    assert np.asarray(starts1).tolist() == [True, True, False, False]  # N_new = 1: at once
    assert np.all(np.asarray(cand1.kind) == EMPTY)


def test_config_refuses_beams_without_nasrukf_beams():
    with pytest.raises(ConfigError, match="data.detections"):
        load_config(CONFIG, ["filter.method=ekf_slam"])
    with pytest.raises(ConfigError, match="nasrukf.measurement"):
        load_config(CONFIG, ["data.detections=laser_lines", "model.measurement=line"])
    with pytest.raises(ConfigError, match="nasrukf.n_new"):
        load_config(CONFIG, ["nasrukf.n_new=0"])


# --------------------------------------------------------------------------- the filter


ROOM = [(-2.0, -3.0, 6.0, -3.0), (6.0, -3.0, 6.0, 4.0), (6.0, 4.0, -2.0, 4.0), (-2.0, 4.0, -2.0, -3.0)]


def _static_room_segments(pose, n_scans, k_max, rng):
    """Scans at rest from the sensor pose ``pose`` in the room, every 4th of 361 beams, grouped by
    wall (the front end's grouping, done here from the ray-cast), as laser_beams segments."""
    phi = np.linspace(-np.pi / 2, np.pi / 2, 361)[::4]
    walls = np.array(ROOM)
    r = np.stack([_ray_cast_room(pose, phi, [w]) for w in walls])
    wall = np.argmin(r, axis=0)
    rng_true = np.min(r, axis=0)
    corner = np.zeros(phi.size, bool)  # the beams beside a corner are left out, as the front end does
    corner[1:] |= wall[1:] != wall[:-1]
    corner[:-1] |= wall[1:] != wall[:-1]
    keep = np.isfinite(rng_true) & ~corner
    gid = np.unique(wall[keep], return_inverse=True)[1]
    z = np.zeros((n_scans, k_max, 2))
    m = np.zeros((n_scans, k_max), bool)
    ids = np.full((n_scans, k_max), -1)
    n = int(keep.sum())
    for t in range(n_scans):
        z[t, :n, 0] = rng_true[keep] + rng.normal(0, 0.01, n)
        z[t, :n, 1] = phi[keep]
        m[t, :n], ids[t, :n] = True, gid
    return Segments(
        time=np.arange(1, n_scans + 1) * 0.025,
        dt=np.full((n_scans, 2), 0.0125),
        u=np.zeros((n_scans, 2, 2)),
        dr_mask=np.ones((n_scans, 2), bool),
        z=z,
        z_mask=m,
        diam=np.zeros((n_scans, k_max)),
        is_scan=np.ones(n_scans, bool),
        z_id=ids.astype(np.int32),
    )


def _pose_from_lines(est, true):
    """The pose of the SLAM frame in the room from matched lines (rho, alpha): the rotation from the
    normals, the translation from the distances (least squares)."""
    d = np.angle(np.exp(1j * (true[:, 1] - est[:, 1])))
    th = float(np.angle(np.mean(np.exp(1j * d))))
    A = np.stack([np.cos(true[:, 1]), np.sin(true[:, 1])], 1)
    t = np.linalg.lstsq(A, true[:, 0] - est[:, 0], rcond=None)[0]
    return np.array([t[0], t[1], th])


@pytest.mark.slow
def test_static_initialisation_recovers_a_known_pose_from_a_room_scan():
    pose = np.array([1.2, -0.4, 0.35])
    cfg = load_config(CONFIG, ["nasrukf.static_scans=40"])
    static, params = settings_from_config(cfg, cfg.data.k_max)
    seg = _static_room_segments(pose, 30, cfg.data.k_max, np.random.default_rng(1))
    run = run_filter(static, params, jax.tree.map(jnp.asarray, seg), 0)
    st = run.state
    np.testing.assert_allclose(np.asarray(run.outputs.best_pose[-1]), 0.0, atol=1e-9)  # held at the origin
    assert not bool(st.moving)
    est = np.asarray(st.normal_lines())[np.asarray(st.lines.active)]
    true = np.array([[3.0, -np.pi / 2], [6.0, 0.0], [4.0, np.pi / 2], [2.0, np.pi]])  # the walls (rho, alpha)
    # each estimated line is a wall seen from the pose: match by the wall the pose puts it on
    world = np.c_[
        est[:, 0] + np.cos(est[:, 1] + pose[2]) * pose[0] + np.sin(est[:, 1] + pose[2]) * pose[1], est[:, 1] + pose[2]
    ]
    match = [
        int(np.argmin(np.abs(np.angle(np.exp(1j * (true[:, 1] - w[1])))) + np.abs(true[:, 0] - w[0]))) for w in world
    ]
    assert len(set(match)) == est.shape[0] >= 3
    recovered = _pose_from_lines(est, true[match])
    assert np.hypot(*(recovered[:2] - pose[:2])) < 0.01
    assert abs(recovered[2] - pose[2]) < math.radians(0.2)


@pytest.mark.slow
def test_nasrukf_per_beam_tracks_a_simulated_indoor_log():
    import nanoslam_jax as ns

    cfg = load_config(CONFIG, ["indoor.duration=20", "indoor.seed=3"])
    res = ns.run(cfg)
    m = res.metrics
    # the simulator's truth: range noise 1 cm, odometry noise 1 cm/s and 1 deg/s (5x in slip);
    # dead reckoning drifts by several cm over 20 s, the filter stays within a few mm
    assert m["finite"]
    assert m["rmse_fixed"] < 0.02
    assert m["rmse_heading_deg"] < 0.5
    assert m["n_lines_matched"] >= 3
    assert m["line_intercept_median"] < 0.02


def test_the_papers_line_form_measures_the_same_ranges_as_the_normal_form():
    from nanoslam_jax.methods.gaussian._nasrukf_beams_update import line_ranges
    from nanoslam_jax.methods.gaussian._nasrukf_beams_state import line_param, to_normal

    rng = np.random.default_rng(7)
    pose = jnp.array([0.4, -0.3, 0.7])
    phi = jnp.linspace(-1.5, 1.5, 31)

    @jax.jit
    def both(line):
        m, vertical = line_param(line, "slope_intercept")
        normal = line_ranges(pose, phi, line, jnp.asarray(False), "normal")
        return (
            m,
            vertical,
            to_normal(m, vertical, "slope_intercept"),
            normal,
            line_ranges(pose, phi, m, vertical, "slope_intercept"),
        )

    for alpha in [0.3, 1.2, np.pi / 2 - 1e-4, 2.5, np.pi, -0.8, 0.0]:
        line = jnp.array([2.0 + rng.random(), alpha])
        m, vertical, back, (r_n, h_n), (r_p, h_p) = both(line)
        np.testing.assert_allclose(np.asarray(back), np.asarray(line), atol=1e-9)
        assert bool(vertical) == (abs(np.cos(alpha)) > 1e3 * abs(np.sin(alpha)))
        np.testing.assert_array_equal(np.asarray(h_n), np.asarray(h_p))
        np.testing.assert_allclose(np.asarray(r_p)[np.asarray(h_n)], np.asarray(r_n)[np.asarray(h_n)], rtol=1e-9)
