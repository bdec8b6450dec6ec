"""Gaussian quadrature rules: polynomial exactness against closed-form Gaussian moments."""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nanoslam_jax.models import wrap_angle
from nanoslam_jax.lib.quadrature import (
    Cubature,
    GaussHermite,
    QuadratureRule,
    Unscented,
    make_rule,
    robust_cholesky,
    sigma_point_cross_cov,
    sigma_point_stats,
)

# ----------------------------------------------------------------------------- closed forms


def random_gaussian(n, seed):
    rng = np.random.default_rng(seed)
    m = rng.normal(size=n)
    a = rng.normal(size=(n, n))
    return m, a @ a.T + 0.5 * np.eye(n)


def central_moment(idx, P):
    """E[prod_k y_{idx_k}] for y ~ N(0, P), by Isserlis' theorem (sum over pairings)."""
    idx = list(idx)
    if not idx:
        return 1.0
    if len(idx) % 2:
        return 0.0
    a, rest = idx[0], idx[1:]
    return sum(P[a, rest[j]] * central_moment(rest[:j] + rest[j + 1 :], P) for j in range(len(rest)))


def raw_moment(idx, m, P):
    """E[prod_k x_{idx_k}] for x ~ N(m, P): expand prod (m_i + y_i) over subsets."""
    total = 0.0
    for mask in itertools.product([0, 1], repeat=len(idx)):
        mean_part = np.prod([m[i] for i, b in zip(idx, mask) if b == 0])
        total += mean_part * central_moment([i for i, b in zip(idx, mask) if b == 1], P)
    return total


def monomials(n, degree):
    return list(itertools.combinations_with_replacement(range(n), degree))


_POINTS_CACHE = {}


def rule_moment(rule, idx, m, P, central=False):
    """sum_i wm_i prod_k X_i[idx_k] (NumPy on the rule's points, cached per (rule, m, P))."""
    key = (repr(rule), np.asarray(m).tobytes(), np.asarray(P).tobytes())
    if key not in _POINTS_CACHE:
        X, wm, _ = rule.points(jnp.asarray(m), jnp.asarray(P))
        _POINTS_CACHE[key] = (np.asarray(X), np.asarray(wm))
    X, wm = _POINTS_CACHE[key]
    if central:
        X = X - m
    return float(wm @ np.prod(X[:, list(idx)], axis=1))


def test_closed_forms_agree_with_textbook_formulas():
    m, P = random_gaussian(3, 0)
    for i in range(3):
        assert raw_moment((i,), m, P) == pytest.approx(m[i])
        for j in range(3):
            assert raw_moment((i, j), m, P) == pytest.approx(P[i, j] + m[i] * m[j])
            for k in range(3):
                third = m[i] * m[j] * m[k] + m[i] * P[j, k] + m[j] * P[i, k] + m[k] * P[i, j]
                assert raw_moment((i, j, k), m, P) == pytest.approx(third)
                for l in range(3):
                    fourth = P[i, j] * P[k, l] + P[i, k] * P[j, l] + P[i, l] * P[j, k]
                    assert central_moment((i, j, k, l), P) == pytest.approx(fourth)
    # and a Monte Carlo sanity check of a raw fourth moment
    rng = np.random.default_rng(1)
    x = rng.multivariate_normal(m, P, size=400_000)
    mc = np.mean(x[:, 0] ** 2 * x[:, 1] * x[:, 2])
    assert raw_moment((0, 0, 1, 2), m, P) == pytest.approx(mc, rel=0.05, abs=0.05)


# ----------------------------------------------------------------------------- exactness


EXACT = [
    (Cubature(), 3),
    (Unscented(), 3),
    (Unscented(alpha=0.9, beta=2.0, kappa=0.0), 3),
    (Unscented(alpha=0.5, beta=2.0, kappa=1.0), 3),
    (GaussHermite(order=2), 3),
    (GaussHermite(order=3), 5),
    (GaussHermite(order=4), 7),
]


@pytest.mark.parametrize("n", [2, 3])
@pytest.mark.parametrize("rule,degree", EXACT, ids=lambda v: repr(v) if isinstance(v, QuadratureRule) else None)
def test_polynomials_integrated_exactly_up_to_degree(rule, degree, n):
    m, P = random_gaussian(n, seed=10 * n + degree)
    X, wm, wc = rule.points(jnp.asarray(m), jnp.asarray(P))
    assert X.shape == (rule.num_points(n), n) and wm.shape == wc.shape == (rule.num_points(n),)
    scale = 1.0 + np.abs(m).max() + np.abs(P).max()
    for d in range(degree + 1):
        for idx in monomials(n, d):
            expected = raw_moment(idx, m, P)
            got = rule_moment(rule, idx, m, P)
            assert got == pytest.approx(expected, rel=1e-9, abs=1e-9 * scale**d), (d, idx)
    # all central moments of degree 4 via Isserlis where the rule's degree allows it
    if degree >= 4:
        for idx in monomials(n, 4):
            assert rule_moment(rule, idx, m, P, central=True) == pytest.approx(central_moment(idx, P), rel=1e-9)


