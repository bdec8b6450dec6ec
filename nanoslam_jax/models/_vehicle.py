"""The Victoria Park vehicle model (docs/method/victoria-park.md, "Vehicle model").

The state is the pose of the **laser**, ``x = (px, py, phi)``; the controls are the rear-left
encoder speed and the steering angle, ``u = (ve, alpha)``. Process noise enters on the controls,
so the functions here take the (possibly noisy) controls explicitly; Jacobians are obtained by
autodiff of :func:`vehicle_step` (see :func:`vehicle_jacobians`).
"""

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from nanoslam_jax.models._settings import VehicleConfig
from nanoslam_jax.lib._trig import sincos, tan
from nanoslam_jax.lib._angles import wrap_angle

#: The configuration's ``vehicle`` section: the one source of the defaults.
_VEHICLE = VehicleConfig()


class VehicleParams(NamedTuple):
    """Car constants (metres). All fields may be traced scalars.

    Attributes:
        wheelbase: L, distance between the axles.
        encoder_offset: H, lateral offset of the rear-left wheel encoder.
        laser_a: a, laser position forward of the rear axle.
        laser_b: b, laser position left of the centre line.
    """

    wheelbase: Float[ArrayLike, ""] = _VEHICLE.wheelbase
    encoder_offset: Float[ArrayLike, ""] = _VEHICLE.encoder_offset
    laser_a: Float[ArrayLike, ""] = _VEHICLE.laser_a
    laser_b: Float[ArrayLike, ""] = _VEHICLE.laser_b


def centre_speed(ve: Float[ArrayLike, ""], alpha: Float[ArrayLike, ""], params: VehicleParams) -> Float[Array, ""]:
    """Rear-axle centre speed from the encoder speed: ``vc = ve / (1 - tan(alpha) H / L)``."""
    return jnp.asarray(ve) / (1.0 - tan(alpha) * params.encoder_offset / params.wheelbase)


def vehicle_rates(u: Float[ArrayLike, "2"], params: VehicleParams) -> Float[Array, "2"]:
    """Centre speed and yaw rate ``(vc, vc tan(alpha) / L)`` from the controls ``u = (ve, alpha)``."""
    u = jnp.asarray(u)
    vc = centre_speed(u[0], u[1], params)
    return jnp.stack([vc, vc / params.wheelbase * tan(u[1])])


def vehicle_move(
    x: Float[ArrayLike, "3"], rates: Float[ArrayLike, "2"], dt: Float[ArrayLike, ""], params: VehicleParams
) -> Float[Array, "3"]:
    """Move the laser pose over ``dt`` at the given :func:`vehicle_rates` (heading wrapped)."""
    x, rates = jnp.asarray(x), jnp.asarray(rates)
    vc, w = rates[0], rates[1]
    a, b = params.laser_a, params.laser_b
    s, c = sincos(x[2])
    dx = vc * c - w * (a * s + b * c)
    dy = vc * s + w * (a * c - b * s)
    return jnp.stack([x[0] + dt * dx, x[1] + dt * dy, wrap_angle(x[2] + dt * w)])


def vehicle_step(
    x: Float[ArrayLike, "3"],
    u: Float[ArrayLike, "2"],
    dt: Float[ArrayLike, ""],
    params: VehicleParams,
) -> Float[Array, "3"]:
    """Move the laser pose over ``dt`` seconds holding the controls constant.

    Args:
        x: pose ``(px, py, phi)`` of the laser.
        u: controls ``(ve, alpha)``: encoder speed (m/s) and steering angle (rad, left positive).
        dt: interval (s); ``dt = 0`` leaves the pose unchanged (padding).
        params: car constants.

    Returns:
        The new pose, heading wrapped to (-pi, pi].
    """
    return vehicle_move(x, vehicle_rates(u, params), dt, params)


def vehicle_jacobians(
    x: Float[ArrayLike, "3"], u: Float[ArrayLike, "2"], dt: Float[ArrayLike, ""], params: VehicleParams
) -> tuple[Float[Array, "3 3"], Float[Array, "3 2"]]:
    """Jacobians of :func:`vehicle_step` with respect to the pose and the controls (autodiff)."""
    return jax.jacfwd(vehicle_step, argnums=(0, 1))(jnp.asarray(x), jnp.asarray(u), dt, params)
