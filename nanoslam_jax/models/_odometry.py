"""The odometry motion model: a robot whose odometry is a stream of poses (CARMEN logs, ROS bags).

The controls of a log piece are the rates ``u = (vx, vy, omega)`` of the **pose increment**
between two consecutive odometry poses, expressed in the body frame of the first: over a piece of
``dt`` seconds the robot's base moves by ``delta = dt u`` (forward, left, turn), so a whole
odometry interval, held as one DR row, moves it by exactly the increment between its two poses
and dead reckoning reproduces the odometry's poses. Rates rather than the increment itself,
because the log is cut into pieces at the scan times: a piece holding part of an interval moves
by that part of the increment.

The noise is Thrun's rotation-translation-rotation model (Probabilistic Robotics,
``sample_motion_model_odometry``): the increment is decomposed into a first rotation, a
translation and a second rotation, each disturbed by zero-mean Gaussian noise of variance

- ``alpha1 rot1^2 + alpha2 trans^2`` (the first rotation),
- ``alpha3 trans^2 + alpha4 (rot1^2 + rot2^2)`` (the translation),
- ``alpha1 rot2^2 + alpha2 trans^2`` (the second rotation),

mapped to the body-frame increment by the Jacobian of the composition (autodiff), plus a small
floor so that the covariance is never singular (a turn in place has no translation noise).
"""

from __future__ import annotations

import math
from typing import Any, ClassVar, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from nanoslam_jax.lib._angles import wrap_angle
from nanoslam_jax.lib._linalg import chol3
from nanoslam_jax.lib._trig import sincos
from nanoslam_jax.models._motion import AbstractMotionModel
from nanoslam_jax.models._settings import OdometryConfig

__all__ = ["Odometry", "rot_trans_rot"]

_ODOMETRY = OdometryConfig()


def _f(x: Any) -> Array | np.ndarray:
    if isinstance(x, jax.Array):
        return jnp.asarray(x, dtype=float)
    return np.asarray(x, dtype=np.float64)


def rot_trans_rot(
    delta: Float[ArrayLike, "3"], min_translation: Float[ArrayLike, ""] = _ODOMETRY.min_translation
) -> Float[Array, "3"]:
    """The decomposition ``(rot1, trans, rot2)`` of a body-frame increment ``(dx, dy, dtheta)``.

    ``rot1`` is the direction of travel, ``trans`` the distance and ``rot2 = dtheta - rot1``
    (wrapped). Backward motion (``dx < 0``) is a negative translation along the reversed
    direction, so that reversing does not count as a half turn. Below ``min_translation`` the
    direction is not defined by the odometry's resolution: ``rot1 = 0`` (a turn in place).
    """
    d = jnp.asarray(delta)
    dx, dy = d[0], d[1]
    sign = jnp.where(dx < 0, -1.0, 1.0)
    sq = dx * dx + dy * dy
    dist = jnp.where(sq > 0, jnp.sqrt(jnp.where(sq > 0, sq, 1.0)), 0.0)
    moving = (sq > 0) & (dist >= min_translation)
    rot1 = jnp.where(moving, jnp.arctan2(sign * dy, jnp.where(moving, sign * dx, 1.0)), 0.0)
    return jnp.stack([rot1, sign * dist, wrap_angle(d[2] - rot1)])


def _compose_rtr(rtr: Float[Array, "3"]) -> Float[Array, "3"]:
    """The body-frame increment of a rotation, a translation and a rotation (not wrapped)."""
    s, c = jnp.sin(rtr[0]), jnp.cos(rtr[0])
    return jnp.stack([rtr[1] * c, rtr[1] * s, rtr[0] + rtr[2]])


