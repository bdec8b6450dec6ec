"""Resampling schemes, effective sample size and log-weight normalisation.

Independent truths: the expected offspring count ``N w_i`` of an unbiased scheme (checked with a
Monte Carlo mean over many keys and its own standard error), the deterministic count bounds each
scheme guarantees by construction, and ``1 / sum w^2`` computed in numpy.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nanoslam_jax.methods import Multinomial, Residual, Stratified, Systematic, effective_sample_size, normalise

RESAMPLERS = {r.name: r for r in (Systematic(), Stratified(), Multinomial(), Residual())}

N_KEYS = 20_000

# Unnormalised weights of N = 10 particles: a spread with counts N w_i between 0 and 3.1, a
# particle of zero weight in the middle, and a nearly degenerate set.
WEIGHTS = {
    "spread": np.array([0.31, 0.2, 0.15, 0.1, 0.1, 0.0, 0.07, 0.04, 0.02, 0.01]),
    "dominant": np.array([0.905, 0.01, 0.01, 0.02, 0.01, 0.01, 0.01, 0.005, 0.01, 0.01]),
    "uniform": np.full(10, 0.1),
}


def log_weights(w, offset=0.0):
    with np.errstate(divide="ignore"):
        return np.log(w) + offset  # deliberately unnormalised (offset), zero weight -> -inf


@pytest.fixture(scope="module")
def offspring():
    """Offspring counts (keys, N) of each scheme and weight set, over N_KEYS keys (vmapped)."""
    keys = jax.random.split(jax.random.key(1234), N_KEYS)
    out = {}
    for name, fn in RESAMPLERS.items():
        run = jax.jit(jax.vmap(fn, (0, None)))
        for wname, w in WEIGHTS.items():
            # An offset of -1e4 checks that unnormalised log-weights far from 0 are handled.
            idx = np.asarray(run(keys, jnp.asarray(log_weights(w, -1e4))))
            n = w.shape[0]
            assert idx.shape == (N_KEYS, n)
            assert idx.dtype.kind == "i"
            assert idx.min() >= 0 and idx.max() < n, (name, wname)
            counts = np.stack([np.sum(idx == i, axis=1) for i in range(n)], axis=1)
            assert np.all(counts.sum(axis=1) == n)
            out[name, wname] = counts
    return out


@pytest.mark.parametrize("wname", list(WEIGHTS))
@pytest.mark.parametrize("scheme", list(RESAMPLERS))
@pytest.mark.slow
def test_unbiased(offspring, scheme, wname):
    """Mean offspring count = N w_i within 5 standard errors of the Monte Carlo mean (estimated from
    the sample; a count with zero sample variance must be exact)."""
    counts = offspring[scheme, wname]
    w = WEIGHTS[wname] / WEIGHTS[wname].sum()
    expected = w.shape[0] * w
    mean = counts.mean(axis=0)
    se = counts.std(axis=0, ddof=1) / math.sqrt(N_KEYS)
    assert np.all(np.abs(mean - expected) <= 5 * se + 1e-9), (mean, expected, se)


@pytest.mark.parametrize("wname", list(WEIGHTS))
@pytest.mark.parametrize("scheme", list(RESAMPLERS))
def test_zero_weight_never_drawn(offspring, scheme, wname):
    counts = offspring[scheme, wname]
    zero = WEIGHTS[wname] == 0
    assert np.all(counts[:, zero] == 0)


@pytest.mark.parametrize("wname", list(WEIGHTS))
def test_systematic_count_is_floor_or_ceil(offspring, wname):
    """Systematic: every particle gets floor(N w_i) or ceil(N w_i) copies, so any particle with
    N w_i >= 1 survives."""
    counts = offspring["systematic", wname]
    w = WEIGHTS[wname] / WEIGHTS[wname].sum()
    nw = w.shape[0] * w
    assert np.all(counts >= np.floor(nw - 1e-9)) and np.all(counts <= np.ceil(nw + 1e-9))
    assert np.all(counts[:, nw >= 1] >= 1)


@pytest.mark.parametrize("wname", list(WEIGHTS))
def test_stratified_count_bounds(offspring, wname):
    """Stratified: a cdf interval of length N w_i holds at least floor(N w_i) - 1 whole strata (one
    point each) and meets at most ceil(N w_i) + 1 strata."""
    counts = offspring["stratified", wname]
    w = WEIGHTS[wname] / WEIGHTS[wname].sum()
    nw = w.shape[0] * w
    assert np.all(counts >= np.floor(nw - 1e-9) - 1) and np.all(counts <= np.ceil(nw + 1e-9) + 1)
    assert np.all(counts[:, nw >= 2] >= 1)


@pytest.mark.parametrize("wname", list(WEIGHTS))
def test_residual_keeps_floor_copies(offspring, wname):
    counts = offspring["residual", wname]
    w = WEIGHTS[wname] / WEIGHTS[wname].sum()
    nw = w.shape[0] * w
    assert np.all(counts >= np.floor(nw - 1e-9))
    if wname == "uniform":  # N w_i = 1 for all: nothing is left to draw, every particle once
        assert np.all(counts == 1)


def test_uniform_systematic_and_stratified_are_identity_counts(offspring):
    for scheme in ("systematic", "stratified"):
        assert np.all(offspring[scheme, "uniform"] == 1), scheme


# ----------------------------------------------------------------------------- ESS and normalise


def np_ess(log_w):
    lw = np.asarray(log_w, dtype=float)
    w = np.exp(lw - lw.max())
    w /= w.sum()
    return 1.0 / np.sum(w * w)


@pytest.mark.parametrize("offset", [0.0, -1e4, 1e4, -7e5])
def test_effective_sample_size(offset):
    rng = np.random.default_rng(3)
    # Log-space normalisation of values near |offset| loses about one ulp(|offset|) per log-weight
    # (1.8e-12 at 1e4, 1.2e-10 at 7e5), which bounds the attainable relative accuracy.
    rtol = 1e-12 + 1e3 * np.spacing(abs(offset))
    for _ in range(5):
        lw = rng.normal(size=12) * 3.0 + offset
        ess = float(effective_sample_size(jnp.asarray(lw)))
        assert math.isfinite(ess)
        np.testing.assert_allclose(ess, np_ess(lw), rtol=rtol)
    # Limits: equal weights -> N, one particle carrying everything -> 1.
    np.testing.assert_allclose(effective_sample_size(jnp.full(7, offset)), 7.0, rtol=rtol)
    lw = np.full(7, -np.inf)
    lw[3] = offset
    np.testing.assert_allclose(effective_sample_size(jnp.asarray(lw)), 1.0, rtol=rtol)
    # Log-weights spread by 1e4 (weights far below the smallest double): the small ones vanish.
    lw = np.array([offset, offset - 1e4, offset - 2e4, offset])
    np.testing.assert_allclose(effective_sample_size(jnp.asarray(lw)), 2.0, rtol=rtol)


@pytest.mark.parametrize("offset", [0.0, -1e4, 1e4])
def test_normalise(offset):
    rng = np.random.default_rng(4)
    lw = rng.normal(size=9) * 5.0
    out = np.asarray(normalise(jnp.asarray(lw + offset)))
    assert np.all(np.isfinite(out))
    top = out.max()
    np.testing.assert_allclose(top + np.log(np.sum(np.exp(out - top))), 0.0, atol=1e-12)
    # Shift-invariant: the same normalised weights whatever the offset.
    np.testing.assert_allclose(out, lw - (lw.max() + np.log(np.sum(np.exp(lw - lw.max())))), atol=1e-9)
    # -inf entries stay -inf; the rest still sum to one.
    lw2 = lw.copy()
    lw2[2] = -np.inf
    out2 = np.asarray(normalise(jnp.asarray(lw2 + offset)))
    assert out2[2] == -np.inf
    np.testing.assert_allclose(np.sum(np.exp(out2)), 1.0, rtol=1e-12)
