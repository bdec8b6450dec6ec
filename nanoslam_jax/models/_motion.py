"""Motion models: how a planar pose ``x = (px, py, phi)`` moves over one piece of the log.

A motion model is an :class:`equinox.Module` deriving from :class:`AbstractMotionModel`. Its
array fields are its traced parameters (constants and noise levels), so a model object is the
pytree the compiled filter receives: changing a value reuses the compiled program, changing the
model's class compiles a new one. The filter needs only

- :meth:`AbstractMotionModel.step`: the noise-free motion ``x' = f(x, u, dt)``;
- :meth:`AbstractMotionModel.noise_sqrt`: a lower square root of the process noise of one piece,
  either on the controls (``x' = f(x, u + w, dt)``, ``noise = "control"``), added to the pose
  (``x' = f(x, u, dt) + w``, ``noise = "additive"``) or applied by the model's own
  :meth:`~AbstractMotionModel.noisy_step` (``noise = "custom"``: noise whose effect depends on the
  controls, as the odometry model's does).

Jacobians come from autodiff of :meth:`~AbstractMotionModel.step`
(:meth:`~AbstractMotionModel.jacobians`). A model whose motion is a body-frame increment that
depends on the controls only (``x' = x (+) delta(u, dt)``) sets ``rigid = True``: its prior
commutes with rigid motions of the plane, which lets the particle filter compute a segment's
prior once for all particles. A model that derives from :class:`AbstractRateModel` splits its
step into ``rates(u)`` and ``move(x, rates, dt)``, which the unscented prior uses to move its
sigma points with fewer evaluations; the results are those of :meth:`step`.

Built in: :class:`Ackermann` (the Victoria Park car, encoder speed and steering),
:class:`Unicycle` (differential drive with ``(v, omega)`` odometry and an optional sensor offset),
:class:`RandomWalk` (no odometry: the pose is driven by process noise alone) and, in
:mod:`nanoslam_jax.models._odometry`, ``Odometry`` (a pose stream as odometry: body-frame
increments with Thrun's rotation-translation-rotation noise).
"""

from __future__ import annotations

import abc
import math
from typing import Any, ClassVar, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from nanoslam_jax.models._settings import RandomWalkConfig, SensorDefaults, UnicycleConfig, VehicleConfig
from nanoslam_jax.lib._angles import wrap_angle
from nanoslam_jax.models._vehicle import VehicleParams, vehicle_move, vehicle_rates, vehicle_step

__all__ = [
    "AbstractMotionModel",
    "AbstractRateModel",
    "Ackermann",
    "Unicycle",
    "RandomWalk",
    "check_motion_model",
]


# The built-in models' defaults: the settings classes of the vehicles and the sensor defaults (the
# configuration's sections take theirs from the same classes).
_VEHICLE, _NOISE, _UNICYCLE, _RANDOM_WALK = VehicleConfig(), SensorDefaults(), UnicycleConfig(), RandomWalkConfig()


def _f(x: Any) -> Array | np.ndarray:
    # Plain numbers stay NumPy so that building a model (config validation, for one) does not
    # start JAX's backend before a sweep has set up its devices.
    if isinstance(x, jax.Array):
        return jnp.asarray(x, dtype=float)
    return np.asarray(x, dtype=np.float64)


