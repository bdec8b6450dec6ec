"""Angle wrapping."""

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float


def wrap_angle(a: Float[ArrayLike, "*shape"]) -> Float[Array, "*shape"]:
    """Wrap angles to (-pi, pi].

    Args:
        a: angles in radians, any shape.
    """
    a = jnp.asarray(a)
    # Subtracting the nearest multiple of 2 pi is ~10x cheaper on CPU than jnp.mod (fmod).
    w = a - (2.0 * jnp.pi) * jnp.round(a / (2.0 * jnp.pi))
    # round() leaves -pi at -pi (and round-off can land just outside): the interval is (-pi, pi].
    w = jnp.where(w <= -jnp.pi, w + 2.0 * jnp.pi, w)
    return jnp.where(w > jnp.pi, w - 2.0 * jnp.pi, w)


def wrap_angle_np(a: Float[ArrayLike, "*shape"]) -> Float[np.ndarray, "*shape"]:
    """:func:`wrap_angle` in numpy, for host code (data loading, simulation, the smoother): (-pi, pi]."""
    w = np.mod(np.asarray(a) + np.pi, 2.0 * np.pi) - np.pi
    return np.where(w <= -np.pi, w + 2.0 * np.pi, w)


def circular_mean(angles: Float[ArrayLike, " n"], weights: Float[ArrayLike, " n"]) -> Float[Array, ""]:
    """Weighted circular mean of angles (weights need not be normalised)."""
    angles, weights = jnp.asarray(angles), jnp.asarray(weights)
    return jnp.arctan2(jnp.sum(weights * jnp.sin(angles)), jnp.sum(weights * jnp.cos(angles)))
