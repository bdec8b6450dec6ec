"""Sine, cosine and arctangent written as vectorisable arithmetic.

XLA:CPU evaluates ``sin``, ``cos``, ``tan`` and ``atan2`` one element at a time (an order of
magnitude slower than a multiply-add or a square root), and the filter evaluates a few thousand
of them per particle and scan: the range-bearing model at every quadrature point of every NANO
iteration, the vehicle model at every sigma point of every dead-reckoning piece. The functions
here are range reductions and truncated Taylor series made of additions, multiplications, one
division and selects, which XLA fuses and vectorises, and accurate to one or two units in the
last place in float64 (the tests compare them with NumPy over many decades of arguments).

The series are exact Taylor series (no fitted constants): the reductions make the arguments
small enough that the first omitted term is below 1e-18 relative. Derivatives are defined by
``jax.custom_jvp`` with the analytic rules (``d sin = cos``, ``d atan2(y, x) = (x dy - y dx) /
(x^2 + y^2)``), so Jacobians and Hessians are those of the true functions, not of the series.
"""

from __future__ import annotations

import math
from fractions import Fraction
from typing import TypeVar

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

T = TypeVar("T")

# pi to 60 digits, for the Cody-Waite split of pi/2 below.
_PI = "3.14159265358979323846264338327950288419716939937510582097494459"


def _split(value: Fraction, parts: int, bits: int) -> tuple[float, ...]:
    """``value`` as a sum of float64 numbers with at most ``bits`` significant bits each (the last full)."""
    out = []
    rest = value
    for i in range(parts):
        f = float(rest)
        if i < parts - 1:
            m, e = math.frexp(f)
            f = math.ldexp(math.floor(m * 2.0**bits) / 2.0**bits, e)
        out.append(f)
        rest = rest - Fraction(f)  # exact arithmetic on rationals
    return tuple(out)


# pi/2 = P1 + P2 + P3; n * P1 and n * P2 are exact for |n| < 2^25, so x - n pi/2 is accurate to
# ~1e-16 absolute for |x| up to ~5e7 (the filter's angles are below ~1e3).
_P1, _P2, _P3 = _split(Fraction(_PI) / 2, 3, 28)
_TWO_OVER_PI = 2.0 / math.pi

# Taylor coefficients in r^2 of sin(r)/r and cos(r), |r| <= pi/4: the first omitted terms are
# r^19/19! (relative 1e-19) and r^18/18! (2e-18).
_SIN = tuple((-1) ** k / math.factorial(2 * k + 1) for k in range(9))
_COS = tuple((-1) ** k / math.factorial(2 * k) for k in range(10))
# atan(u) = u sum_k (-u^2)^k / (2k + 1), |u| <= tan(pi/16): first omitted term relative 6e-19.
_ATAN = tuple((-1) ** k / (2 * k + 1) for k in range(12))
_T16 = math.tan(math.pi / 16)  # interval edges of the reduction of atan's argument in [0, 1]
_T316 = math.tan(3 * math.pi / 16)
_T8 = math.sqrt(2.0) - 1.0  # tan(pi/8), the centre of the middle interval


def _horner(s: Array, coeffs: tuple[float, ...]) -> Array:
    acc = jnp.full_like(s, coeffs[-1])
    for c in coeffs[-2::-1]:
        acc = acc * s + c
    return acc


@jax.custom_jvp
def sincos(x: Float[ArrayLike, "*shape"]) -> tuple[Float[Array, "*shape"], Float[Array, "*shape"]]:
    """``(sin(x), cos(x))`` by reduction modulo pi/2 and Taylor series on ``[-pi/4, pi/4]``.

    Args:
        x: angles in radians, any shape (accurate to ~1e-16 absolute for ``|x| < 5e7``;
            non-finite inputs give NaN, as ``jnp.sin``).
    """
    x = jnp.asarray(x)
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(float)
    n = jnp.round(x * _TWO_OVER_PI)
    r = ((x - n * _P1) - n * _P2) - n * _P3
    s2 = r * r
    sin_r = r * _horner(s2, _SIN)
    cos_r = _horner(s2, _COS)
    q = n - 4.0 * jnp.floor(0.25 * n)  # quadrant 0..3
    sin_x = jnp.where(q == 0, sin_r, jnp.where(q == 1, cos_r, jnp.where(q == 2, -sin_r, -cos_r)))
    cos_x = jnp.where(q == 0, cos_r, jnp.where(q == 1, -sin_r, jnp.where(q == 2, -cos_r, sin_r)))
    return sin_x, cos_x


@sincos.defjvp
def _sincos_jvp(primals, tangents):
    (x,), (dx,) = primals, tangents
    s, c = sincos(x)
    return (s, c), (c * dx, -s * dx)


