"""Vehicle and range-bearing models: closed-form Jacobians, finite differences, geometry."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from nanoslam_jax.models import (
    VehicleParams,
    centre_speed,
    circular_mean,
    innovation,
    inverse_range_bearing,
    inverse_range_bearing_jacobians,
    range_bearing,
    range_bearing_components,
    range_bearing_jacobian_components,
    range_bearing_jacobians,
    vehicle_jacobians,
    vehicle_step,
    wrap_angle,
)

PARAMS = VehicleParams()


def random_pose(rng, phi=None):
    return np.array([*rng.uniform(-50, 50, size=2), rng.uniform(-np.pi, np.pi) if phi is None else phi])


def landmark_at(x, r, beta):
    """Landmark seen from pose x at range r and bearing beta (the inverse model, in NumPy)."""
    return np.array([x[0] + r * np.cos(x[2] + beta), x[1] + r * np.sin(x[2] + beta)])


# ----------------------------------------------------------------------------- hand-derived Jacobians


def vehicle_jacobians_by_hand(x, u, dt, p):
    """d f / d x (3x3) and d f / d u (3x2) of vehicle_step, derived from the vehicle model (docs/method/victoria-park.md).

    With D = 1 - tan(alpha) H / L, vc = ve / D, w = vc tan(alpha) / L:
      dvc/dve = 1/D,            dvc/dalpha = ve H sec^2(alpha) / (L D^2)
      dw/dve  = tan(alpha)/(L D), dw/dalpha = ve sec^2(alpha) / (L D^2)
        (d/dalpha [tan / D] = sec^2 (D + tan H / L) / D^2 = sec^2 / D^2)
    and the rates xdot = vc c - w (a s + b c), ydot = vc s + w (a c - b s), phidot = w.
    """
    _, _, phi = x
    ve, al = u
    L, H, a, b = p.wheelbase, p.encoder_offset, p.laser_a, p.laser_b
    s, c, t = np.sin(phi), np.cos(phi), np.tan(al)
    sec2 = 1.0 / np.cos(al) ** 2
    D = 1.0 - t * H / L
    vc, w = ve / D, ve * t / (L * D)
    xdot = vc * c - w * (a * s + b * c)
    ydot = vc * s + w * (a * c - b * s)
    Fx = np.array([[1.0, 0.0, -dt * ydot], [0.0, 1.0, dt * xdot], [0.0, 0.0, 1.0]])
    dvc = np.array([1.0 / D, ve * H * sec2 / (L * D**2)])
    dw = np.array([t / (L * D), ve * sec2 / (L * D**2)])
    Fu = dt * np.stack([dvc * c - dw * (a * s + b * c), dvc * s + dw * (a * c - b * s), dw])
    return Fx, Fu


def range_bearing_jacobians_by_hand(x, m):
    """Gx (2x3), Gm (2x2) of (r, beta) with dx = mx - px, dy = my - py, q = dx^2 + dy^2."""
    dx, dy = m[0] - x[0], m[1] - x[1]
    q = dx * dx + dy * dy
    r = np.sqrt(q)
    Gx = np.array([[-dx / r, -dy / r, 0.0], [dy / q, -dx / q, -1.0]])
    Gm = np.array([[dx / r, dy / r], [-dy / q, dx / q]])
    return Gx, Gm


def inverse_jacobians_by_hand(x, z):
    """Jacobians of m = p + r (cos, sin)(phi + beta) w.r.t. the pose (2x3) and z = (r, beta) (2x2)."""
    r, th = z[0], x[2] + z[1]
    s, c = np.sin(th), np.cos(th)
    return np.array([[1.0, 0.0, -r * s], [0.0, 1.0, r * c]]), np.array([[c, -r * s], [s, r * c]])


def wrapped_fd_jacobian(f, x, angle_out, h=1e-6):
    """Central differences of f at x; the output component angle_out is differenced wrapped."""
    x = np.asarray(x, dtype=float)
    steps = h * np.eye(x.size)
    d = np.asarray(jax.vmap(f)(jnp.asarray(x + steps))) - np.asarray(jax.vmap(f)(jnp.asarray(x - steps)))
    d[:, angle_out] = np.mod(d[:, angle_out] + np.pi, 2 * np.pi) - np.pi
    return d.T / (2 * h)


def check_derivatives(f, args, h=1e-5):
    """Autodiff of ``f`` (batched over the leading axis of every arg) against finite differences.

    jax.test_util.check_grads covers order 1 in forward and reverse mode and order 2 in forward
    mode; the reverse-mode second derivatives (forward-over-reverse Hessians) are compared with
    central differences of the reverse-mode Jacobian (cheaper than check_grads' rev-over-rev).
    """
    args = tuple(jnp.asarray(a) for a in args)
    fb = jax.jit(jax.vmap(f))
    check_grads(fb, args, order=1, modes=("fwd", "rev"))
    check_grads(fb, args, order=2, modes=("fwd",))
    cut = np.cumsum([a.shape[-1] for a in args])[:-1]
    g = lambda v: f(*jnp.split(v, cut))  # noqa: E731
    v = jnp.concatenate(args, axis=-1)
    jac = jax.jit(jax.vmap(jax.jacrev(g)))
    hess = np.asarray(jax.jit(jax.vmap(jax.jacfwd(jax.jacrev(g))))(v))  # (batch, out, n, n)
    steps = h * np.eye(v.shape[-1])
    fd = np.stack([(jac(v + e) - jac(v - e)) / (2 * h) for e in steps], axis=-1)
    np.testing.assert_allclose(hess, fd, rtol=1e-6, atol=1e-6 * (1 + np.abs(hess).max()))


# module-level jitted wrappers: compiled once, shared by parametrised tests (keeps the file fast)
step = jax.jit(lambda x, u, dt: vehicle_step(x, u, dt, PARAMS))
step_jac_fwd = jax.jit(jax.jacfwd(step, argnums=(0, 1)))
step_jac_rev = jax.jit(jax.jacrev(step, argnums=(0, 1)))
rb_jac_fwd = jax.jit(range_bearing_jacobians)
rb_jac_rev = jax.jit(jax.jacrev(range_bearing, argnums=(0, 1)))


def random_controls(rng):
    return np.array([rng.uniform(-1.0, 8.0), rng.uniform(-0.5, 0.5)])


# Random cases, batched: one jit-compiled vmapped call checks them all (keeps the file fast).
N_CASES = 16


def vehicle_cases(seed, phi_range=(-np.pi, np.pi)):
    rng = np.random.default_rng(seed)
    xs = np.stack([random_pose(rng, phi=rng.uniform(*phi_range)) for _ in range(N_CASES)])
    us = np.stack([random_controls(rng) for _ in range(N_CASES)])
    return xs, us


def landmark_cases(seed, betas=None):
    rng = np.random.default_rng(seed)
    xs = np.stack([random_pose(rng) for _ in range(N_CASES)])
    if betas is None:
        betas = rng.uniform(-np.pi, np.pi, N_CASES)
    ms = np.stack([landmark_at(x, rng.uniform(3.0, 30.0), b) for x, b in zip(xs, betas)])
    return xs, ms, np.asarray(betas)


# ----------------------------------------------------------------------------- vehicle Jacobians


@pytest.mark.slow
def test_vehicle_jacobians_match_closed_form():
    xs, us = vehicle_cases(0)
    dt = 0.025
    jac_fwd = jax.jit(jax.vmap(lambda x, u: vehicle_jacobians(x, u, dt, PARAMS)))  # the library's helper
    for Fx, Fu in (jac_fwd(xs, us), jax.vmap(step_jac_rev, (0, 0, None))(xs, us, dt)):
        for k in range(N_CASES):
            Fx_h, Fu_h = vehicle_jacobians_by_hand(xs[k], us[k], dt, PARAMS)
            np.testing.assert_allclose(Fx[k], Fx_h, rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(Fu[k], Fu_h, rtol=1e-12, atol=1e-12)


@pytest.mark.slow
def test_vehicle_step_check_grads():
    # heading kept away from the +-pi cut so that finite differences stay on one side
    xs, us = vehicle_cases(1, phi_range=(-2.5, 2.5))
    check_derivatives(lambda x, u: vehicle_step(x, u, 0.1, PARAMS), (xs, us))


@pytest.mark.parametrize("phi", [np.pi - 1e-3, np.pi, -np.pi + 1e-4])
@pytest.mark.slow
def test_vehicle_jacobian_across_heading_wrap(phi):
    # turning left across the +-pi cut: the wrapped heading jumps, its derivative does not
    x, u, dt = np.array([3.0, -2.0, phi]), np.array([5.0, 0.3]), 0.025
    assert float(step(x, u, dt)[2]) < 0 < phi or phi < 0  # the step crosses (or starts past) the cut
    Fx_h, Fu_h = vehicle_jacobians_by_hand(x, u, dt, PARAMS)
    for Fx, Fu in (step_jac_fwd(x, u, dt), step_jac_rev(x, u, dt)):
        np.testing.assert_allclose(Fx, Fx_h, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(Fu, Fu_h, rtol=1e-12, atol=1e-12)
    fd_x = wrapped_fd_jacobian(lambda x: step(x, u, dt), x, angle_out=2)
    fd_u = wrapped_fd_jacobian(lambda u: step(x, u, dt), u, angle_out=2)
    np.testing.assert_allclose(Fx_h, fd_x, rtol=1e-7, atol=1e-8)
    np.testing.assert_allclose(Fu_h, fd_u, rtol=1e-7, atol=1e-8)


# ----------------------------------------------------------------------------- range-bearing Jacobians


def test_range_bearing_jacobians_match_closed_form():
    xs, ms, _ = landmark_cases(100)
    for Gx, Gm in (jax.vmap(rb_jac_fwd)(xs, ms), jax.vmap(rb_jac_rev)(xs, ms)):
        for k in range(N_CASES):
            Gx_h, Gm_h = range_bearing_jacobians_by_hand(xs[k], ms[k])
            np.testing.assert_allclose(Gx[k], Gx_h, rtol=1e-12, atol=1e-14)
            np.testing.assert_allclose(Gm[k], Gm_h, rtol=1e-12, atol=1e-14)


@pytest.mark.slow
def test_range_bearing_component_jacobian_matches_closed_form():
    # The per-component form (one array per coordinate, a jvp per input) used over a window of
    # landmarks: the same model and the same Jacobian entries, evaluated on a whole batch at once.
    xs, ms, _ = landmark_cases(101)
    (r, b), J = jax.jit(range_bearing_jacobian_components)(xs[:, 0], xs[:, 1], xs[:, 2], ms[:, 0], ms[:, 1])
    rb = jax.vmap(range_bearing)(xs, ms)
    np.testing.assert_allclose(np.stack([r, b], -1), rb, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(
        np.stack(range_bearing_components(xs[:, 0], xs[:, 1], xs[:, 2], ms[:, 0], ms[:, 1]), -1),
        rb,
        rtol=1e-14,
        atol=1e-15,
    )
    J = np.asarray(J)  # (2 outputs, 5 inputs, cases)
    for k in range(N_CASES):
        Gx_h, Gm_h = range_bearing_jacobians_by_hand(xs[k], ms[k])
        np.testing.assert_allclose(J[:, :3, k], Gx_h, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(J[:, 3:, k], Gm_h, rtol=1e-12, atol=1e-14)


@pytest.mark.slow
def test_range_bearing_check_grads_one_side_of_cut():
    # Bearings include +-(pi - 0.02): eps = 1e-4 perturbations move the bearing by ~1e-4 * |v| / r,
    # far less than the 0.02 to the cut, so the finite differences stay on one side.
    betas = np.tile([0.4, -2.0, np.pi - 0.02, -np.pi + 0.02], N_CASES // 4)
    xs, ms, _ = landmark_cases(200, betas)
    np.testing.assert_allclose(jax.vmap(range_bearing)(xs, ms)[:, 1], betas, atol=1e-9)
    # (the Jacobian itself is continuous across the cut, so its differences need no wrapping)
    check_derivatives(range_bearing, (xs, ms))


@pytest.mark.parametrize("beta", [np.pi, np.pi - 1e-9, -np.pi + 1e-9])
@pytest.mark.slow
def test_range_bearing_jacobian_continuous_across_wrap(beta):
    x = np.array([1.0, 2.0, 0.7])
    m = landmark_at(x, 7.0, beta)
    Gx_h, Gm_h = range_bearing_jacobians_by_hand(x, m)
    for Gx, Gm in (rb_jac_fwd(x, m), rb_jac_rev(x, m)):
        np.testing.assert_allclose(Gx, Gx_h, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(Gm, Gm_h, rtol=1e-9, atol=1e-12)
    # wrapped central differences straddle the cut without trouble
    rb = jax.jit(range_bearing)
    np.testing.assert_allclose(Gx_h, wrapped_fd_jacobian(lambda x: rb(x, m), x, angle_out=1), rtol=1e-7, atol=1e-8)
    np.testing.assert_allclose(Gm_h, wrapped_fd_jacobian(lambda m: rb(x, m), m, angle_out=1), rtol=1e-7, atol=1e-8)


@pytest.mark.slow
def test_inverse_range_bearing_jacobians():
    rng = np.random.default_rng(300)
    xs = np.stack([random_pose(rng) for _ in range(N_CASES)])
    zs = np.stack([rng.uniform(1.0, 30.0, N_CASES), rng.uniform(-np.pi, np.pi, N_CASES)], axis=1)
    Jx, Jz = jax.jit(jax.vmap(inverse_range_bearing_jacobians))(xs, zs)
    # G_new of the filter: Gm of the forward model inverts the z-Jacobian of the inverse model
    _, Gm = jax.jit(jax.vmap(range_bearing_jacobians))(xs, jax.vmap(inverse_range_bearing)(xs, zs))
    for k in range(N_CASES):
        Jx_h, Jz_h = inverse_jacobians_by_hand(xs[k], zs[k])
        np.testing.assert_allclose(Jx[k], Jx_h, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(Jz[k], Jz_h, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(Gm[k] @ Jz[k], np.eye(2), atol=1e-10)
    check_derivatives(inverse_range_bearing, (xs, zs))


def test_inverse_round_trip():
    rng = np.random.default_rng(400)
    xs = np.stack([random_pose(rng) for _ in range(N_CASES)])
    zs = np.stack([rng.uniform(0.5, 40.0, N_CASES), rng.uniform(-np.pi, np.pi, N_CASES)], axis=1)
    ms = rng.uniform(-60, 60, size=(N_CASES, 2))
    rb, inv = jax.vmap(range_bearing), jax.vmap(inverse_range_bearing)
    np.testing.assert_allclose(rb(xs, inv(xs, zs)), zs, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(inv(xs, rb(xs, ms)), ms, rtol=1e-10, atol=1e-10)


@pytest.mark.slow
def test_round_trip_bearing_pi_and_innovation_wrap():
    x = np.array([0.0, 0.0, 0.0])
    z = range_bearing(x, np.array([-5.0, 0.0]))  # directly behind
    assert float(z[1]) == pytest.approx(np.pi) and float(z[0]) == pytest.approx(5.0)
    d = innovation(jnp.array([5.0, -np.pi + 0.01]), jnp.array([4.0, np.pi - 0.01]))
    np.testing.assert_allclose(d, [1.0, 0.02], atol=1e-12)


# ----------------------------------------------------------------------------- angles


@pytest.mark.slow
def test_wrap_angle_properties():
    rng = np.random.default_rng(0)
    a = np.concatenate([rng.uniform(-50, 50, 2000), np.arange(-7, 8) * np.pi, [0.0, 1e-300, -1e-300]])
    w = np.asarray(wrap_angle(a))
    assert np.all(w > -np.pi) and np.all(w <= np.pi)
    assert float(wrap_angle(np.pi)) == np.pi
    assert float(wrap_angle(-np.pi)) == np.pi
    assert float(wrap_angle(3 * np.pi)) == pytest.approx(np.pi)
    np.testing.assert_array_equal(np.asarray(wrap_angle(w)), w)  # idempotent
    k = rng.integers(-5, 6, size=a.size)
    # wrap(a + 2 k pi) == wrap(a), compared on the circle (a value at the cut may land on either end)
    diff = np.asarray(wrap_angle(wrap_angle(a + 2 * np.pi * k) - w))
    np.testing.assert_allclose(diff, 0.0, atol=1e-12)
    # away from the cut the values themselves agree
    inner = np.abs(w) < np.pi - 1e-6
    np.testing.assert_allclose(np.asarray(wrap_angle(a + 2 * np.pi * k))[inner], w[inner], atol=1e-12)
    # a - wrap(a) is a multiple of 2 pi; the derivative is 1
    turns = (a - w) / (2 * np.pi)
    np.testing.assert_allclose(turns, np.round(turns), atol=1e-12)
    np.testing.assert_allclose(jax.vmap(jax.grad(wrap_angle))(jnp.asarray(a)), 1.0)


def test_circular_mean():
    ang = jnp.array([np.pi - 0.1, -np.pi + 0.1, np.pi - 0.05, -np.pi + 0.05])
    assert abs(float(wrap_angle(circular_mean(ang, jnp.ones(4)) - np.pi))) < 1e-12
    assert float(circular_mean(jnp.array([0.1, 0.3]), jnp.array([3.0, 1.0]))) == pytest.approx(0.15, abs=1e-3)


# ----------------------------------------------------------------------------- vehicle geometry


def test_centre_speed_formula_and_geometry():
    L, H = PARAMS.wheelbase, PARAMS.encoder_offset
    assert float(centre_speed(3.0, 0.0, PARAMS)) == 3.0
    for ve, al in [(3.0, 0.2), (5.0, -0.4), (-1.0, 0.1)]:
        assert float(centre_speed(ve, al, PARAMS)) == pytest.approx(ve / (1 - np.tan(al) * H / L), rel=1e-14)
    # the rear-left wheel sits H left of the axle centre: radius R - H about the ICR, R = L / tan(alpha)
    for vc, al in [(4.0, 0.25), (4.0, -0.25)]:
        R = L / np.tan(al)
        assert float(centre_speed(vc * (R - H) / R, al, PARAMS)) == pytest.approx(vc, rel=1e-13)


def test_dt_zero_is_identity():
    rng = np.random.default_rng(1)
    xs = np.stack([random_pose(rng) for _ in range(20)] + [np.array([1.0, 2.0, np.pi])])
    us = np.stack([random_controls(rng) for _ in range(21)])
    out = jax.vmap(step, (0, 0, None))(xs, us, 0.0)
    np.testing.assert_array_equal(out, xs)
    Fx, Fu = step_jac_fwd(xs[0], us[0], 0.0)
    np.testing.assert_array_equal(Fx, np.eye(3))
    np.testing.assert_array_equal(Fu, np.zeros((3, 2)))


def test_straight_driving():
    rng = np.random.default_rng(2)
    for _ in range(5):
        x, ve, dt = random_pose(rng), rng.uniform(0, 10), rng.uniform(0, 0.1)
        out = vehicle_step(x, np.array([ve, 0.0]), dt, PARAMS)
        np.testing.assert_allclose(out, x + ve * dt * np.array([np.cos(x[2]), np.sin(x[2]), 0.0]), atol=1e-12)


def exact_arc(x0, ve, alpha, t, p):
    """Laser pose at times t under constant controls, from the rigid-body circle about the ICR."""
    L, a, b = p.wheelbase, p.laser_a, p.laser_b
    vc = ve / (1 - np.tan(alpha) * p.encoder_offset / L)
    R, w = L / np.tan(alpha), vc * np.tan(alpha) / L
    phi0 = x0[2]
    rear0 = x0[:2] - np.array([a * np.cos(phi0) - b * np.sin(phi0), a * np.sin(phi0) + b * np.cos(phi0)])
    icr = rear0 + R * np.array([-np.sin(phi0), np.cos(phi0)])
    phi = phi0 + w * t
    rear = icr + R * np.stack([np.sin(phi), -np.cos(phi)], axis=-1)
    laser = rear + np.stack([a * np.cos(phi) - b * np.sin(phi), a * np.sin(phi) + b * np.cos(phi)], axis=-1)
    return np.concatenate([laser, np.asarray(wrap_angle(phi))[..., None]], axis=-1), icr, np.hypot(a, R - b)


@jax.jit
def integrate(x0, u, dt, n_steps_arr):
    def body(x, _):
        x = vehicle_step(x, u, dt, PARAMS)
        return x, x

    return jax.lax.scan(body, x0, None, length=n_steps_arr.shape[0])[1]


@pytest.mark.parametrize("alpha", [0.3, -0.2])
@pytest.mark.slow
def test_constant_steering_follows_circle(alpha):
    x0, ve, T = np.array([2.0, -1.0, 2.5]), 4.0, 12.0  # more than a full turn: the heading wraps
    errs = []
    for n in (4000, 8000, 16000):
        dt = T / n
        traj = np.asarray(integrate(jnp.asarray(x0), jnp.array([ve, alpha]), dt, jnp.zeros(n)))
        t = dt * np.arange(1, n + 1)
        exact, icr, rho = exact_arc(x0, ve, alpha, t, PARAMS)
        # every laser position is on the circle of radius sqrt(a^2 + (R - b)^2) about the ICR
        radial = np.abs(np.hypot(*(traj[:, :2] - icr).T) - rho)
        assert radial.max() < 0.02
        pos_err = np.hypot(*(traj[:, :2] - exact[:, :2]).T).max()
        head_err = np.abs(np.asarray(wrap_angle(traj[:, 2] - exact[:, 2]))).max()
        assert head_err < 1e-9  # the heading rate is exact: Euler integrates it without error
        errs.append(pos_err)
    assert errs[-1] < 0.03
    # Euler is first order: halving dt halves the error, so the limit is the exact arc
    np.testing.assert_allclose(np.array(errs[:-1]) / np.array(errs[1:]), 2.0, rtol=0.05)