class AbstractMotionModel(eqx.Module):
    """A planar motion model with its traced parameters.

    Class attributes a model sets:
        control_dim: length of the control vector ``u`` of each log piece (0: none is used).
        noise: ``"control"`` (the noise ``w`` is added to the controls, ``noise_dim ==
            control_dim``), ``"additive"`` (``w`` is added to the pose, ``noise_dim == 3``) or
            ``"custom"`` (the model overrides :meth:`noisy_step`, which applies ``w``; ``noise_dim
            == 3`` unless the model overrides :attr:`noise_dim`; Jacobians with respect to ``w``
            at ``w = 0`` by autodiff of :meth:`noisy_step`).
        rigid: the motion is a body-frame increment depending on ``(u, dt)`` only and the noise
            is invariant under rotations of the plane (see the module docstring).
    """

    control_dim: ClassVar[int]
    noise: ClassVar[Literal["control", "additive", "custom"]]
    rigid: ClassVar[bool] = False

    @abc.abstractmethod
    def step(self, x: Float[Array, "3"], u: Float[Array, " c"], dt: Float[ArrayLike, ""]) -> Float[Array, "3"]:
        """Move the pose over ``dt`` seconds with the controls ``u`` held constant.

        Args:
            x: pose ``(px, py, phi)``.
            u: the piece's controls (``control_dim`` values; ignored when 0).
            dt: duration (s); ``dt = 0`` must leave the pose unchanged (padding).

        Returns:
            The new pose, heading wrapped to (-pi, pi].
        """

    @abc.abstractmethod
    def noise_sqrt(self, dt: Float[ArrayLike, ""]) -> Float[Array, "w w"]:
        """Lower square root of the process-noise covariance of one piece of duration ``dt``."""

    @property
    def noise_dim(self) -> int:
        """Length of the noise vector ``w``."""
        return self.control_dim if self.noise == "control" else 3

    def noise_cov(self, dt: Float[ArrayLike, ""]) -> Float[Array, "w w"]:
        """Process-noise covariance of one piece (``S S'`` of :meth:`noise_sqrt`)."""
        S = self.noise_sqrt(dt)
        return S @ S.T

    def noisy_step(
        self, x: Float[Array, "3"], u: Float[Array, " c"], w: Float[Array, " w"], dt: Float[ArrayLike, ""]
    ) -> Float[Array, "3"]:
        """:meth:`step` with the noise ``w`` applied (on the controls or added to the pose; a model
        with ``noise = "custom"`` overrides it)."""
        if self.noise == "control":
            return self.step(x, u + w, dt)
        if self.noise == "custom":
            raise NotImplementedError(f"{type(self).__name__}: a model with noise 'custom' overrides noisy_step")
        y = self.step(x, u, dt) + w
        return y.at[2].set(wrap_angle(y[2]))

    def jacobians(
        self, x: Float[Array, "3"], u: Float[Array, " c"], dt: Float[ArrayLike, ""]
    ) -> tuple[Float[Array, "3 3"], Float[Array, "3 w"]]:
        """Jacobians of the motion with respect to the pose and the noise (autodiff)."""
        if self.noise == "control":
            return jax.jacfwd(self.step, argnums=(0, 1))(x, u, dt)
        if self.noise == "custom":
            w = jnp.zeros((self.noise_dim,), dtype=jnp.result_type(x))
            return jax.jacfwd(self.noisy_step, argnums=(0, 2))(x, u, w, dt)
        F = jax.jacfwd(self.step)(x, u, dt)
        return F, jnp.eye(3, dtype=F.dtype)


class AbstractRateModel(AbstractMotionModel):
    """A motion model whose step is ``move(x, rates(u), dt)``: body-frame speed and turn rate
    from the controls, then the pose moved at those rates. Control noise enters through
    ``rates`` only, which the unscented prior uses (each sigma point perturbs either the pose or
    the controls)."""

    noise: ClassVar[Literal["control", "additive", "custom"]] = "control"
    rigid: ClassVar[bool] = True

    @abc.abstractmethod
    def rates(self, u: Float[Array, " c"]) -> Float[Array, "2"]:
        """Forward speed and turn rate ``(v, omega)`` of the body from the controls."""

    @abc.abstractmethod
    def move(self, x: Float[Array, "3"], rates: Float[Array, "2"], dt: Float[ArrayLike, ""]) -> Float[Array, "3"]:
        """Move the pose over ``dt`` at the given :meth:`rates` (heading wrapped)."""

    def step(self, x: Float[Array, "3"], u: Float[Array, " c"], dt: Float[ArrayLike, ""]) -> Float[Array, "3"]:
        return self.move(x, self.rates(u), dt)