@pytest.mark.parametrize("n", [2, 3])
def test_cubature_is_not_exact_for_degree_four(n):
    m, P = random_gaussian(n, seed=3)
    rule = Cubature()
    # E[y_0^4] = 3 P_00^2, but the cubature points give n * P_00^2 ... (here n < 3)
    errs = [abs(rule_moment(rule, idx, m, P, central=True) - central_moment(idx, P)) for idx in monomials(n, 4)]
    assert max(errs) > 1e-2 * np.abs(P).max() ** 2
    # explicitly in unit coordinates: E[xi_0^4] = 3 for N(0, I) but the rule gives n
    xi, wm, _ = rule.unit_points(n)
    assert float(wm @ xi[:, 0] ** 4) == pytest.approx(n)


@pytest.mark.parametrize("n", [2, 3])
def test_unscented_with_n_plus_kappa_three_matches_axis_fourth_moments(n):
    # With alpha = 1 and n + kappa = 3 the sigma points reproduce E[y_i^4] = 3 P_ii^2 along each
    # Cholesky axis (diagonal P: the coordinate axes), but not the mixed E[y_i^2 y_j^2].
    rng = np.random.default_rng(n)
    m, P = rng.normal(size=n), np.diag(rng.uniform(0.5, 2.0, size=n))
    good = Unscented(alpha=1.0, beta=2.0, kappa=3.0 - n)
    bad = Unscented(alpha=1.0, beta=2.0, kappa=0.0)
    for i in range(n):
        idx = (i,) * 4
        assert rule_moment(good, idx, m, P, central=True) == pytest.approx(3 * P[i, i] ** 2, rel=1e-9)
        assert rule_moment(bad, idx, m, P, central=True) == pytest.approx(n * P[i, i] ** 2, rel=1e-9)
    assert rule_moment(good, (0, 0, 1, 1), m, P, central=True) == pytest.approx(0.0, abs=1e-12)
    assert central_moment((0, 0, 1, 1), P) == pytest.approx(P[0, 0] * P[1, 1])


def test_unscented_one_dimensional_kappa_two_is_three_point_gauss_hermite():
    m, P = np.array([0.7]), np.array([[2.3]])
    ut = Unscented(alpha=1.0, beta=0.0, kappa=2.0)
    X_u, w_u, _ = ut.points(m, P)
    X_g, w_g, _ = GaussHermite(order=3).points(m, P)
    order_u, order_g = np.argsort(np.asarray(X_u[:, 0])), np.argsort(np.asarray(X_g[:, 0]))
    np.testing.assert_allclose(X_u[order_u], X_g[order_g], rtol=1e-12)
    np.testing.assert_allclose(w_u[order_u], w_g[order_g], rtol=1e-12)
    for d in range(6):
        assert rule_moment(ut, (0,) * d, m, P) == pytest.approx(raw_moment((0,) * d, m, P), rel=1e-10)