def sin(x: Float[ArrayLike, "*shape"]) -> Float[Array, "*shape"]:
    """``sin(x)`` (see :func:`sincos`)."""
    return sincos(x)[0]


def cos(x: Float[ArrayLike, "*shape"]) -> Float[Array, "*shape"]:
    """``cos(x)`` (see :func:`sincos`)."""
    return sincos(x)[1]


def tan(x: Float[ArrayLike, "*shape"]) -> Float[Array, "*shape"]:
    """``tan(x) = sin(x) / cos(x)`` (see :func:`sincos`)."""
    s, c = sincos(x)
    return s / c


@jax.custom_jvp
def atan2(y: Float[ArrayLike, "*shape"], x: Float[ArrayLike, "*shape"]) -> Float[Array, "*shape"]:
    """Four-quadrant arctangent of ``y / x`` in ``[-pi, pi]``, with ``jnp.arctan2``'s conventions
    for signed zeros and infinities.

    The ratio ``t = min(|x|, |y|) / max(|x|, |y|)`` in ``[0, 1]`` is reduced to
    ``|u| <= tan(pi/16)`` by ``atan(t) = j pi/8 + atan((t - c_j) / (1 + t c_j))`` with
    ``c_j = tan(j pi/8)``, ``j = 0, 1, 2``; then a Taylor series.

    Args:
        y, x: the coordinates (broadcast together).
    """
    y, x = jnp.asarray(y), jnp.asarray(x)
    dtype = jnp.result_type(y, x, float)
    y, x = y.astype(dtype), x.astype(dtype)
    ax, ay = jnp.abs(x), jnp.abs(y)
    swap = ay > ax
    num, den = jnp.minimum(ax, ay), jnp.maximum(ax, ay)
    both_inf = jnp.isinf(num)
    t = jnp.where(both_inf, 1.0, num / jnp.where(den > 0, den, 1.0))
    j = jnp.where(t <= _T16, 0.0, jnp.where(t <= _T316, 1.0, 2.0))
    c = jnp.where(j == 0, 0.0, jnp.where(j == 1, _T8, 1.0))
    u = (t - c) / (1.0 + t * c)
    a = j * (math.pi / 8) + u * _horner(u * u, _ATAN)
    a = jnp.where(swap, math.pi / 2 - a, a)
    a = jnp.where(jnp.signbit(x), math.pi - a, a)
    a = jnp.where(jnp.isnan(x) | jnp.isnan(y), jnp.nan, a)
    return jnp.where(jnp.signbit(y), -a, a)


@atan2.defjvp
def _atan2_jvp(primals, tangents):
    y, x = primals
    dy, dx = tangents
    q = x * x + y * y
    return atan2(y, x), (x * dy - y * dx) / q


def computed_once(tree: T) -> T:
    """``tree`` (an array or a pytree of arrays of one dtype) unchanged, but written to memory once
    where it is computed, rather than recomputed inside each computation that reads it.

    The series above are additions and multiplications, which XLA's fusion judges cheap and so
    duplicates into every fusion that reads them: a landmark initialised from a ``sin``/``cos``
    recomputed both series for each entry of its 2x2 Jacobian, inverse and covariance, and a prior
    placed at a particle's heading recomputed them for each of the window's slots and of the
    capacity's radius tests. XLA:CPU offers no "do not fuse" marker (it removes optimisation
    barriers before fusion), so this relies on what its passes do: the leaves are concatenated
    into one vector behind a ``jax.lax.optimization_barrier``, which keeps the simplifier from
    forwarding the parts to their readers (slice of a concatenation); the concatenation then
    becomes a fusion of its own, written once, and the readers slice it. It changes no value (nor
    derivative).
    """
    leaves, treedef = jax.tree.flatten(tree)
    if len({jnp.result_type(a) for a in leaves}) > 1:
        raise TypeError(f"computed_once: the leaves must share one dtype, got {[jnp.result_type(a) for a in leaves]}")
    flat = jax.lax.optimization_barrier(jnp.concatenate([jnp.ravel(a) for a in leaves]))
    out, start = [], 0
    for a in leaves:
        out.append(flat[start : start + a.size].reshape(a.shape))
        start += a.size
    return jax.tree.unflatten(treedef, out)


__all__ = ["atan2", "computed_once", "cos", "sin", "sincos", "tan"]

# The split must reproduce pi/2 far below float64 resolution (a guard against editing mistakes).
assert abs(Fraction(_P1) + Fraction(_P2) + Fraction(_P3) - Fraction(_PI) / 2) < Fraction(1, 10**30)
