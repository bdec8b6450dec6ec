"""Resampling schemes over normalised log-weights (docs/method/filter.md).

Each returns ``N`` ancestor indices. All are unbiased: the expected number of copies of
particle ``i`` is ``N w_i``. A particle filter takes its scheme as a resampler object
(:class:`AbstractResampler`), so a user's own scheme is a subclass with a ``__call__``.
"""

from __future__ import annotations

import abc
import dataclasses
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int, Key


def normalise(log_w: Float[Array, " n"]) -> Float[Array, " n"]:
    """Log-weights shifted so that ``logsumexp = 0`` (never exponentiating unnormalised values)."""
    return log_w - jax.scipy.special.logsumexp(log_w)


def effective_sample_size(log_w: Float[Array, " n"]) -> Float[Array, ""]:
    """``1 / sum w^2`` of normalised log-weights, computed in log space."""
    lw = normalise(log_w)
    return jnp.exp(-jax.scipy.special.logsumexp(2.0 * lw))


def _inverse_cdf(log_w, u):
    cdf = jnp.cumsum(jnp.exp(normalise(log_w)))
    cdf = cdf.at[-1].set(jnp.inf)  # guard against round-off at the top end
    return jnp.searchsorted(cdf, u, side="right").astype(jnp.int32)


def systematic(key: Key[Array, ""], log_w: Float[Array, " n"]) -> Int[Array, " n"]:
    """One uniform offset, ``N`` evenly spaced positions."""
    n = log_w.shape[0]
    return _inverse_cdf(log_w, (jnp.arange(n) + jax.random.uniform(key, dtype=log_w.dtype)) / n)


def stratified(key: Key[Array, ""], log_w: Float[Array, " n"]) -> Int[Array, " n"]:
    """One uniform per stratum ``[i/N, (i+1)/N)``."""
    n = log_w.shape[0]
    return _inverse_cdf(log_w, (jnp.arange(n) + jax.random.uniform(key, (n,), dtype=log_w.dtype)) / n)


def multinomial(key: Key[Array, ""], log_w: Float[Array, " n"]) -> Int[Array, " n"]:
    """``N`` independent draws."""
    n = log_w.shape[0]
    return jax.random.categorical(key, normalise(log_w), shape=(n,)).astype(jnp.int32)


def residual(key: Key[Array, ""], log_w: Float[Array, " n"]) -> Int[Array, " n"]:
    """``floor(N w_i)`` deterministic copies, the rest multinomial on the residual weights."""
    n = log_w.shape[0]
    nw = n * jnp.exp(normalise(log_w))
    counts = jnp.floor(nw).astype(jnp.int32)
    det = jnp.repeat(jnp.arange(n, dtype=jnp.int32), counts, total_repeat_length=n)
    n_det = jnp.sum(counts)
    rest = nw - counts
    log_rest = jnp.where(rest > 0, jnp.log(jnp.maximum(rest, 1e-300)), -jnp.inf)
    # If nothing is left to draw (all residuals 0), the categorical draws are never used.
    log_rest = jnp.where(jnp.any(rest > 0), log_rest, jnp.zeros_like(log_rest))
    drawn = jax.random.categorical(key, log_rest, shape=(n,)).astype(jnp.int32)
    return jnp.where(jnp.arange(n) < n_det, det, drawn)


@dataclasses.dataclass(frozen=True)
class AbstractResampler(abc.ABC):
    """A resampling scheme: ancestor indices from log-weights (``filter.resampler`` names one).

    A subclass is a frozen dataclass (hashable: it is part of a filter's static settings) whose
    ``__call__`` is a pure JAX function of a key and the particles' log-weights.

    Attributes:
        name: the scheme's name (``filter.resampler``).
    """

    name: ClassVar[str] = ""

    @abc.abstractmethod
    def __call__(self, key: Key[Array, ""], log_w: Float[Array, " n"]) -> Int[Array, " n"]:
        """``n`` ancestor indices, each particle ``i`` drawn ``n w_i`` times in expectation.

        Args:
            key: the draw's random key.
            log_w: the particles' log-weights (not necessarily normalised).
        """


@dataclasses.dataclass(frozen=True)
class _Scheme(AbstractResampler):
    """A built-in scheme: one of this module's functions (:attr:`scheme`)."""

    scheme: ClassVar[Any]  # a staticmethod (key, log_w) -> ancestor indices

    def __call__(self, key, log_w):
        return type(self).scheme(key, log_w)


@dataclasses.dataclass(frozen=True)
class Systematic(_Scheme):
    """Systematic resampling (:func:`systematic`): one uniform offset for ``n`` evenly spaced points."""

    name: ClassVar[str] = "systematic"
    scheme = staticmethod(systematic)


@dataclasses.dataclass(frozen=True)
class Stratified(_Scheme):
    """Stratified resampling (:func:`stratified`): one uniform draw in each of ``n`` strata."""

    name: ClassVar[str] = "stratified"
    scheme = staticmethod(stratified)


@dataclasses.dataclass(frozen=True)
class Multinomial(_Scheme):
    """Multinomial resampling (:func:`multinomial`): ``n`` independent categorical draws."""

    name: ClassVar[str] = "multinomial"
    scheme = staticmethod(multinomial)


@dataclasses.dataclass(frozen=True)
class Residual(_Scheme):
    """Residual resampling (:func:`residual`): ``floor(n w_i)`` copies, the rest multinomial."""

    name: ClassVar[str] = "residual"
    scheme = staticmethod(residual)