class Odometry(AbstractMotionModel):
    """A robot with a pose stream as odometry: controls ``u = (vx, vy, omega)``, the body-frame
    rates of the increment between two odometry poses (see the module docstring), the pose the
    sensor's, mounted ``(sensor_x, sensor_y)`` from the robot's base in the base frame.

    The motion over ``dt`` is exact rigid-body composition of the base pose with
    ``delta = dt u``: ``b' = b + R(phi) delta_xy``, ``phi' = phi + delta_theta``, the sensor at
    ``b + R(phi) s``. The noise ``w`` is standard normal in three dimensions and enters the
    increment as ``delta + L w``, ``L L'`` the covariance of Thrun's rotation-translation-rotation
    model mapped to the increment, plus the floor (``noise = "custom"``: it depends on the
    controls).

    Attributes:
        alpha1: rotation noise from rotation (variance per squared radian).
        alpha2: rotation noise from translation (rad^2 per m^2).
        alpha3: translation noise from translation (variance per squared metre).
        alpha4: translation noise from rotation (m^2 per rad^2).
        floor_xy: standard deviation (m) added to each position coordinate of every piece's
            increment, so that the covariance is never singular.
        floor_phi: standard deviation (rad) added to the heading of every piece's increment.
        min_translation: below this distance (m) a piece's direction of travel is taken as
            straight ahead (``rot1 = 0``).
        sensor_x: sensor forward of the robot's base (m).
        sensor_y: sensor to the left of the robot's base (m).
    """

    control_dim: ClassVar[int] = 3
    noise: ClassVar[Literal["control", "additive", "custom"]] = "custom"
    rigid: ClassVar[bool] = True

    alpha1: Float[Array, ""] = eqx.field(default=_ODOMETRY.alpha1, converter=_f)
    alpha2: Float[Array, ""] = eqx.field(default=_ODOMETRY.alpha2, converter=_f)
    alpha3: Float[Array, ""] = eqx.field(default=_ODOMETRY.alpha3, converter=_f)
    alpha4: Float[Array, ""] = eqx.field(default=_ODOMETRY.alpha4, converter=_f)
    floor_xy: Float[Array, ""] = eqx.field(default=_ODOMETRY.floor_xy, converter=_f)
    floor_phi: Float[Array, ""] = eqx.field(default=math.radians(_ODOMETRY.floor_phi_deg), converter=_f)
    min_translation: Float[Array, ""] = eqx.field(default=_ODOMETRY.min_translation, converter=_f)
    sensor_x: Float[Array, ""] = eqx.field(default=_ODOMETRY.sensor_x, converter=_f)
    sensor_y: Float[Array, ""] = eqx.field(default=_ODOMETRY.sensor_y, converter=_f)

    def _move(self, x: Float[Array, "3"], delta: Float[Array, "3"]) -> Float[Array, "3"]:
        x = jnp.asarray(x)
        s0, c0 = sincos(x[2])
        phi = x[2] + delta[2]
        s1, c1 = sincos(phi)
        sx, sy = self.sensor_x, self.sensor_y
        # sensor' = sensor - R(phi) s + R(phi) delta_xy + R(phi') s
        ax, ay = delta[0] - sx, delta[1] - sy
        px = x[0] + c0 * ax - s0 * ay + c1 * sx - s1 * sy
        py = x[1] + s0 * ax + c0 * ay + s1 * sx + c1 * sy
        return jnp.stack([px, py, wrap_angle(phi)])

    def increment(self, u: Float[Array, " c"], dt: Float[ArrayLike, ""]) -> Float[Array, "3"]:
        """The body-frame increment ``dt u`` of one piece."""
        return jnp.asarray(dt, dtype=float) * jnp.asarray(u)[:3]

    def rtr_variances(self, rtr: Float[Array, "3"]) -> Float[Array, "3"]:
        """Thrun's variances of ``(rot1, trans, rot2)`` (the module docstring)."""
        r1, t, r2 = jnp.square(rtr[0]), jnp.square(rtr[1]), jnp.square(rtr[2])
        return jnp.stack(
            [
                self.alpha1 * r1 + self.alpha2 * t,
                self.alpha3 * t + self.alpha4 * (r1 + r2),
                self.alpha1 * r2 + self.alpha2 * t,
            ]
        )

    def increment_cov(self, u: Float[Array, " c"], dt: Float[ArrayLike, ""]) -> Float[Array, "3 3"]:
        """Covariance of one piece's body-frame increment: ``J M J' + floor``, ``M`` Thrun's
        variances of the decomposition and ``J`` the Jacobian of the increment with respect to
        it (autodiff)."""
        rtr = rot_trans_rot(self.increment(u, dt), self.min_translation)
        J = jax.jacfwd(_compose_rtr)(rtr)
        floor = jnp.stack([jnp.square(self.floor_xy), jnp.square(self.floor_xy), jnp.square(self.floor_phi)])
        Q = (J * self.rtr_variances(rtr)) @ J.T + jnp.diag(floor)
        return 0.5 * (Q + Q.T)

    def step(self, x, u, dt):
        return self._move(x, self.increment(u, dt))

    def noisy_step(self, x, u, w, dt):
        L = chol3(self.increment_cov(u, dt))
        return self._move(x, self.increment(u, dt) + L @ jnp.asarray(w))

    def noise_sqrt(self, dt):
        return jnp.eye(3, dtype=jnp.result_type(float))
