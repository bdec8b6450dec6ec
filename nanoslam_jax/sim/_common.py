"""What the park and the city simulators share: the driver, the vehicle's truth, the sensor and the noise.

The park (:mod:`.park`) and the city (:mod:`.city`) differ in their worlds and routes only. Both
drive a rear-axle reference path with the pure-pursuit driver of :func:`drive`, log the true
controls plus white noise and a steering bias (:func:`logged_controls`), scan at jittered times
(:func:`scan_times`), detect landmarks with range and bearing noise, misses and clutter
(:func:`detections`) and keep the truth (:func:`truth_streams`); the module docstring of
:mod:`.park` describes each step. Every function draws from the ``Generator`` it is given in a
fixed order, so a seed gives the same log whatever calls it.
"""

from __future__ import annotations

import math
from typing import NamedTuple, Optional

import numpy as np

from nanoslam_jax.data._types import RawLog
from nanoslam_jax.lib._angles import wrap_angle_np
from nanoslam_jax.models._settings import UnicycleConfig, VehicleConfig
from nanoslam_jax.sim._settings import SimConfig

#: GPS rate of the simulated logs (Hz).
GPS_RATE = 5.0
#: Bound on the true steering angle (rad).
MAX_STEER = 0.45
#: Steering rate limit (rad/s) and first-order steering lag (s) of the simulated driver.
STEER_RATE = 0.6
STEER_TAU = 0.25


def wrap_scalar(a: float) -> float:
    w = math.fmod(a + math.pi, 2.0 * math.pi)
    if w < 0.0:
        w += 2.0 * math.pi
    w -= math.pi
    return w + 2.0 * math.pi if w <= -math.pi else w


def step_np(x: np.ndarray, u: np.ndarray, dt: np.ndarray, vehicle: VehicleConfig) -> np.ndarray:
    """Vectorised numpy twin of :func:`nanoslam_jax.models.vehicle_step`.

    Args:
        x: ``(n, 3)`` laser poses.
        u: ``(n, 2)`` controls ``(ve, alpha)``.
        dt: ``(n,)`` intervals (s).
        vehicle: car constants.

    Returns:
        ``(n, 3)`` poses after ``dt``, heading wrapped.
    """
    L, H, a, b = vehicle.wheelbase, vehicle.encoder_offset, vehicle.laser_a, vehicle.laser_b
    phi, ve, alpha = x[:, 2], u[:, 0], u[:, 1]
    vc = ve / (1.0 - np.tan(alpha) * H / L)
    w = vc / L * np.tan(alpha)
    s, c = np.sin(phi), np.cos(phi)
    dx = vc * c - w * (a * s + b * c)
    dy = vc * s + w * (a * c - b * s)
    return np.stack([x[:, 0] + dt * dx, x[:, 1] + dt * dy, wrap_angle_np(phi + dt * w)], axis=1)


