"""The range-bearing measurement model and its inverse (docs/method/victoria-park.md, "Measurement model").

Bearings are relative to the vehicle's forward axis and wrapped to (-pi, pi]. Jacobians come
from autodiff (:func:`range_bearing_jacobians`); the filter never uses hand-written formulas.
"""

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from nanoslam_jax.lib._trig import atan2, sincos
from nanoslam_jax.lib._angles import wrap_angle


def range_bearing_components(
    px: Float[ArrayLike, "*#shape"],
    py: Float[ArrayLike, "*#shape"],
    phi: Float[ArrayLike, "*#shape"],
    mx: Float[ArrayLike, "*#shape"],
    my: Float[ArrayLike, "*#shape"],
) -> tuple[Float[Array, "*shape"], Float[Array, "*shape"]]:
    """:func:`range_bearing` on separate coordinate arrays (any broadcastable shapes): ``(r, beta)``.

    The model's one definition; :func:`range_bearing` stacks its two results. Code that evaluates
    many landmarks at once keeps the components apart: on XLA:CPU arithmetic on stacked 2-vectors
    and 2x2 matrices per landmark runs several times slower than on one array per component.
    """
    dx, dy = jnp.asarray(mx) - px, jnp.asarray(my) - py
    # sqrt(q) with a floor keeps the derivative finite at r = 0 (never reached by real data).
    r = jnp.sqrt(jnp.maximum(dx * dx + dy * dy, 1e-24))
    return r, wrap_angle(atan2(dy, dx) - phi)


def range_bearing(x: Float[ArrayLike, "3"], m: Float[ArrayLike, "2"]) -> Float[Array, "2"]:
    """Predicted detection ``(r, beta)`` of landmark ``m = (mx, my)`` from laser pose ``x``."""
    x, m = jnp.asarray(x), jnp.asarray(m)
    return jnp.stack(range_bearing_components(x[0], x[1], x[2], m[0], m[1]))


def inverse_range_bearing(x: Float[ArrayLike, "3"], z: Float[ArrayLike, "2"]) -> Float[Array, "2"]:
    """Landmark position from pose ``x`` and detection ``z = (r, beta)``: ``p + r (cos, sin)(phi + beta)``."""
    x, z = jnp.asarray(x), jnp.asarray(z)
    s, c = sincos(x[2] + z[1])
    return jnp.stack([x[0] + z[0] * c, x[1] + z[0] * s])


def innovation(z: Float[ArrayLike, "2"], z_hat: Float[ArrayLike, "2"]) -> Float[Array, "2"]:
    """Measurement residual ``z - z_hat`` with the bearing component wrapped."""
    d = jnp.asarray(z) - jnp.asarray(z_hat)
    return jnp.stack([d[0], wrap_angle(d[1])])


def range_bearing_jacobians(
    x: Float[ArrayLike, "3"], m: Float[ArrayLike, "2"]
) -> tuple[Float[Array, "2 3"], Float[Array, "2 2"]]:
    """Jacobians ``(Gx, Gm)`` of :func:`range_bearing` w.r.t. the pose and the landmark (autodiff)."""
    return jax.jacfwd(range_bearing, argnums=(0, 1))(jnp.asarray(x), jnp.asarray(m))


def inverse_range_bearing_jacobians(
    x: Float[ArrayLike, "3"], z: Float[ArrayLike, "2"]
) -> tuple[Float[Array, "2 3"], Float[Array, "2 2"]]:
    """Jacobians of :func:`inverse_range_bearing` w.r.t. the pose and the detection (autodiff)."""
    return jax.jacfwd(inverse_range_bearing, argnums=(0, 1))(jnp.asarray(x), jnp.asarray(z))


def range_bearing_jacobian_components(
    px: Float[ArrayLike, "*#shape"],
    py: Float[ArrayLike, "*#shape"],
    phi: Float[ArrayLike, "*#shape"],
    mx: Float[ArrayLike, "*#shape"],
    my: Float[ArrayLike, "*#shape"],
) -> tuple[tuple[Float[Array, "*shape"], Float[Array, "*shape"]], tuple[tuple[Float[Array, "*shape"], ...], ...]]:
    """:func:`range_bearing_components` and its Jacobian entry by entry (autodiff, one ``jvp`` per input).

    Returns:
        ``(r, beta)`` and ``J`` with ``J[a][i]`` the derivative of output ``a`` (range, bearing)
        with respect to input ``i`` (``px, py, phi, mx, my``): columns 0-2 are ``Gx``, 3-4 ``Gm``.
    """
    args = jnp.broadcast_arrays(px, py, phi, mx, my)
    cols = []
    for i in range(5):

        def along(a, i=i):
            parts = list(args)
            parts[i] = a
            return range_bearing_components(*parts)

        z, dz = jax.jvp(along, (args[i],), (jnp.ones_like(args[i]),))
        cols.append(dz)
    return z, tuple(tuple(c[a] for c in cols) for a in range(2))