class Ackermann(AbstractRateModel):
    """The Victoria Park car: the pose is the laser's, the controls are the rear-left wheel
    encoder speed and the steering angle ``u = (ve, alpha)``; noise on the controls, white per
    log sample (see the method page on the vehicle model).

    Attributes:
        wheelbase: L, distance between the axles (m).
        encoder_offset: H, lateral offset of the rear-left wheel encoder (m).
        laser_a: a, laser position forward of the rear axle (m).
        laser_b: b, laser position left of the centre line (m).
        sigma_v: encoder speed noise per log sample (m/s).
        sigma_alpha: steering noise per log sample (rad).
    """

    control_dim: ClassVar[int] = 2

    wheelbase: Float[Array, ""] = eqx.field(default=_VEHICLE.wheelbase, converter=_f)
    encoder_offset: Float[Array, ""] = eqx.field(default=_VEHICLE.encoder_offset, converter=_f)
    laser_a: Float[Array, ""] = eqx.field(default=_VEHICLE.laser_a, converter=_f)
    laser_b: Float[Array, ""] = eqx.field(default=_VEHICLE.laser_b, converter=_f)
    sigma_v: Float[Array, ""] = eqx.field(default=_NOISE.sigma_v, converter=_f)
    sigma_alpha: Float[Array, ""] = eqx.field(default=math.radians(_NOISE.sigma_alpha_deg), converter=_f)

    @property
    def vehicle(self) -> VehicleParams:
        """The car constants as :class:`VehicleParams`."""
        return VehicleParams(self.wheelbase, self.encoder_offset, self.laser_a, self.laser_b)

    def rates(self, u):
        return vehicle_rates(u, self.vehicle)

    def move(self, x, rates, dt):
        return vehicle_move(x, rates, dt, self.vehicle)

    def step(self, x, u, dt):
        return vehicle_step(x, u, dt, self.vehicle)

    def noise_sqrt(self, dt):
        return jnp.diag(jnp.stack([self.sigma_v, self.sigma_alpha]))

    def noise_cov(self, dt):
        return jnp.diag(jnp.stack([jnp.square(self.sigma_v), jnp.square(self.sigma_alpha)]))


class Unicycle(AbstractRateModel):
    """A differential-drive robot with ``(v, omega)`` odometry: forward speed (m/s) and turn rate
    (rad/s) of the robot's centre, held over each log piece; the pose is the sensor's, mounted
    ``(sensor_x, sensor_y)`` from the centre in the robot's frame (forward, left). Noise on the
    controls, white per log sample.

    The motion over ``dt`` is the first-order (Euler) step the Victoria Park model also uses:
    ``p' = p + dt (v R(phi) e_x + omega R(phi) J s)``, ``phi' = phi + dt omega``, with ``s`` the
    sensor offset and ``J`` the rotation by 90 degrees.

    Attributes:
        sensor_x: sensor forward of the robot's centre (m).
        sensor_y: sensor to the left of the robot's centre (m).
        sigma_v: speed noise per log sample (m/s).
        sigma_omega: turn-rate noise per log sample (rad/s).
    """

    control_dim: ClassVar[int] = 2

    sensor_x: Float[Array, ""] = eqx.field(default=_UNICYCLE.sensor_x, converter=_f)
    sensor_y: Float[Array, ""] = eqx.field(default=_UNICYCLE.sensor_y, converter=_f)
    sigma_v: Float[Array, ""] = eqx.field(default=_UNICYCLE.sigma_v, converter=_f)
    sigma_omega: Float[Array, ""] = eqx.field(default=math.radians(_UNICYCLE.sigma_omega_deg), converter=_f)

    def rates(self, u):
        return jnp.asarray(u)[:2]

    def move(self, x, rates, dt):
        # the car's move at given rates is that of a body with its sensor offset by (a, b)
        return vehicle_move(x, rates, dt, VehicleParams(laser_a=self.sensor_x, laser_b=self.sensor_y))

    def noise_sqrt(self, dt):
        return jnp.diag(jnp.stack([self.sigma_v, self.sigma_omega]))


