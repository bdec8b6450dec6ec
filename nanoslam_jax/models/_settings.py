"""Settings of the built-in vehicles: the Victoria Park car's constants, the differential-drive
and random-walk models' sensor offsets and noise (in degrees where a user gives degrees)."""

from __future__ import annotations

from dataclasses import dataclass

from nanoslam_jax.lib._fields import _f

__all__ = ["VehicleConfig", "UnicycleConfig", "OdometryConfig", "RandomWalkConfig", "SensorDefaults"]


@dataclass(frozen=True)
class VehicleConfig:
    """Car constants of the Victoria Park vehicle model (metres); the model is in the docs, page
    method/victoria-park.md."""

    wheelbase: float = _f(2.83, lo=0.0, lo_open=True, doc="L: wheelbase")
    encoder_offset: float = _f(0.76, lo=0.0, doc="H: lateral offset of the rear-left wheel encoder")
    laser_a: float = _f(3.78, doc="a: laser forward of the rear axle")
    laser_b: float = _f(0.50, doc="b: laser to the left of the centre line")


@dataclass(frozen=True)
class UnicycleConfig:
    """The differential-drive motion model (model.motion: unicycle): controls (v, omega)."""

    sensor_x: float = _f(0.0, doc="sensor forward of the robot's centre (m)")
    sensor_y: float = _f(0.0, doc="sensor to the left of the robot's centre (m)")
    sigma_v: float = _f(0.05, lo=0.0, lo_open=True, doc="speed noise (m/s) per odometry sample")
    sigma_omega_deg: float = _f(5.0, lo=0.0, lo_open=True, doc="turn-rate noise (deg/s) per odometry sample")


@dataclass(frozen=True)
class OdometryConfig:
    """The odometry motion model (model.motion: odometry): controls (vx, vy, omega), the body-frame
    rates of the increment between two odometry poses, with the rotation-translation-rotation noise
    of Thrun's sample_motion_model_odometry (variances alpha1 rot1^2 + alpha2 trans^2 of each
    rotation, alpha3 trans^2 + alpha4 (rot1^2 + rot2^2) of the translation)."""

    alpha1: float = _f(0.05, lo=0.0, doc="rotation noise from rotation: variance (rad^2) per rad^2 turned")
    alpha2: float = _f(0.01, lo=0.0, doc="rotation noise from translation: variance (rad^2) per m^2 travelled")
    alpha3: float = _f(0.05, lo=0.0, doc="translation noise from translation: variance (m^2) per m^2 travelled")
    alpha4: float = _f(0.01, lo=0.0, doc="translation noise from rotation: variance (m^2) per rad^2 turned")
    floor_xy: float = _f(
        0.001, lo=0.0, lo_open=True, doc="noise floor (m, standard deviation) of each position coordinate per piece"
    )
    floor_phi_deg: float = _f(
        0.01, lo=0.0, lo_open=True, doc="noise floor (deg, standard deviation) of the heading per piece"
    )
    min_translation: float = _f(
        0.001,
        lo=0.0,
        doc="below this distance (m) per piece the direction of travel is straight ahead (a turn in place)",
    )
    sensor_x: float = _f(0.0, doc="sensor forward of the robot's base (m)")
    sensor_y: float = _f(0.0, doc="sensor to the left of the robot's base (m)")


@dataclass(frozen=True)
class RandomWalkConfig:
    """The random-walk motion model (model.motion: random_walk): no odometry, the pose driven by noise."""

    sigma_xy: float = _f(0.5, lo=0.0, lo_open=True, doc="position noise (m per square root of a second)")
    sigma_phi_deg: float = _f(10.0, lo=0.0, lo_open=True, doc="heading noise (deg per square root of a second)")


@dataclass(frozen=True)
class SensorDefaults:
    """The defaults of the built-in models' noise and sensor footprint: the published setting of
    the Victoria Park car and its laser. The configuration's ``noise``, ``data`` and ``map``
    sections take their defaults from here.

    Attributes:
        sigma_v: encoder speed noise (m/s) per log sample.
        sigma_alpha_deg: steering noise (deg) per log sample.
        sigma_r: range noise (m).
        sigma_beta_deg: bearing noise (deg).
        min_range: the sensor's minimum range (m).
        max_range: the sensor's range (m).
        fov_deg: the sensor's field of view (deg).
        view_margin: a landmark counts as in view this far (m) inside the range limits.
        view_margin_deg: ... and this far (deg) inside the field of view.
    """

    sigma_v: float = 2.0
    sigma_alpha_deg: float = 6.0
    sigma_r: float = 1.0
    sigma_beta_deg: float = 3.0
    min_range: float = 0.0
    max_range: float = 30.0
    fov_deg: float = 180.0
    view_margin: float = 3.0
    view_margin_deg: float = 2.5
