"""The vectorisable sine, cosine, tangent and arctangent against NumPy (libm) and their
derivatives against the analytic rules and finite differences."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nanoslam_jax.lib import _trig as trig

ULP = np.finfo(np.float64).eps


@pytest.mark.parametrize("scale", [1e-12, 1e-4, 0.3, 1.0, np.pi, 10.0, 1e3, 1e6])
def test_sincos_matches_libm(scale):
    x = np.random.default_rng(1).uniform(-scale, scale, 100_000)
    x = np.concatenate([x, np.arange(-40, 41) * (np.pi / 4)])  # quadrant edges
    s, c = (np.asarray(a) for a in trig.sincos(x))
    # Absolute error of a correctly reduced argument: a couple of ulps of the result's scale.
    np.testing.assert_allclose(s, np.sin(x), rtol=0, atol=3 * ULP)
    np.testing.assert_allclose(c, np.cos(x), rtol=0, atol=3 * ULP)
    big = np.abs(np.sin(x)) > 1e-3
    np.testing.assert_allclose(s[big], np.sin(x)[big], rtol=4 * ULP)
    np.testing.assert_allclose(np.asarray(trig.sin(x)), s, rtol=0, atol=0)
    np.testing.assert_allclose(np.asarray(trig.cos(x)), c, rtol=0, atol=0)


def test_small_angles_are_relatively_accurate():
    x = np.geomspace(1e-300, 1e-2, 2000)
    np.testing.assert_allclose(np.asarray(trig.sin(x)), np.sin(x), rtol=2 * ULP)
    np.testing.assert_allclose(np.asarray(trig.sin(-x)), -np.sin(x), rtol=2 * ULP)
    np.testing.assert_allclose(np.asarray(trig.tan(x)), np.tan(x), rtol=4 * ULP)


def test_tan_matches_libm():
    x = np.random.default_rng(2).uniform(-1.5, 1.5, 100_000)
    np.testing.assert_allclose(np.asarray(trig.tan(x)), np.tan(x), rtol=6 * ULP, atol=2 * ULP)


@pytest.mark.parametrize("y_scale", [1e-200, 1e-8, 1.0, 1e8, 1e200])
@pytest.mark.slow
def test_atan2_matches_libm(y_scale):
    rng = np.random.default_rng(3)
    y, x = rng.normal(size=100_000) * y_scale, rng.normal(size=100_000)
    a, b = np.asarray(trig.atan2(y, x)), np.arctan2(y, x)
    np.testing.assert_allclose(a, b, rtol=4 * ULP, atol=2 * ULP)


@pytest.mark.slow
def test_atan2_at_reduction_edges_and_axes():
    angles = np.concatenate([np.arange(-16, 17) * (np.pi / 16), np.arange(-8, 9) * (np.pi / 8) + 1e-12])
    y, x = np.sin(angles), np.cos(angles)
    np.testing.assert_allclose(np.asarray(trig.atan2(y, x)), np.arctan2(y, x), rtol=0, atol=4 * ULP)


@pytest.mark.slow
def test_atan2_special_values_follow_numpy():
    v = np.array([0.0, -0.0, 1.0, -1.0, np.inf, -np.inf, np.nan])
    Y, X = np.meshgrid(v, v)
    a, b = np.asarray(trig.atan2(Y, X)), np.arctan2(Y, X)
    np.testing.assert_array_equal(a, b)  # NaN positions equal too
    finite = ~np.isnan(b)
    np.testing.assert_array_equal(np.signbit(a[finite]), np.signbit(b[finite]))


def test_sincos_nonfinite_is_nan():
    s, c = trig.sincos(np.array([np.inf, -np.inf, np.nan]))
    assert np.all(np.isnan(np.asarray(s))) and np.all(np.isnan(np.asarray(c)))


@pytest.mark.slow
def test_derivatives_are_the_analytic_ones():
    x = np.linspace(-7.0, 7.0, 101)
    ds = jax.vmap(jax.grad(trig.sin))(x)
    dc = jax.vmap(jax.grad(trig.cos))(x)
    d2s = jax.vmap(jax.grad(jax.grad(trig.sin)))(x)
    np.testing.assert_allclose(ds, np.cos(x), atol=3 * ULP)
    np.testing.assert_allclose(dc, -np.sin(x), atol=3 * ULP)
    np.testing.assert_allclose(d2s, -np.sin(x), atol=3 * ULP)
    dt = jax.vmap(jax.grad(trig.tan))(x[np.abs(np.cos(x)) > 0.1])
    np.testing.assert_allclose(dt, 1.0 / np.cos(x[np.abs(np.cos(x)) > 0.1]) ** 2, rtol=1e-14)
    y, xx = np.random.default_rng(4).normal(size=(2, 50))
    gy, gx = jax.vmap(jax.grad(trig.atan2, argnums=(0, 1)))(y, xx)
    q = xx**2 + y**2
    np.testing.assert_allclose(gy, xx / q, rtol=1e-14)
    np.testing.assert_allclose(gx, -y / q, rtol=1e-14)
    # Second derivatives by autodiff of the rule vs central differences of the first.
    h = 1e-6
    hyy = jax.vmap(jax.grad(jax.grad(trig.atan2)))(y, xx)
    fd = (jax.vmap(jax.grad(trig.atan2))(y + h, xx) - jax.vmap(jax.grad(trig.atan2))(y - h, xx)) / (2 * h)
    np.testing.assert_allclose(hyy, fd, rtol=1e-6, atol=1e-6)


@pytest.mark.slow
def test_float32_inputs_stay_float32_and_accurate():
    x = np.random.default_rng(5).uniform(-10, 10, 10_000).astype(np.float32)
    s, c = trig.sincos(jnp.asarray(x))
    assert s.dtype == jnp.float32 and c.dtype == jnp.float32
    np.testing.assert_allclose(np.asarray(s), np.sin(x.astype(np.float64)), atol=1e-6)
    a = trig.atan2(jnp.asarray(x), jnp.asarray(x[::-1]))
    assert a.dtype == jnp.float32
    np.testing.assert_allclose(np.asarray(a), np.arctan2(x.astype(np.float64), x[::-1].astype(np.float64)), atol=1e-6)


def test_computed_once_changes_no_value_under_jit_vmap_and_jvp():
    """The fusion barrier is the identity: same values, and derivatives pass through it."""
    rng = np.random.default_rng(3)
    x = jnp.asarray(rng.uniform(-10, 10, (7,)))

    def f(a):
        s, c = trig.computed_once(trig.sincos(a))
        return s * c + s

    ref = np.sin(np.asarray(x)) * np.cos(np.asarray(x)) + np.sin(np.asarray(x))
    np.testing.assert_allclose(jax.jit(jax.vmap(f))(x), ref, rtol=1e-14, atol=1e-14)
    _, tangent = jax.jvp(jax.vmap(f), (x,), (jnp.ones_like(x),))
    xs = np.asarray(x)
    np.testing.assert_allclose(tangent, np.cos(2 * xs) + np.cos(xs), rtol=1e-12, atol=1e-12)


def test_computed_once_keeps_a_pytree_and_rejects_mixed_dtypes():
    tree = {"a": jnp.arange(6.0).reshape(2, 3), "b": (jnp.array(2.5), jnp.ones(4))}
    out = jax.jit(trig.computed_once)(tree)
    assert jax.tree.structure(out) == jax.tree.structure(tree)
    for x, y in zip(jax.tree.leaves(out), jax.tree.leaves(tree)):
        assert x.shape == y.shape
        np.testing.assert_array_equal(x, y)
    with pytest.raises(TypeError, match="one dtype"):
        trig.computed_once((jnp.ones(2), jnp.ones(2, jnp.int32)))