class RandomWalk(AbstractMotionModel):
    """No odometry: the pose stays where it is and process noise alone moves it,
    ``x' = x + w`` with ``w ~ N(0, dt diag(s_xy^2, s_xy^2, s_phi^2))`` (a Wiener process; the
    position noise is isotropic, so the model commutes with rigid motions of the plane).

    Attributes:
        sigma_xy: position noise per square root of a second (m / sqrt(s)).
        sigma_phi: heading noise per square root of a second (rad / sqrt(s)).
    """

    control_dim: ClassVar[int] = 0
    noise: ClassVar[Literal["control", "additive", "custom"]] = "additive"
    rigid: ClassVar[bool] = True

    sigma_xy: Float[Array, ""] = eqx.field(default=_RANDOM_WALK.sigma_xy, converter=_f)
    sigma_phi: Float[Array, ""] = eqx.field(default=math.radians(_RANDOM_WALK.sigma_phi_deg), converter=_f)

    def step(self, x, u, dt):
        x = jnp.asarray(x)
        return x.at[2].set(wrap_angle(x[2]))

    def noise_sqrt(self, dt):
        r = jnp.sqrt(jnp.maximum(jnp.asarray(dt, dtype=float), 0.0))
        return jnp.diag(jnp.stack([self.sigma_xy * r, self.sigma_xy * r, self.sigma_phi * r]))


def check_motion_model(model: AbstractMotionModel) -> None:
    """Raise a ValueError naming the model's class and method when ``step`` (or, for a rate model,
    ``rates``) or ``noise_sqrt`` does not give the shape the filter needs: ``step(x (3,), u
    (control_dim,), dt ())`` a pose ``(3,)``, ``rates(u)`` ``(2,)``, ``noise_sqrt(dt)`` ``(noise_dim,
    noise_dim)``. Checked on abstract values (:func:`jax.eval_shape`): nothing is computed."""
    name = type(model).__name__
    dtype = jnp.result_type(float)
    x = jax.ShapeDtypeStruct((3,), dtype)
    u = jax.ShapeDtypeStruct((int(model.control_dim),), dtype)
    dt = jax.ShapeDtypeStruct((), dtype)
    checks: list[tuple[str, str, Any, tuple[int, ...], str]] = [
        ("step", "x, u, dt", lambda m, x, u, dt: m.step(x, u, dt), (3,), "a pose")
    ]
    if isinstance(model, AbstractRateModel):
        checks.append(("rates", "u", lambda m, x, u, dt: m.rates(u), (2,), "the rates"))
    w = model.noise_dim
    checks.append(("noise_sqrt", "dt", lambda m, x, u, dt: m.noise_sqrt(dt), (w, w), f"a {w} x {w} square root"))
    where = f"x {x.shape}, u {u.shape}, dt ()"
    for method, args, call, shape, what in checks:
        try:
            out = jax.eval_shape(call, model, x, u, dt)
        except Exception as e:  # the user's code: report what it raised, with the model and method
            raise ValueError(
                f"motion model {name}.{method}({args}) failed on abstract inputs ({where}; control_dim "
                f"{model.control_dim}): {type(e).__name__}: {e}"
            ) from None
        got = getattr(out, "shape", None)
        if got != shape:
            raise ValueError(
                f"motion model {name}.{method}({args}): expected {what} of shape {shape}, got "
                f"{'shape ' + str(got) if got is not None else type(out).__name__} (inputs {where}; "
                f"control_dim {model.control_dim}, noise {model.noise!r})"
            )
