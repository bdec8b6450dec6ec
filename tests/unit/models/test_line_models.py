"""Line and arc landmarks: the per-beam ranges against ray-casts written here, the parameter forms
against each other (the vertical case continuous in the normal form), autodiff Jacobians against
finite differences, the measurement plug-ins' inverse models, a filter with line landmarks on a
room written here, and the Table 1 metrics on hand-built maps with known offsets."""

import math
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nanoslam_jax.app.config import ConfigError, load_config
from nanoslam_jax.data import Segments
from nanoslam_jax.methods import reported_map, run_filter
from nanoslam_jax.app.filters import settings_from_config
from nanoslam_jax.eval.metrics import (
    arc_feature_errors,
    feature_map_errors,
    line_feature_errors,
    line_intersections,
    point_feature_errors,
)
from nanoslam_jax.models import (
    Circle,
    LineSegment,
    beam_range_circle,
    beam_range_line,
    beam_range_slope_intercept,
    beam_range_vertical,
    check_measurement_model,
    line_from_slope_intercept,
    line_from_vertical,
    line_to_sensor,
    line_to_world,
    normalize_line,
    sensor_pose,
    slope_intercept_from_line,
)

# the functions under test, compiled once per input shape (run eagerly, JAX compiles each operation)
(
    beam_range_circle,
    beam_range_line,
    beam_range_slope_intercept,
    beam_range_vertical,
    line_from_slope_intercept,
    line_from_vertical,
    line_to_sensor,
    line_to_world,
    normalize_line,
    sensor_pose,
    slope_intercept_from_line,
) = (
    jax.jit(f)
    for f in (
        beam_range_circle,
        beam_range_line,
        beam_range_slope_intercept,
        beam_range_vertical,
        line_from_slope_intercept,
        line_from_vertical,
        line_to_sensor,
        line_to_world,
        normalize_line,
        sensor_pose,
        slope_intercept_from_line,
    )
)

# ---------------------------------------------------------------------------------------------
# geometry written out here, independently of the package


