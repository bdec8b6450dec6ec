"""Closed-form algebra for the tiny matrices of the filter (2x2 and 3x3).

Batched ``jnp.linalg`` calls on 2x2/3x3 matrices dominate the run time of a vmapped filter on
CPU; these closed forms compile to a handful of fused element-wise operations instead. All
functions act on the last two axes and broadcast over leading axes.
"""

from typing import cast

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

_TINY = 1e-300


def _stack2d(rows):
    return jnp.stack([jnp.stack(r, axis=-1) for r in rows], axis=-2)


def mm(a: Float[Array, "... n k"], b: Float[Array, "... k m"]) -> Float[Array, "... n m"]:
    """Matrix product of tiny matrices, written element by element.

    Each output element is a sum of products of batch-shaped arrays, stacked at the end, so all
    arithmetic runs along the (long) batch axes. XLA:CPU vectorises the innermost axis: a batched
    ``@`` or a broadcast-and-sum keeps the tiny 2-3 wide matrix axes innermost and runs several
    times slower for 2x2/3x3 operands.
    """
    n, k, m = a.shape[-2], a.shape[-1], b.shape[-1]
    return _stack2d([[sum(a[..., i, l] * b[..., l, j] for l in range(k)) for j in range(m)] for i in range(n)])


def mmt(a: Float[Array, "... n k"], b: Float[Array, "... m k"]) -> Float[Array, "... n m"]:
    """``A B'`` for tiny matrices (see :func:`mm`)."""
    n, k, m = a.shape[-2], a.shape[-1], b.shape[-2]
    return _stack2d([[sum(a[..., i, l] * b[..., j, l] for l in range(k)) for j in range(m)] for i in range(n)])


def mv(a: Float[Array, "... n k"], v: Float[Array, "... k"]) -> Float[Array, "... n"]:
    """Matrix-vector product of tiny operands (see :func:`mm`)."""
    n, k = a.shape[-2], a.shape[-1]
    return jnp.stack([sum(a[..., i, l] * v[..., l] for l in range(k)) for i in range(n)], axis=-1)


def dot(u: Float[Array, "... n"], v: Float[Array, "... n"]) -> Float[Array, "..."]:
    """Inner product over a tiny last axis (see :func:`mm`)."""
    return cast(Array, sum(u[..., l] * v[..., l] for l in range(u.shape[-1])))  # the axis is never empty


def tsum(a: Float[Array, "..."], axis: int = 0) -> Float[Array, "..."]:
    """Sum over a short axis as a chain of additions of its slices.

    XLA:CPU emits reductions whose result keeps tiny minor axes (``(k, 3, 3) -> (3, 3)``) as
    scalar loops, several times slower than the unrolled element-wise sum, which fuses.
    """
    return cast(Array, sum(jnp.take(a, i, axis=axis) for i in range(a.shape[axis])))  # the axis is never empty


def mt(a: Float[Array, "... n m"]) -> Float[Array, "... m n"]:
    """Transpose of the last two axes."""
    return jnp.swapaxes(a, -1, -2)


def sandwich(a: Float[Array, "... n k"], b: Float[Array, "... k k"]) -> Float[Array, "... n n"]:
    """``A B A'`` for tiny matrices (see :func:`mm`)."""
    return mmt(mm(a, b), a)


def sym(a: Float[Array, "... n n"]) -> Float[Array, "... n n"]:
    """Symmetric part ``(A + A') / 2``."""
    return 0.5 * (a + jnp.swapaxes(a, -1, -2))


def det2(a: Float[Array, "... 2 2"]) -> Float[Array, "..."]:
    """Determinant of 2x2 matrices."""
    return a[..., 0, 0] * a[..., 1, 1] - a[..., 0, 1] * a[..., 1, 0]


def inv2(a: Float[Array, "... 2 2"]) -> Float[Array, "... 2 2"]:
    """Inverse of 2x2 matrices (adjugate over determinant)."""
    d = det2(a)
    adj = jnp.stack([jnp.stack([a[..., 1, 1], -a[..., 0, 1]], -1), jnp.stack([-a[..., 1, 0], a[..., 0, 0]], -1)], -2)
    return adj / d[..., None, None]


def det3(a: Float[Array, "... 3 3"]) -> Float[Array, "..."]:
    """Determinant of 3x3 matrices."""
    return (
        a[..., 0, 0] * (a[..., 1, 1] * a[..., 2, 2] - a[..., 1, 2] * a[..., 2, 1])
        - a[..., 0, 1] * (a[..., 1, 0] * a[..., 2, 2] - a[..., 1, 2] * a[..., 2, 0])
        + a[..., 0, 2] * (a[..., 1, 0] * a[..., 2, 1] - a[..., 1, 1] * a[..., 2, 0])
    )