def drive(
    path: np.ndarray, ve: np.ndarray, dt: float, vehicle: VehicleConfig, lookahead: float, closed: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """Pure-pursuit driving of the laser pose along ``path``; returns (poses (n, 3), alpha (n,)).

    ``poses[k]`` is the pose at DR sample ``k``; ``alpha[k]`` the true steering held over
    ``[t_k, t_k + dt)``. The rear axle starts at ``-(laser_a, laser_b)`` heading +x (the laser at
    pose 0) and near ``path[0]``. ``closed``: the path is a loop (its last point joins the first);
    otherwise it is an open polyline, which must reach a lookahead beyond where the drive ends.
    Plain-Python scalar loop (about 10k steps per 0.1 s).
    """
    L, H, a, b = vehicle.wheelbase, vehicle.encoder_offset, vehicle.laser_a, vehicle.laser_b
    n = ve.shape[0]
    px_l, py_l = path[:, 0].tolist(), path[:, 1].tolist()
    m = len(px_l)
    ds = float(np.mean(np.hypot(*np.diff(np.vstack([path, path[:1]]) if closed else path, axis=0).T)))
    n_look = max(1, int(round(lookahead / ds)))
    poses = np.empty((n, 3))
    alphas = np.empty(n)
    x = y = phi = 0.0
    alpha = 0.0
    idx = 0
    max_dalpha = STEER_RATE * dt
    for k in range(n):
        poses[k, 0], poses[k, 1], poses[k, 2] = x, y, phi
        s, c = math.sin(phi), math.cos(phi)
        rx, ry = x - a * c + b * s, y - a * s - b * c  # rear-axle centre
        # nearest path point: hill-climb forward from the last one
        i0 = idx % m
        d_cur = (px_l[i0] - rx) ** 2 + (py_l[i0] - ry) ** 2
        for _ in range(m):
            if not closed and idx + 1 >= m:
                break
            i1 = (idx + 1) % m
            d_next = (px_l[i1] - rx) ** 2 + (py_l[i1] - ry) ** 2
            if d_next > d_cur:
                break
            idx, d_cur = idx + 1, d_next
        g = (idx + n_look) % m if closed else min(idx + n_look, m - 1)
        gx, gy = px_l[g] - rx, py_l[g] - ry
        lx, ly = c * gx + s * gy, -s * gx + c * gy
        kappa = 2.0 * ly / max(lx * lx + ly * ly, 1e-9)
        cmd = min(max(math.atan(L * kappa), -MAX_STEER), MAX_STEER)
        d_alpha = (cmd - alpha) * min(dt / STEER_TAU, 1.0)
        alpha = min(max(alpha + min(max(d_alpha, -max_dalpha), max_dalpha), -MAX_STEER), MAX_STEER)
        alphas[k] = alpha
        # vehicle model (same expression order as nanoslam_jax.models.vehicle_step)
        ta = math.tan(alpha)
        vc = ve[k] / (1.0 - ta * H / L)
        w = vc / L * ta
        x = x + dt * (vc * c - w * (a * s + b * c))
        y = y + dt * (vc * s + w * (a * c - b * s))
        phi = wrap_scalar(phi + dt * w)
    return poses, alphas


def poses_at(
    times: np.ndarray, dr_t: np.ndarray, dr_poses: np.ndarray, u: np.ndarray, vehicle: VehicleConfig
) -> np.ndarray:
    """True poses at arbitrary times inside the DR span (held control over the remaining fraction).

    Args:
        times: ``(n,)`` query times in ``[dr_t[0], dr_t[-1]]``.
        dr_t: ``(N,)`` DR sample times.
        dr_poses: ``(N, 3)`` true poses at the DR samples.
        u: ``(N, 2)`` true controls held over each DR interval.
        vehicle: car constants.

    Returns:
        ``(n, 3)`` poses.
    """
    idx = np.clip(np.searchsorted(dr_t, times, side="right") - 1, 0, dr_t.shape[0] - 1)
    return step_np(dr_poses[idx], u[idx], times - dr_t[idx], vehicle)


def vehicle_for(vehicle: VehicleConfig, unicycle: Optional[UnicycleConfig]) -> VehicleConfig:
    """The car's constants, or those that move a differential-drive robot's sensor as the car's model does."""
    if unicycle is None:
        return vehicle
    # the car's model with no encoder offset moves the sensor as a unicycle does
    return VehicleConfig(
        wheelbase=vehicle.wheelbase, encoder_offset=0.0, laser_a=unicycle.sensor_x, laser_b=unicycle.sensor_y
    )


def speed_profile(speed: float, dr_t: np.ndarray, rng_prof: np.random.Generator) -> np.ndarray:
    """The true encoder speed at the DR samples: ``speed * ramp(t) * (1 + 0.1 sin(...))`` from rest in 3 s."""
    period = rng_prof.uniform(25.0, 45.0)
    phase = rng_prof.uniform(0.0, 2.0 * np.pi)
    ramp = np.clip(dr_t / 3.0, 0.0, 1.0)
    ramp = ramp * ramp * (3.0 - 2.0 * ramp)  # smoothstep: start from rest
    return speed * ramp * (1.0 + 0.1 * np.sin(2.0 * np.pi * dr_t / period + phase))


def logged_controls(
    dr_t: np.ndarray,
    ve_true: np.ndarray,
    alpha_true: np.ndarray,
    sim: SimConfig,
    vehicle: VehicleConfig,
    rng_ctrl: np.random.Generator,
    unicycle: bool = False,
) -> np.ndarray:
    """The LOGGED controls ``(N, 3)``: the true ones plus white noise plus a constant bias.

    ``time, ve, alpha`` for the car (``sim.sigma_v``, ``sim.sigma_alpha_deg``,
    ``sim.steering_bias_deg``); with ``unicycle``, ``time, v, omega`` of a differential-drive robot
    (``sim.sigma_omega_deg``, ``sim.omega_bias_deg``).
    """
    n_dr = dr_t.shape[0]
    ve_log = ve_true + rng_ctrl.normal(0.0, 1.0, n_dr) * sim.sigma_v
    alpha_log = (
        alpha_true
        + rng_ctrl.normal(0.0, 1.0, n_dr) * math.radians(sim.sigma_alpha_deg)
        + math.radians(sim.steering_bias_deg)
    )
    dr = np.stack([dr_t, ve_log, alpha_log], axis=1)
    if unicycle:
        omega_true = ve_true / vehicle.wheelbase * np.tan(alpha_true)
        omega_log = (
            omega_true
            + rng_ctrl.normal(0.0, 1.0, n_dr) * math.radians(sim.sigma_omega_deg)
            + math.radians(sim.omega_bias_deg)
        )
        dr = np.stack([dr_t, ve_log, omega_log], axis=1)
    return dr


def scan_times(t_end: float, sim: SimConfig, rng_prof: np.random.Generator) -> np.ndarray:
    """Scan times at about ``sim.scan_rate`` Hz (random phase, +-5 % jitter), never on a DR sample, in ``(0, t_end)``."""
    scan_period = 1.0 / sim.scan_rate
    n_scan = int(math.floor(t_end / scan_period)) + 2
    scan_t = rng_prof.uniform(0.05, 0.95) * scan_period + np.arange(n_scan) * scan_period
    scan_t = scan_t + rng_prof.uniform(-0.05, 0.05, n_scan) * scan_period
    frac = scan_t * sim.dr_rate - np.round(scan_t * sim.dr_rate)
    scan_t = np.where(np.abs(frac) < 0.02, scan_t + 0.05 / sim.dr_rate, scan_t)
    return scan_t[(scan_t > 0.0) & (scan_t < t_end)]


def detections(
    scan_t: np.ndarray,
    scan_poses: np.ndarray,
    landmarks: np.ndarray,
    diameters: np.ndarray,
    sim: SimConfig,
    rng_det: np.random.Generator,
    rng_clut: np.random.Generator,
    pairs: Optional[tuple[np.ndarray, np.ndarray]] = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The detections of the landmarks and the clutter, sorted by time and bearing.

    Args:
        scan_t: ``(S,)`` scan times.
        scan_poses: ``(S, 3)`` true laser poses at the scan times.
        landmarks: ``(L, 2)`` true landmark positions.
        diameters: ``(L,)`` true diameters.
        sim: the sensor and its noise (``max_range``, ``fov_deg``, ``sigma_r``, ``sigma_beta_deg``,
            ``p_detect``, ``clutter_rate``).
        rng_det: the stream of the detections' noise and misses.
        rng_clut: the stream of the clutter.
        pairs: ``(scan index, landmark index)`` of the candidate pairs, in scan order (a landmark
            that no pair names is never detected in that scan); ``None``: every landmark in every
            scan, in row-major order.

    Returns:
        ``(det, ids)``: ``(M, 4)`` rows ``time, range, bearing, diameter`` and ``(M,)`` the
        landmark each is of (-1: clutter).
    """
    max_range = sim.max_range
    half_fov = 0.5 * math.radians(sim.fov_deg)
    n_s, n_l = scan_t.shape[0], landmarks.shape[0]
    if pairs is None:
        si, li = np.repeat(np.arange(n_s), n_l), np.tile(np.arange(n_l), n_s)
    else:
        si, li = pairs
    n_p = si.shape[0]
    dx = landmarks[li, 0] - scan_poses[si, 0]
    dy = landmarks[li, 1] - scan_poses[si, 1]
    r = np.hypot(dx, dy) + rng_det.normal(0.0, 1.0, n_p) * sim.sigma_r
    beta_noise = rng_det.normal(0.0, 1.0, n_p) * math.radians(sim.sigma_beta_deg)
    beta = wrap_angle_np(np.arctan2(dy, dx) - scan_poses[si, 2] + beta_noise)
    hit = rng_det.random(n_p) < sim.p_detect
    diam = np.clip(diameters[li] + rng_det.normal(0.0, 0.02, n_p), 0.1, 0.6)
    (k,) = np.nonzero(hit & (r > 0.0) & (r < max_range) & (np.abs(beta) <= half_fov))
    rows = [np.stack([scan_t[si[k]], r[k], beta[k], diam[k]], axis=1)]
    ids = [li[k]]

    # ---- clutter: Poisson per scan, uniform over the footprint sector
    n_clut = np.asarray(rng_clut.poisson(sim.clutter_rate, n_s) if sim.clutter_rate > 0 else np.zeros(n_s, int))
    tot = int(n_clut.sum())
    if tot:
        c_t = np.repeat(scan_t, n_clut)
        c_r = max_range * np.sqrt(1.0 - rng_clut.random(tot))  # in (0, max_range]
        c_r = np.minimum(c_r, np.nextafter(max_range, 0.0))
        c_b = wrap_angle_np(rng_clut.uniform(-half_fov, half_fov, tot))
        c_d = rng_clut.uniform(0.1, 0.6, tot)
        rows.append(np.stack([c_t, c_r, c_b, c_d], axis=1))
        ids.append(np.full(tot, -1))
    det = np.concatenate(rows, axis=0)
    order = np.lexsort((det[:, 2], det[:, 0]))
    return det[order], np.concatenate(ids)[order]


class DriveTruth(NamedTuple):
    """A simulated drive: its logged controls and the truth at the DR samples and the scans.

    Attributes:
        dr: ``(N, 3)`` logged controls (their first column the DR times).
        dr_poses: ``(N, 3)`` true laser poses at the DR samples.
        u_true: ``(N, 2)`` true controls held over each DR interval.
        scan_t: ``(S,)`` scan times.
        scan_poses: ``(S, 3)`` the true poses at the scan times.
    """

    dr: np.ndarray
    dr_poses: np.ndarray
    u_true: np.ndarray
    scan_t: np.ndarray
    scan_poses: np.ndarray


def simulated_log(
    truth: DriveTruth,
    det: np.ndarray,
    det_ids: np.ndarray,
    landmarks: np.ndarray,
    diameters: np.ndarray,
    vehicle: VehicleConfig,
) -> RawLog:
    """The :class:`RawLog` of a simulated drive with its truth: poses at every DR and scan time, GPS at 5 Hz.

    Args:
        truth: the logged controls and the true poses (:class:`DriveTruth`).
        det: ``(M, 4)`` detections; det_ids: ``(M,)`` their landmarks (-1: clutter).
        landmarks: ``(L, 2)``; diameters: ``(L,)``.
        vehicle: car constants (the poses between DR samples).
    """
    dr, dr_poses, u_true, scan_t, scan_poses = truth
    dr_t = dr[:, 0]
    t_end = dr_t[-1]
    gps_t = np.arange(int(math.floor(t_end * GPS_RATE + 1e-9)) + 1) / GPS_RATE
    gps_t = gps_t[gps_t <= t_end]
    gps_xy = poses_at(gps_t, dr_t, dr_poses, u_true, vehicle)[:, :2]
    truth_t = np.concatenate([dr_t, scan_t])
    truth_p = np.concatenate([dr_poses, scan_poses], axis=0)
    order = np.argsort(truth_t, kind="stable")
    truth_poses = np.concatenate([truth_t[order, None], truth_p[order]], axis=1)
    return RawLog(
        dr=dr,
        detections=det,
        gps=np.concatenate([gps_t[:, None], gps_xy], axis=1),
        truth_poses=truth_poses,
        truth_landmarks=landmarks,
        truth_diameters=diameters,
        source="simulated",
        detection_ids=det_ids,
        landmark_ids=np.arange(landmarks.shape[0]),
    )