def _sensor(pose, offset):
    """The sensor's position and heading: the pose moved by ``offset`` (forward, left) in its frame."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    return np.array([pose[0] + c * offset[0] - s * offset[1], pose[1] + s * offset[0] + c * offset[1]]), pose[2]


def _ray_segment(origin, direction, p1, p2):
    """The distance along a ray to the line through ``p1, p2``: solve ``o + t d = p1 + u (p2 - p1)``;
    None when parallel or behind."""
    A = np.column_stack([direction, p1 - p2])
    if abs(np.linalg.det(A)) < 1e-12:
        return None
    t, _ = np.linalg.solve(A, p1 - origin)
    return t if t > 0 else None


def _ray_circle(origin, direction, centre, radius):
    """The nearest intersection ahead of a ray with a circle: the smallest positive real root of
    ``|o + t d - c|^2 = R^2`` (numpy's polynomial roots); None when there is none."""
    w = origin - centre
    roots = np.roots([direction @ direction, 2.0 * direction @ w, w @ w - radius**2])
    ahead = [r.real for r in roots if abs(r.imag) < 1e-9 and r.real > 0]
    return min(ahead) if ahead else None


def _normal_form(p1, p2):
    """``(rho, alpha)`` of the line through two points, ``rho >= 0``."""
    e = (p2 - p1) / np.linalg.norm(p2 - p1)
    n = np.array([-e[1], e[0]])
    rho = n @ p1
    if rho < 0:
        n, rho = -n, -rho
    return np.array([rho, math.atan2(n[1], n[0])])


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


def _central_difference(f, a, eps=1e-6):
    """Central differences of a function ``f`` vectorised over rows: ``(N, k) -> (N,)`` or ``(N, d)``;
    returns ``(N, k)`` or ``(N, d, k)``."""
    a = np.asarray(a, float)
    cols = []
    for i in range(a.shape[-1]):
        d = np.zeros_like(a)
        d[..., i] = eps
        cols.append((np.asarray(f(jnp.asarray(a + d))) - np.asarray(f(jnp.asarray(a - d)))) / (2 * eps))
    return np.stack(cols, -1)


def _random_scene(rng, n):
    """``n`` random poses, beam angles and lines through two random points."""
    pose = rng.uniform([-3, -3, -np.pi], [3, 3, np.pi], (n, 3))
    phi = rng.uniform(-np.pi, np.pi, n)
    p1, p2 = rng.uniform(-8, 8, (n, 2)), rng.uniform(-8, 8, (n, 2))
    return pose, phi, p1, p2


# ---------------------------------------------------------------------------------------------
# per-beam ranges against ray-casts


@pytest.mark.parametrize("offset", [None, np.array([-0.18, 0.05])], ids=["no_offset", "offset"])
def test_beam_range_to_a_line_equals_a_ray_cast_in_every_form(offset):
    rng = np.random.default_rng(0)
    n = 300
    pose, phi, p1, p2 = _random_scene(rng, n)
    off = np.zeros(2) if offset is None else np.asarray(offset)
    want = np.full(n, np.inf)
    for i in range(n):
        s, theta = _sensor(pose[i], off)
        t = _ray_segment(s, np.array([math.cos(theta + phi[i]), math.sin(theta + phi[i])]), p1[i], p2[i])
        want[i] = np.inf if t is None else t
    lines = np.stack([_normal_form(a, b) for a, b in zip(p1, p2)])
    same_lines = np.stack([-lines[:, 0], lines[:, 1] + np.pi], -1)  # (-rho, alpha + pi): the same lines
    slope = (p2[:, 1] - p1[:, 1]) / (p2[:, 0] - p1[:, 0])
    icpt = p1[:, 1] - slope * p1[:, 0]
    hits = np.isfinite(want)
    assert 50 < hits.sum() < n - 50
    for r, hit in (
        beam_range_line(pose, phi, lines, offset),
        beam_range_line(pose, phi, same_lines, offset),
        beam_range_slope_intercept(pose, phi, slope, icpt, offset),
    ):
        np.testing.assert_array_equal(np.asarray(hit), hits)
        np.testing.assert_allclose(np.asarray(r), want, rtol=1e-9, atol=1e-9)  # inf where missed
    # the vertical form x = c (eq. 15), against the ray-cast to the line through (c, 0), (c, 1)
    c = rng.uniform(-6, 6, n)
    want = np.full(n, np.inf)
    for i in range(n):
        s, theta = _sensor(pose[i], off)
        t = _ray_segment(
            s,
            np.array([math.cos(theta + phi[i]), math.sin(theta + phi[i])]),
            np.array([c[i], 0.0]),
            np.array([c[i], 1.0]),
        )
        want[i] = np.inf if t is None else t
    for r, hit in (
        beam_range_vertical(pose, phi, c, offset),
        beam_range_line(pose, phi, line_from_vertical(c), offset),
    ):
        np.testing.assert_array_equal(np.asarray(hit), np.isfinite(want))
        np.testing.assert_allclose(np.asarray(r), want, rtol=1e-9, atol=1e-9)


def test_beam_range_to_a_circle_equals_a_ray_cast():
    rng = np.random.default_rng(1)
    n = 400
    pose, phi = rng.uniform([-3, -3, -np.pi], [3, 3, np.pi], (n, 3)), rng.uniform(-np.pi, np.pi, n)
    circle = np.concatenate([rng.uniform(-4, 4, (n, 2)), rng.uniform(0.2, 3.0, (n, 1))], 1)
    offset = np.array([-0.18, 0.0])  # the paper's Ls behind the reference point
    want, inside = np.full(n, np.inf), np.zeros(n, bool)
    for i in range(n):
        s, theta = _sensor(pose[i], offset)
        t = _ray_circle(s, np.array([math.cos(theta + phi[i]), math.sin(theta + phi[i])]), circle[i, :2], circle[i, 2])
        want[i] = np.inf if t is None else t
        inside[i] = np.hypot(*(s - circle[i, :2])) < circle[i, 2]
    r, hit = beam_range_circle(pose, phi, circle, offset)
    np.testing.assert_array_equal(np.asarray(hit), np.isfinite(want))
    np.testing.assert_allclose(np.asarray(r), want, rtol=1e-9, atol=1e-9)
    hits = np.isfinite(want)
    assert min((hits & ~inside).sum(), (hits & inside).sum(), (~hits).sum()) > 20


def test_beam_ranges_vectorise_over_beams_and_never_give_nan():
    """A whole scan at once: the nearest of a room's walls and a pillar on every beam, against the
    ray-cast beam by beam; beams parallel to a wall miss it (inf, not NaN)."""
    walls = [
        (np.array([-2.0, -2.0]), np.array([6.0, -2.0])),
        (np.array([6.0, -2.0]), np.array([6.0, 4.0])),
        (np.array([6.0, 4.0]), np.array([-2.0, 4.0])),
        (np.array([-2.0, 4.0]), np.array([-2.0, -2.0])),
    ]
    pillar = np.array([3.0, 1.0, 0.4])
    pose = np.array([0.5, 0.2, 0.0])  # heading along the x axis: beams at 0 and +-90 deg parallel to walls
    phi = np.linspace(-np.pi / 2, np.pi / 2, 181)
    lines = np.stack([_normal_form(*w) for w in walls])
    r_lines, hit_lines = beam_range_line(pose, phi[:, None], lines)  # (181, 4)
    r_circle, hit_circle = beam_range_circle(pose, phi, pillar)
    got = np.minimum(np.min(np.asarray(r_lines), 1), np.asarray(r_circle))
    assert not np.isnan(np.asarray(r_lines)).any() and not np.asarray(hit_lines)[90, 0]  # parallel
    s = pose[:2]
    for i, p in enumerate(phi):
        d = np.array([math.cos(p), math.sin(p)])
        cands = [t for t in (_ray_segment(s, d, *w) for w in walls) if t is not None]
        t_c = _ray_circle(s, d, pillar[:2], pillar[2])
        want = min(cands + ([t_c] if t_c is not None else []))
        np.testing.assert_allclose(got[i], want, rtol=1e-9)
    assert np.asarray(hit_circle).sum() > 5


# ---------------------------------------------------------------------------------------------
# parameter forms and frames


def test_forms_convert_into_each_other():
    rng = np.random.default_rng(2)
    a, b = rng.uniform(-5, 5, 50), rng.uniform(-5, 5, 50)
    lines = np.asarray(line_from_slope_intercept(a, b))
    assert np.all(lines[:, 0] >= 0)
    # each line holds the points (x, a x + b)
    for x in (-3.0, 0.0, 4.0):
        np.testing.assert_allclose(x * np.cos(lines[:, 1]) + (a * x + b) * np.sin(lines[:, 1]), lines[:, 0], atol=1e-12)
    back = slope_intercept_from_line(lines)
    assert not np.asarray(back.vertical).any()
    np.testing.assert_allclose(back.a, a, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(back.b, b, rtol=1e-12, atol=1e-12)
    c = rng.uniform(-5, 5, 20)
    vert = np.asarray(line_from_vertical(c))
    np.testing.assert_allclose(vert[:, 0], np.abs(c))
    np.testing.assert_allclose(np.cos(vert[:, 1]) * vert[:, 0], c, atol=1e-12)
    back = slope_intercept_from_line(vert)
    assert np.asarray(back.vertical).all()
    np.testing.assert_allclose(back.c, c, atol=1e-12)
    # (-rho, alpha + pi) is the same line
    np.testing.assert_allclose(normalize_line(np.stack([-lines[:, 0], lines[:, 1] + np.pi], -1)), lines, atol=1e-12)


def test_sensor_frame_of_a_line_equals_its_points_moved_into_the_sensor_frame():
    rng = np.random.default_rng(3)
    n, offset = 50, np.array([-0.18, 0.3])
    pose, _, p1, p2 = _random_scene(rng, n)
    world = np.stack([_normal_form(a, b) for a, b in zip(p1, p2)])
    want, s_all = np.zeros((n, 2)), np.zeros((n, 2))
    for i in range(n):
        s, theta = _sensor(pose[i], offset)
        rot = np.array([[math.cos(theta), math.sin(theta)], [-math.sin(theta), math.cos(theta)]])  # world -> sensor
        want[i], s_all[i] = _normal_form(rot @ (p1[i] - s), rot @ (p2[i] - s)), s
    got = np.asarray(line_to_sensor(world, pose, offset))
    np.testing.assert_allclose(got[:, 0], want[:, 0], atol=1e-9)
    np.testing.assert_allclose(_wrap(got[:, 1] - want[:, 1]), 0.0, atol=1e-9)
    np.testing.assert_allclose(line_to_world(got, pose, offset), world, atol=1e-9)
    np.testing.assert_allclose(np.asarray(sensor_pose(pose, offset))[:, :2], s_all, atol=1e-12)


def test_the_vertical_case_is_continuous_in_the_normal_form():
    """A line through (3, 2) turning through vertical: its slope-intercept parameters jump without
    bound, its normal form and the range along a fixed beam change in proportion to the turn."""
    step = 1e-4
    turn = np.arange(-0.2, 0.2 + step / 2, step) + np.pi / 2  # direction angle of the line
    turn[np.argmin(np.abs(turn - np.pi / 2))] = np.pi / 2  # exactly vertical once
    p = np.array([3.0, 2.0])
    vertical = turn == np.pi / 2
    a = np.where(vertical, 0.0, np.tan(turn))
    b = p[1] - a * p[0]
    lines = np.where(
        vertical[:, None],
        np.asarray(line_from_vertical(np.full(turn.size, p[0]))),
        np.asarray(line_from_slope_intercept(a, b)),
    )
    # the normal form of the line through p at that angle, written out here: n = (sin, -cos) of the
    # turn, turned to point away from the origin
    n = np.stack([np.sin(turn), -np.cos(turn)], -1)
    n = np.where((n @ p < 0)[:, None], -n, n)
    np.testing.assert_allclose(lines[:, 0], n @ p, atol=1e-9)
    np.testing.assert_allclose(_wrap(lines[:, 1] - np.arctan2(n[:, 1], n[:, 0])), 0.0, atol=1e-9)
    assert np.max(np.abs(np.diff(lines[:, 0]))) < 5 * step
    assert np.max(np.abs(_wrap(np.diff(lines[:, 1])))) < 1.01 * step
    assert np.max(np.abs(np.diff(b[~vertical]))) > 1e3  # the slope-intercept form is singular here
    r, hit = beam_range_line(np.zeros(3), 0.3, lines)
    assert np.asarray(hit).all() and np.max(np.abs(np.diff(np.asarray(r)))) < 10 * step


# ---------------------------------------------------------------------------------------------
# autodiff Jacobians against finite differences


@pytest.mark.slow
def test_beam_range_jacobians_match_finite_differences():
    rng = np.random.default_rng(4)
    offset = jnp.array([-0.18, 0.0])
    n = 200
    pose, phi, p1, p2 = _random_scene(rng, n)
    line = np.stack([_normal_form(a, b) for a, b in zip(p1, p2)])
    circle = np.concatenate([rng.uniform(-4, 4, (n, 2)), rng.uniform(0.3, 2.0, (n, 1))], 1)
    r_line, hit_line = beam_range_line(pose, phi, line, offset)
    r_circ, hit_circ = beam_range_circle(pose, phi, circle, offset)
    ok = np.asarray(hit_line & hit_circ & (r_line < 50))
    assert ok.sum() > 10
    pose, phi, line, circle = pose[ok], phi[ok], line[ok], circle[ok]
    for f, arg in (
        (lambda p: beam_range_line(p, phi, line, offset)[0], pose),
        (lambda m: beam_range_line(pose, phi, m, offset)[0], line),
        (lambda p: beam_range_circle(p, phi, circle, offset)[0], pose),
        (lambda m: beam_range_circle(pose, phi, m, offset)[0], circle),
    ):
        f = jax.jit(f)
        grad = jax.jit(jax.grad(lambda a: jnp.sum(f(a))))(jnp.asarray(arg))  # rows independent: per-row gradients
        np.testing.assert_allclose(grad, _central_difference(f, arg), rtol=1e-5, atol=1e-6)
    # a miss has a zero gradient, not NaN
    g = jax.grad(lambda p: beam_range_circle(p, 0.0, jnp.array([0.0, 50.0, 1.0]))[0])(jnp.zeros(3))
    assert np.all(np.isfinite(g))


@pytest.mark.slow
@pytest.mark.parametrize(
    "model", [LineSegment(sensor_x=-0.18), Circle(sensor_x=-0.18, sensor_y=0.05)], ids=["line", "circle"]
)
def test_model_jacobians_match_finite_differences_and_the_inverse_round_trips(model):
    rng = np.random.default_rng(5)
    n = 20
    x = rng.uniform([-2, -2, -np.pi], [2, 2, np.pi], (n, 3))
    if isinstance(model, LineSegment):
        m = np.stack([_normal_form(*rng.uniform(-8, 8, (2, 2))) for _ in range(n)])
    else:
        m = np.concatenate([rng.uniform(-8, 8, (n, 2)), rng.uniform(0.2, 1.0, (n, 1))], 1)
    h, inv = jax.jit(jax.vmap(model.h)), jax.jit(jax.vmap(model.landmark_from))
    z = np.asarray(h(x, m))
    keep = z[:, 0] > 0.3  # away from the sensor, where a line's normal would flip
    x, m, z = x[keep], m[keep], z[keep]
    assert keep.sum() > 10
    np.testing.assert_allclose(inv(x, z), m, atol=1e-9)
    np.testing.assert_allclose(jax.jit(jax.vmap(model.innovation))(h(x, inv(x, z)), z), 0.0, atol=1e-9)
    Gx, Gm = jax.jit(jax.vmap(model.jacobians))(x, m)
    Ix, Iz = jax.jit(jax.vmap(model.inverse_jacobians))(x, z)
    dm, dz = model.landmark_dim, model.measurement_dim
    assert Gx.shape[1:] == (dz, 3) and Gm.shape[1:] == (dz, dm) and Iz.shape[1:] == (dm, dz)
    np.testing.assert_allclose(Gx, _central_difference(lambda a: h(a, m), x), atol=1e-6)
    np.testing.assert_allclose(Gm, _central_difference(lambda a: h(x, a), m), atol=1e-6)
    np.testing.assert_allclose(Ix, _central_difference(lambda a: inv(a, z), x), atol=1e-6)
    np.testing.assert_allclose(Iz, _central_difference(lambda a: inv(x, a), z), atol=1e-6)
    np.testing.assert_allclose(Gm @ Iz, np.broadcast_to(np.eye(dz), Gm.shape[:1] + (dz, dz)), atol=1e-9)


def test_line_segment_detection_and_visibility():
    """A wall seen by a sensor 0.18 m behind the reference point: the detection is the wall's
    distance and foot-point bearing from the sensor; visibility follows the foot point."""
    model = LineSegment(max_range=5.0, half_fov=math.radians(100), sensor_x=-0.18)
    wall = _normal_form(np.array([3.0, -5.0]), np.array([3.0, 5.0]))  # x = 3
    poses = np.array([[1.0, 0.5, 0.0], [1.0, 0.5, math.pi / 2], [1.0, 0.5, 0.3], [1.0, 0.5, math.pi], [-4.0, 0.5, 0.0]])
    z = np.asarray(jax.jit(jax.vmap(model.h, (0, None)))(poses, wall))
    np.testing.assert_allclose(z[0], [3.0 - 0.82, 0.0], atol=1e-12)
    np.testing.assert_allclose(z[1], [2.0, -math.pi / 2], atol=1e-12)  # the sensor at (1, 0.32)
    # visible ahead; not behind; not beyond max_range
    np.testing.assert_array_equal(
        jax.jit(jax.vmap(model.visible, (0, None)))(poses, wall), [True, True, True, False, False]
    )


# ---------------------------------------------------------------------------------------------
# configuration and the engine


def test_line_model_by_config_name_and_unequal_dimensions_refused_with_the_reason():
    cfg = load_config(
        None,
        [
            "model.measurement=line",
            "model.measurement_params.sigma_rho=0.03",
            "model.measurement_params.sensor_x=-0.18",
        ],
    )
    _, params = settings_from_config(cfg, 4)
    assert isinstance(params.measurement, LineSegment)
    np.testing.assert_allclose(params.R, np.diag([0.03**2, math.radians(1.0) ** 2]))
    np.testing.assert_allclose(params.measurement.offset, [-0.18, 0.0])
    _, params = settings_from_config(load_config(None, ["model.measurement=circle"]), 4)
    assert isinstance(params.measurement, Circle) and params.R.shape == (3, 3)

    class PartialCircle(Circle):  # a detection that does not determine the landmark
        measurement_dim: ClassVar[int] = 2

    with pytest.raises(ValueError, match="model.measurement.*landmark_dim 3 and measurement_dim 2"):
        check_measurement_model(PartialCircle, "fastslam2")
    with pytest.raises(ConfigError, match="model.measurement.*nasrukf"):
        load_config(None, ["model.measurement=line", "filter.method=nasrukf"])
    with pytest.raises(ConfigError, match="model.measurement_params"):
        load_config(None, ["model.measurement=line", "model.measurement_params.sigma_r=1"])


#: The room (walls x = -2, x = 6, y = -2, y = 4 in the frame of the start pose).
ROOM = np.array([[2.0, np.pi], [6.0, 0.0], [2.0, -np.pi / 2], [4.0, np.pi / 2]])
SIGMA_RHO, SIGMA_ALPHA, SIGMA_V, SIGMA_OMEGA = 0.01, math.radians(0.5), 0.02, math.radians(2.0)


def _room_log(n_seg=180, dt=0.2, seed=0):
    """A differential-drive robot on a circle (radius 1.2 m, 0.4 m/s) from the origin, two odometry
    pieces of ``(v, omega)`` per scan with noise; each scan detects the walls whose foot point lies
    in the sensor's half plane ahead, as ``(rho_s, alpha_s)`` with noise."""
    rng = np.random.default_rng(seed)
    v, omega = 0.4, 0.4 / 1.2
    k_max = ROOM.shape[0]
    u = np.zeros((n_seg, 2, 2))
    z = np.zeros((n_seg, k_max, 2))
    z_mask = np.zeros((n_seg, k_max), bool)
    truth = np.zeros((n_seg, 3))
    x = np.zeros(3)
    for t in range(n_seg):
        for j in range(2):
            h = dt / 2
            x = np.array(
                [
                    x[0] + v * h * math.cos(x[2] + omega * h / 2),
                    x[1] + v * h * math.sin(x[2] + omega * h / 2),
                    x[2] + omega * h,
                ]
            )
            u[t, j] = [v + SIGMA_V * rng.normal(), omega + SIGMA_OMEGA * rng.normal()]
        truth[t] = x
    # the walls in the sensor frame, written out here: rho_s = rho - n . p, alpha_s = alpha - theta
    n_x, n_y = np.cos(ROOM[:, 1]), np.sin(ROOM[:, 1])
    rho_s = ROOM[None, :, 0] - n_x * truth[:, :1] - n_y * truth[:, 1:2]
    alpha_s = _wrap(ROOM[None, :, 1] - truth[:, 2:] + np.where(rho_s < 0, np.pi, 0.0))
    z_true = np.stack([np.abs(rho_s), alpha_s], -1)
    for t in range(n_seg):
        zt = z_true[t]
        seen = np.abs(zt[:, 1]) < np.radians(85)
        n = int(seen.sum())
        z[t, :n] = zt[seen] + rng.normal(size=(n, 2)) * [SIGMA_RHO, SIGMA_ALPHA]
        z[t, :n, 1] = _wrap(z[t, :n, 1])
        z_mask[t, :n] = True
    seg = Segments(
        time=np.arange(1, n_seg + 1) * dt,
        dt=np.full((n_seg, 2), dt / 2),
        u=u,
        dr_mask=np.ones((n_seg, 2), bool),
        z=z,
        z_mask=z_mask,
        diam=np.zeros((n_seg, k_max)),
        is_scan=np.ones(n_seg, bool),
        z_id=np.full((n_seg, k_max), -1, np.int32),
    )
    return jax.tree.map(jnp.asarray, seg), truth


@pytest.mark.slow
@pytest.mark.parametrize("method", ["fastslam1", "ekf_slam"])
def test_filter_with_line_landmarks_recovers_the_walls_of_a_room(method):
    seg, truth = _room_log()
    cfg = load_config(
        None,
        [
            f"filter.method={method}",
            "filter.n_particles=30",
            "model.motion=unicycle",
            f"unicycle.sigma_v={SIGMA_V}",
            f"unicycle.sigma_omega_deg={math.degrees(SIGMA_OMEGA)}",
            "model.measurement=line",
            f"model.measurement_params.sigma_rho={SIGMA_RHO}",
            f"model.measurement_params.sigma_alpha={SIGMA_ALPHA}",
            "model.measurement_params.max_range=20",
            f"model.measurement_params.half_fov={math.radians(80)}",
            "filter.capacity=16",
            "filter.window=16",
            "filter.window_margin=1000",
            "filter.init_cov=1e-8",
            "map.occlusion=false",
        ],
    )
    static, params = settings_from_config(cfg, seg.k_max)
    run = run_filter(static, params, seg, 0)
    lm = jax.tree.map(np.asarray, reported_map(run.state))
    est = lm.mean[lm.active & lm.confirmed]
    err = line_feature_errors(est, ROOM, gate=0.3)
    assert err["n_matched"] == 4 and len(est) == 4, (est, err)
    assert np.max(np.abs(err["rho_error"])) < 0.05, err
    assert np.max(np.abs(err["alpha_error"])) < math.radians(1.0), err
    pose = np.asarray(run.outputs.best_pose)
    pos_err = np.hypot(*(pose[:, :2] - truth[:, :2]).T)
    assert np.sqrt(np.mean(pos_err**2)) < 0.05


# ---------------------------------------------------------------------------------------------
# Table 1 metrics on a hand-built map with known offsets


def test_table1_metrics_give_the_offsets_built_into_a_map():
    # true walls y = 0.5 x + 1, y = -2 (horizontal), x = 5 (vertical), x = 0.2 y - 3 (steep)
    true = np.stack(
        [
            np.asarray(line_from_slope_intercept(0.5, 1.0)),
            np.asarray(line_from_slope_intercept(0.0, -2.0)),
            np.asarray(line_from_vertical(5.0)),
            _normal_form(np.array([-3.0, 0.0]), np.array([-2.8, 1.0])),
        ]
    )
    # estimates: slope and intercept offsets in the paper's form, listed in another order
    est = np.stack(
        [
            _normal_form(np.array([-3.01, 0.0]), np.array([-2.8 - 0.01 + 0.03, 1.0])),  # a' + 0.03, c - 0.01
            np.asarray(line_from_vertical(5.02)),  # c + 0.02
            np.asarray(line_from_slope_intercept(0.5 + 0.02, 1.0 - 0.015)),
            np.asarray(line_from_slope_intercept(0.0, -2.0 + 0.008)) * [-1, 1] + [0, np.pi],
        ]
    )  # rho < 0
    err = line_feature_errors(est, true)
    np.testing.assert_array_equal(err["match"], [2, 3, 1, 0])
    np.testing.assert_array_equal(err["steep"], [False, False, True, True])
    np.testing.assert_allclose(err["slope_error"], [0.02, 0.0, 0.0, 0.03], atol=1e-12)
    np.testing.assert_allclose(err["intercept_error"], [-0.015, 0.008, 0.02, -0.01], atol=1e-12)
    np.testing.assert_allclose(err["rho_error"][1:3], [-0.008, 0.02], atol=1e-12)  # y = -2: rho 2, alpha -pi/2
    np.testing.assert_allclose(err["alpha_error"][1:3], 0.0, atol=1e-12)

    arcs_true = np.array([[2.0, 3.0, 0.5], [-1.0, -1.0, 0.3]])
    arcs_est = np.array([[-1.0 + 0.006, -1.0 - 0.008, 0.31], [2.0, 3.0 + 0.015, 0.5 - 0.013], [9.0, 9.0, 1.0]])
    arcs = arc_feature_errors(arcs_est, arcs_true)
    np.testing.assert_array_equal(arcs["match"], [1, 0])
    np.testing.assert_allclose(arcs["centre_error"], [0.015, 0.01], atol=1e-12)
    np.testing.assert_allclose(arcs["radius_error"], [-0.013, 0.01], atol=1e-12)

    breaks_true = np.array([[0.0, 1.0], [4.0, -2.0]])
    breaks_est = np.array([[4.0 + 0.012, -2.0 + 0.016], [0.021, 1.0], [20.0, 20.0]])
    pts = point_feature_errors(breaks_est, breaks_true)
    np.testing.assert_allclose(pts["error"], [0.021, 0.02], atol=1e-12)

    # corners from the lines: y = -2 meets x = 5 at (5, -2); shift x = 5 by 0.02 -> (5.02, -2.0 + 0.008)
    table = feature_map_errors(
        est,
        true,
        est_arcs=arcs_est,
        true_arcs=arcs_true,
        corners=[[1, 2], [0, 1]],
        est_break_points=breaks_est,
        true_break_points=breaks_true,
    )
    corners = table["corners"]
    np.testing.assert_allclose(corners["true"], [[5.0, -2.0], [-6.0, -2.0]], atol=1e-12)
    np.testing.assert_allclose(corners["error"][0], math.hypot(0.02, 0.008), atol=1e-12)
    # y = 0.52 x + 0.985 meets y = -1.992 at x = -2.977 / 0.52
    np.testing.assert_allclose(corners["estimate"][1], [-2.977 / 0.52, -1.992], atol=1e-12)
    s = table["summary"]
    np.testing.assert_allclose(s["line_slope_median"], np.median([0.02, 0.0, 0.0, 0.03]))
    np.testing.assert_allclose(s["line_slope_worst"], 0.03)
    np.testing.assert_allclose(s["line_intercept_worst"], 0.02)
    np.testing.assert_allclose(s["arc_centre_worst"], 0.015)
    np.testing.assert_allclose(s["arc_radius_median"], 0.0115)
    np.testing.assert_allclose(s["break_point_median"], 0.0205)
    assert (s["n_lines"], s["n_lines_matched"], s["n_arcs_matched"], s["n_corners_matched"]) == (4, 4, 2, 2)


def test_table1_metrics_leave_far_features_unmatched_and_intersect_lines():
    err = line_feature_errors(np.array([[10.0, 0.0]]), np.array([[2.0, 0.0], [2.0, np.pi / 2]]), gate=0.5)
    assert err["n_matched"] == 0 and np.isnan(err["slope_error"]).all()
    table = feature_map_errors(np.zeros((0, 2)), np.array([[2.0, 0.0], [2.0, np.pi / 2]]), corners=[[0, 1]])
    assert np.isnan(table["corners"]["error"]).all() and table["summary"]["n_corners_matched"] == 0
    assert np.isnan(table["summary"]["corner_median"])
    np.testing.assert_allclose(line_intersections([[2.0, 0.0]], [[3.0, np.pi / 2]]), [[2.0, 3.0]], atol=1e-12)
    assert np.isnan(line_intersections([[2.0, 0.0]], [[3.0, 0.0]])).all()
    with pytest.raises(ValueError, match="corners"):
        feature_map_errors(np.zeros((0, 2)), np.array([[2.0, 0.0]]), corners=[[0, 1]])


def test_table1_metrics_of_a_diverged_map_leave_its_non_finite_lines_unmatched():
    """A run that went non-finite is scored (its NaN lines match nothing), not stopped by the
    assignment."""
    true = np.array([[2.0, 0.0], [3.0, np.pi / 2]])
    est = np.array([[np.nan, np.nan], [3.01, np.pi / 2], [np.inf, 0.0]])
    err = line_feature_errors(est, true, gate=0.5)
    assert err["n_matched"] == 1 and list(err["match"]) == [-1, 1]
    np.testing.assert_allclose(err["rho_error"][1], 0.01, atol=1e-12)