def inv3(a: Float[Array, "... 3 3"]) -> Float[Array, "... 3 3"]:
    """Inverse of 3x3 matrices (adjugate over determinant)."""
    c = lambda i, j, k, l: a[..., i, j] * a[..., k, l] - a[..., i, l] * a[..., k, j]  # noqa: E731
    adj = jnp.stack(
        [
            jnp.stack([c(1, 1, 2, 2), -c(0, 1, 2, 2), c(0, 1, 1, 2)], -1),
            jnp.stack([-c(1, 0, 2, 2), c(0, 0, 2, 2), -c(0, 0, 1, 2)], -1),
            jnp.stack([c(1, 0, 2, 1), -c(0, 0, 2, 1), c(0, 0, 1, 1)], -1),
        ],
        -2,
    )
    return adj / det3(a)[..., None, None]


def chol2(a: Float[Array, "... 2 2"]) -> Float[Array, "... 2 2"]:
    """Lower Cholesky factor of symmetric positive semi-definite 2x2 matrices (floored pivots)."""
    l11 = jnp.sqrt(jnp.maximum(a[..., 0, 0], _TINY))
    l21 = a[..., 1, 0] / l11
    l22 = jnp.sqrt(jnp.maximum(a[..., 1, 1] - l21 * l21, _TINY))
    z = jnp.zeros_like(l11)
    return jnp.stack([jnp.stack([l11, z], -1), jnp.stack([l21, l22], -1)], -2)


def chol3(a: Float[Array, "... 3 3"]) -> Float[Array, "... 3 3"]:
    """Lower Cholesky factor of symmetric positive semi-definite 3x3 matrices (floored pivots).

    A pivot that would be zero or negative (a singular or slightly indefinite matrix from
    round-off) is floored at a tiny positive value, so the factor stays finite.
    """
    l11 = jnp.sqrt(jnp.maximum(a[..., 0, 0], _TINY))
    l21 = a[..., 1, 0] / l11
    l31 = a[..., 2, 0] / l11
    l22 = jnp.sqrt(jnp.maximum(a[..., 1, 1] - l21 * l21, _TINY))
    l32 = (a[..., 2, 1] - l31 * l21) / l22
    l33 = jnp.sqrt(jnp.maximum(a[..., 2, 2] - l31 * l31 - l32 * l32, _TINY))
    z = jnp.zeros_like(l11)
    return jnp.stack([jnp.stack([l11, z, z], -1), jnp.stack([l21, l22, z], -1), jnp.stack([l31, l32, l33], -1)], -2)


def logdet_spd(a: Float[Array, "... n n"]) -> Float[Array, "..."]:
    """``log det`` of symmetric positive definite 2x2 or 3x3 matrices."""
    d = det2(a) if a.shape[-1] == 2 else det3(a)
    return jnp.log(jnp.maximum(d, _TINY))


def quad_form(v: Float[Array, "... n"], a: Float[Array, "... n n"]) -> Float[Array, "..."]:
    """``v' A v``."""
    return dot(v, mv(a, v))


def inv_small(a: Float[Array, "... n n"]) -> Float[Array, "... n n"]:
    """Inverse of tiny matrices: the closed forms for 1x1, 2x2 and 3x3 (:func:`inv2`, :func:`inv3`),
    ``jnp.linalg.inv`` beyond."""
    n = a.shape[-1]
    if n == 1:
        return 1.0 / a
    if n == 2:
        return inv2(a)
    if n == 3:
        return inv3(a)
    return jnp.linalg.inv(a)


def chol_small(a: Float[Array, "... n n"]) -> Float[Array, "... n n"]:
    """Lower Cholesky factor of symmetric positive semi-definite tiny matrices: the closed forms
    with floored pivots for 1x1 to 3x3 (:func:`chol2`, :func:`chol3`), ``jnp.linalg.cholesky`` beyond."""
    n = a.shape[-1]
    if n == 1:
        return jnp.sqrt(jnp.maximum(a, _TINY))
    if n == 2:
        return chol2(a)
    if n == 3:
        return chol3(a)
    return jnp.linalg.cholesky(a)


def is_pd_small(a: Float[Array, "... n n"]) -> Bool[Array, "..."]:
    """Whether symmetric tiny matrices are positive definite (Sylvester's criterion: every leading
    principal minor positive; closed forms up to 3x3, an eigenvalue test beyond)."""
    n = a.shape[-1]
    if n == 1:
        return a[..., 0, 0] > 0
    if n == 2:
        return (a[..., 0, 0] > 0) & (det2(a) > 0)
    if n == 3:
        return (a[..., 0, 0] > 0) & (det2(a[..., :2, :2]) > 0) & (det3(a) > 0)
    return jnp.all(jnp.linalg.eigvalsh(a) > 0, axis=-1)


def gaussian_logpdf(nu: Float[Array, "... d"], s: Float[Array, "... d d"]) -> Float[Array, "..."]:
    """``log N(nu; 0, S)`` for tiny vectors (the closed forms up to 3-vectors)."""
    d = nu.shape[-1]
    if d == 2:
        return -0.5 * (quad_form(nu, inv2(s)) + logdet_spd(s)) - jnp.log(2.0 * jnp.pi)
    logdet = logdet_spd(s) if d == 3 else jnp.linalg.slogdet(s)[1]
    return -0.5 * (quad_form(nu, inv_small(s)) + logdet) - 0.5 * d * jnp.log(2.0 * jnp.pi)
