"""Angle wrapping."""

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float


def wrap_angle(a: Float[ArrayLike, "*shape"]) -> Float[Array, "*shape"]:
    """Wrap angles to (-pi, pi].

    Args:
        a: angles in radians, any shape.
    """
    a = jnp.asarray(a)
    w = jnp.mod(a + jnp.pi, 2.0 * jnp.pi) - jnp.pi
    # mod maps +pi to -pi; the half-open interval here is (-pi, pi].
    return jnp.where(w <= -jnp.pi, w + 2.0 * jnp.pi, w)


def circular_mean(angles: Float[ArrayLike, "n"], weights: Float[ArrayLike, "n"]) -> Float[Array, ""]:
    """Weighted circular mean of angles (weights need not be normalised)."""
    angles, weights = jnp.asarray(angles), jnp.asarray(weights)
    return jnp.arctan2(jnp.sum(weights * jnp.sin(angles)), jnp.sum(weights * jnp.cos(angles)))