@pytest.mark.parametrize("alpha,beta,kappa", [(0.9, 2.0, 0.0), (1e-2, 2.0, 0.0), (1.0, 0.0, 3.0)])
def test_unscented_covariance_weights_recover_linear_map_exactly(alpha, beta, kappa):
    n, d = 3, 2
    m, P = random_gaussian(n, 7)
    rng = np.random.default_rng(8)
    A, b = rng.normal(size=(d, n)), rng.normal(size=d)
    X, wm, wc = Unscented(alpha=alpha, beta=beta, kappa=kappa).points(m, P)
    Y = X @ A.T + b
    mean, cov = sigma_point_stats(Y, wm, wc)
    np.testing.assert_allclose(mean, A @ m + b, rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(cov, A @ P @ A.T, rtol=1e-7, atol=1e-7)
    np.testing.assert_allclose(sigma_point_cross_cov(X, m, Y, mean, wc), P @ A.T, rtol=1e-7, atol=1e-7)
    # also the rule's own covariance of the points is P
    _, cov_x = sigma_point_stats(X, wm, wc)
    np.testing.assert_allclose(cov_x, P, rtol=1e-7, atol=1e-7)


def test_unscented_weights_formula():
    n, alpha, beta, kappa = 3, 0.9, 2.0, 0.5
    xi, wm, wc = Unscented(alpha=alpha, beta=beta, kappa=kappa).unit_points(n)
    lam = alpha**2 * (n + kappa) - n
    assert float(wm[0]) == pytest.approx(lam / (n + lam))
    assert float(wc[0]) == pytest.approx(lam / (n + lam) + 1 - alpha**2 + beta)
    np.testing.assert_allclose(wm[1:], 1 / (2 * (n + lam)))
    np.testing.assert_allclose(wc[1:], 1 / (2 * (n + lam)))
    np.testing.assert_allclose(xi[0], 0.0)
    np.testing.assert_allclose(xi[1 : n + 1], np.sqrt(n + lam) * np.eye(n))
    np.testing.assert_allclose(xi[n + 1 :], -np.sqrt(n + lam) * np.eye(n))


def test_gauss_hermite_points_and_weights():
    for p in (1, 2, 3, 5):
        xi, wm, wc = GaussHermite(order=p).unit_points(2)
        assert xi.shape == (p**2, 2) and GaussHermite(order=p).num_points(2) == p**2
        assert float(wm.sum()) == pytest.approx(1.0)
        np.testing.assert_array_equal(wm, wc)
    with pytest.raises(ValueError):
        GaussHermite(order=0)


# ----------------------------------------------------------------------------- API details


def test_make_rule_and_errors():
    assert isinstance(make_rule("cubature"), Cubature)
    ut = make_rule("unscented", alpha=0.9, beta=2.0, kappa=0.0)
    assert isinstance(ut, Unscented) and ut.alpha == 0.9
    gh = make_rule("gauss_hermite", order=4)
    assert isinstance(gh, GaussHermite) and gh.order == 4
    with pytest.raises(ValueError, match="cubature.*unscented.*gauss_hermite"):
        make_rule("sigma")
    with pytest.raises(TypeError):
        QuadratureRule()  # abstract


def test_points_robust_for_singular_covariance():
    m = jnp.array([1.0, 2.0, 3.0])
    v = jnp.array([1.0, -2.0, 0.5])
    P = jnp.outer(v, v)  # rank one
    for rule in (Cubature(), Unscented(alpha=0.9), GaussHermite(order=3)):
        X, wm, wc = rule.points(m, P)
        assert bool(jnp.all(jnp.isfinite(X)))
        mean, cov = sigma_point_stats(X, wm, wc if not isinstance(rule, Unscented) else wm)
        np.testing.assert_allclose(mean, m, atol=1e-9)
        np.testing.assert_allclose(cov, P, atol=1e-9)
    X, _, _ = Cubature().points(m, jnp.zeros((3, 3)))
    np.testing.assert_allclose(X, jnp.broadcast_to(m, X.shape), atol=1e-100)
    L = robust_cholesky(jnp.array([[4.0, 2.0], [2.0 + 1e-14, 3.0]]))  # slightly asymmetric
    np.testing.assert_allclose(L @ L.T, [[4.0, 2.0], [2.0, 3.0]], rtol=1e-10)
    assert float(L[0, 1]) == 0.0


@pytest.mark.parametrize("rule", [Cubature(), Unscented(alpha=0.9), GaussHermite(order=3)], ids=repr)
@pytest.mark.slow
def test_expect_pytree_jit_and_vmap(rule):
    n = 3
    _, P = random_gaussian(n, 11)
    means = jnp.asarray(np.random.default_rng(12).normal(size=(5, n)))

    def f(x):
        return {"lin": 2.0 * x, "sq": jnp.outer(x, x), "sin": jnp.sin(x[0])}

    batched = jax.jit(jax.vmap(lambda mu: rule.expect(f, mu, P)))(means)
    assert batched["lin"].shape == (5, n) and batched["sq"].shape == (5, n, n) and batched["sin"].shape == (5,)
    for k in range(5):
        eager = rule.expect(f, means[k], P)
        for key in eager:
            np.testing.assert_allclose(batched[key][k], eager[key], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(eager["lin"], 2.0 * means[k], rtol=1e-12)
        np.testing.assert_allclose(eager["sq"], P + jnp.outer(means[k], means[k]), rtol=1e-10)
    # the rule itself passes through jit as a pytree argument
    out = jax.jit(lambda r, mu: r.expect(f, mu, P))(rule, means[0])
    np.testing.assert_allclose(out["sin"], rule.expect(f, means[0], P)["sin"], rtol=1e-12)


def test_unscented_traced_alpha_one_compilation():
    m, P = random_gaussian(3, 13)
    traces = []

    @jax.jit
    def run(rule, mu, cov):
        traces.append(None)
        X, wm, wc = rule.points(mu, cov)
        Y = jnp.stack([jnp.sin(X[:, 0]) * X[:, 1], X[:, 2] ** 2], axis=1)
        return sigma_point_stats(Y, wm, wc), rule.expect(lambda x: jnp.exp(0.1 * x), mu, cov)

    for alpha in (0.3, 0.9, 1.0):
        rule = Unscented(alpha=jnp.asarray(alpha), beta=jnp.asarray(2.0), kappa=jnp.asarray(0.0))
        (mean_j, cov_j), e_j = run(rule, m, P)
        X, wm, wc = Unscented(alpha=alpha).points(m, P)
        Y = jnp.stack([jnp.sin(X[:, 0]) * X[:, 1], X[:, 2] ** 2], axis=1)
        mean_e, cov_e = sigma_point_stats(Y, wm, wc)
        np.testing.assert_allclose(mean_j, mean_e, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(cov_j, cov_e, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(e_j, Unscented(alpha=alpha).expect(lambda x: jnp.exp(0.1 * x), m, P), rtol=1e-12)
    assert len(traces) == 1


def test_gauss_hermite_order_is_static():
    leaves = jax.tree_util.tree_leaves(GaussHermite(order=4))
    assert leaves == []


# ----------------------------------------------------------------------------- angles


@jax.jit
def _angle_case(rule, m, P):
    """Stats of points straddling the +-pi cut (jitted once per rule: keeps the test fast)."""
    X, wm, wc = rule.points(m, P)
    Y = X.at[:, 1].set(wrap_angle(X[:, 1]))
    mean, cov = sigma_point_stats(Y, wm, wc, angle_index=1)
    naive = sigma_point_stats(Y, wm, wc)
    C = sigma_point_cross_cov(Y, mean, Y, mean, wc, x_angle_index=1, y_angle_index=1)
    # a map of the heading: z = (heading + 0.05 wrapped, cos(heading))
    Z = jnp.stack([wrap_angle(X[:, 1] + 0.05), jnp.cos(X[:, 1])], axis=1)
    z_mean, _ = sigma_point_stats(Z, wm, wc, angle_index=0)
    Cxz = sigma_point_cross_cov(Y, mean, Z, z_mean, wc, x_angle_index=1, y_angle_index=0)
    return Y, mean, cov, naive, C, z_mean, Cxz


@pytest.mark.parametrize("mu_angle", [np.pi - 0.01, np.pi, -np.pi + 0.02])
@pytest.mark.parametrize("rule", [Cubature(), Unscented(alpha=0.9), GaussHermite(order=3)], ids=repr)
def test_sigma_point_stats_angle_near_pi(rule, mu_angle):
    m = jnp.array([1.0, mu_angle])
    P = jnp.array([[0.5, 0.02], [0.02, 0.1**2]])
    Y, mean, cov, (naive_mean, naive_cov), C, z_mean, Cxz = _angle_case(rule, m, P)
    assert bool(jnp.any(Y[:, 1] > 0)) and bool(jnp.any(Y[:, 1] < 0))  # points straddle the cut
    assert abs(float(wrap_angle(mean[1] - mu_angle))) < 1e-12
    assert abs(float(mean[1])) > 3.0  # near +-pi, not 0
    assert float(mean[0]) == pytest.approx(1.0)
    np.testing.assert_allclose(cov, P, rtol=1e-9, atol=1e-12)
    # without the angle treatment the answer is badly wrong
    assert abs(float(naive_mean[1])) < 2.0 or float(naive_cov[1, 1]) > 1.0
    # cross-covariance with wrapped deviations on both sides
    np.testing.assert_allclose(C, cov, rtol=1e-9, atol=1e-12)
    assert abs(float(wrap_angle(z_mean[0] - mu_angle - 0.05))) < 1e-12
    np.testing.assert_allclose(Cxz[:, 0], P[:, 1], rtol=1e-9, atol=1e-12)


def test_sigma_point_stats_negative_angle_index_and_jit():
    rule = Unscented(alpha=0.9)
    m = jnp.array([0.0, 1.0, np.pi - 0.05])
    P = jnp.diag(jnp.array([1.0, 2.0, 0.2**2]))
    X, wm, wc = rule.points(m, P)
    Y = X.at[:, 2].set(wrap_angle(X[:, 2]))
    f = jax.jit(sigma_point_stats, static_argnames="angle_index")
    mean, cov = f(Y, wm, wc, angle_index=-1)
    np.testing.assert_allclose(mean, m, atol=1e-12)
    np.testing.assert_allclose(cov, P, atol=1e-12)
