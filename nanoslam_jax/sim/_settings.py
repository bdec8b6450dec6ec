"""The simulators' settings: the park-like log, the city and the indoor scenario."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from nanoslam_jax.lib._fields import _f

__all__ = ["SimConfig", "CityConfig", "IndoorConfig"]


@dataclass(frozen=True)
class SimConfig:
    """The Victoria Park-like simulator (data.kind = simulated)."""

    seed: int = _f(0, lo=0, static=True, doc="seed of the simulated world and log")
    duration: float = _f(240.0, lo=0.0, lo_open=True, static=True, doc="seconds driven")
    n_trees: int = _f(
        250,
        lo=1,
        static=True,
        doc="trees in the park (250: 5.8 detections per scan on the default path; the real log has 5.2 at r < 30 m)",
    )
    area: float = _f(200.0, lo=10.0, static=True, doc="side of the square park (m)")
    speed: float = _f(3.0, lo=0.0, lo_open=True, static=True, doc="mean encoder speed (m/s)")
    loops: float = _f(2.0, lo=0.0, static=True, doc="number of loops driven")
    dr_rate: float = _f(40.0, lo=1.0, static=True, doc="dead-reckoning rate (Hz)")
    scan_rate: float = _f(4.7, lo=0.1, static=True, doc="laser scan rate (Hz)")
    max_range: float = _f(30.0, lo=1.0, static=True, doc="range of the simulated laser (m)")
    fov_deg: float = _f(180.0, lo=1.0, hi=360.0, static=True, doc="field of view of the simulated laser (deg)")
    p_detect: float = _f(0.75, lo=0.0, hi=1.0, static=True, doc="probability that a tree in view is detected in a scan")
    clutter_rate: float = _f(0.2, lo=0.0, static=True, doc="mean false detections per scan")
    sigma_r: float = _f(0.3, lo=0.0, static=True, doc="true range noise (m)")
    sigma_beta_deg: float = _f(1.0, lo=0.0, static=True, doc="true bearing noise (deg)")
    sigma_v: float = _f(0.3, lo=0.0, static=True, doc="true encoder speed noise (m/s), white, per DR sample")
    sigma_alpha_deg: float = _f(2.0, lo=0.0, static=True, doc="true steering noise (deg), white, per DR sample")
    sigma_omega_deg: float = _f(
        2.0,
        lo=0.0,
        static=True,
        doc="true turn-rate noise (deg/s), white, per DR sample, of a differential-drive robot (model.motion: unicycle)",
    )
    omega_bias_deg: float = _f(
        0.5, static=True, doc="constant turn-rate bias in the logged controls of a differential-drive robot (deg/s)"
    )
    steering_bias_deg: float = _f(
        0.3,
        static=True,
        doc="constant steering bias in the logged controls (deg): dead reckoning drifts like the real "
        "vehicle's (about 40 m RMSE over the default 240 s log)",
    )
    laser_beams: int = _f(
        361,
        lo=2,
        static=True,
        doc="raw scans (nanoslam simulate --laser): beams per scan, evenly spread over laser_fov_deg",
    )
    laser_fov_deg: float = _f(
        180.0,
        lo=1.0,
        hi=360.0,
        static=True,
        doc="raw scans: field of view (deg), symmetric about straight ahead (Victoria Park's SICK: 180 at 0.5 deg)",
    )
    laser_max_range: float = _f(
        80.0,
        lo=1.0,
        static=True,
        doc="raw scans: surfaces at or beyond this range (m) give no return, written as 81.91 as in the real log",
    )
    laser_range_noise: float = _f(0.02, lo=0.0, static=True, doc="raw scans: range noise (m, one sigma) of a return")
    laser_dropout: float = _f(
        0.005,
        lo=0.0,
        hi=1.0,
        static=True,
        doc="raw scans: probability that a beam which hits a surface returns nothing",
    )
    laser_spurious: float = _f(
        0.001,
        lo=0.0,
        hi=1.0,
        static=True,
        doc="raw scans: probability that a beam reports a spurious range, uniform between 0.5 m and its true "
        "range (or laser_max_range for a beam with no surface)",
    )
    laser_walls: int = _f(
        4, lo=0, static=True, doc="raw scans: solid walls (straight segments 8 to 40 m long) in the park"
    )
    laser_fences: int = _f(
        4,
        lo=0,
        static=True,
        doc="raw scans: wire fences (straight segments 8 to 40 m long) in the park; a beam crossing one returns "
        "from it with probability laser_fence_return, else passes through",
    )
    laser_fence_return: float = _f(
        0.7, lo=0.0, hi=1.0, static=True, doc="raw scans: probability that a beam crossing a fence returns from it"
    )
    laser_bushes: int = _f(
        60,
        lo=0,
        static=True,
        doc="raw scans: bushes (irregular star-shaped outlines of 20 vertices, mean radius 0.5 to 2 m, each "
        "vertex's radius varied by up to laser_bush_roughness) in the park",
    )
    laser_bush_roughness: float = _f(
        0.35,
        lo=0.0,
        hi=0.9,
        static=True,
        doc="raw scans: the largest relative variation of a bush outline's radius between its vertices",
    )
    laser_clearance: float = _f(
        1.0,
        lo=0.0,
        static=True,
        doc="raw scans: walls, fences and bushes keep at least this gap (m) to every trunk, and 3 m to the path",
    )


@dataclass(frozen=True)
class CityConfig:
    """The city (``nanoslam simulate --scenario city``, ``data.kind: city``; docs/simulate_city.md): a car
    drives a street grid lined with trees and lamp posts, with the park's sensor, detections, clutter,
    misses, speed, rates and odometry noise (section sim)."""

    seed: int = _f(0, lo=0, static=True, doc="seed of the city, the route, the odometry noise and the detections")
    distance_m: float = _f(20000.0, lo=100.0, static=True, doc="distance driven (m), at the mean speed sim.speed")
    blocks: int = _f(
        12,
        lo=2,
        static=True,
        doc="the city is blocks x blocks square blocks; blocks + 1 streets run each way (12: 1.4 km across)",
    )
    block_size: float = _f(
        100.0, lo=30.0, hi=1000.0, static=True, doc="side of a block (m), from kerb to kerb across it"
    )
    street_width: float = _f(
        16.0,
        lo=6.0,
        hi=60.0,
        static=True,
        doc="width of a street (m) from kerb to kerb; the car drives its centreline, the trees stand on the kerbs",
    )
    tree_spacing: float = _f(
        10.0,
        lo=2.0,
        static=True,
        doc="trees along each side of every street: floor(block_size / tree_spacing) per block side, evenly spaced",
    )
    tree_jitter: float = _f(
        1.5,
        lo=0.0,
        static=True,
        doc="a street tree moves by up to this (m, uniform) along its kerb from its even spot, and up to 0.5 m "
        "into the block",
    )
    interior_density: float = _f(
        32.0,
        lo=0.0,
        static=True,
        doc="trees per hectare in the blocks' interiors (the block less a 5 m margin; the count per block is "
        "rounded): defaults give 10,080 landmarks",
    )
    lamp_posts: bool = _f(
        True,
        static=True,
        doc="a lamp post (diameter 0.15 to 0.25 m) at every corner of every block, 1 m in from both kerbs",
    )
    turn_radius: float = _f(
        8.0,
        lo=6.0,
        hi=30.0,
        static=True,
        doc="radius (m) of the route's arcs at turns (the car's tightest turn is about 6 m); at most "
        "street_width / 2 + block_size / 4",
    )
    p_straight: float = _f(
        0.5,
        lo=0.0,
        hi=1.0,
        static=True,
        doc="at an intersection the route goes straight with this probability, else turns left or right "
        "(equally likely; never back, never off the grid)",
    )
    revisit_every_m: float = _f(
        2000.0,
        lo=0.0,
        static=True,
        doc="every this many metres (m; 0: never) the route drives the shortest way to the street it has not "
        "driven for the longest (of those it left at least this far back) and along it, then walks on",
    )


@dataclass(frozen=True)
class IndoorConfig:
    """The indoor scenario (``nanoslam simulate --scenario indoor``, docs/simulate_indoor.md): rooms or
    corridors of walls, corners, doors and round pillars, a low-speed differential-drive vehicle with wheel
    slip, raw laser scans and the truth of every line, arc, corner and break point."""

    seed: int = _f(0, lo=0, static=True, doc="seed of the world, the drive, the odometry noise and the scans")
    template: Literal["random", "room", "l_room", "corridor"] = _f(
        "random",
        static=True,
        doc="the world: 'room' (rectangular, a far corner cut by a slanted wall half the time), 'l_room' "
        "(L-shaped), 'corridor' (a ring corridor around a block of rooms, one side a wide hall), 'random' "
        "(one of them, drawn by the seed); sizes, doors and pillars are drawn by the seed",
    )
    duration: float = _f(120.0, lo=0.0, lo_open=True, static=True, doc="seconds logged")
    odom_period: float = _f(
        0.025, lo=0.001, hi=1.0, static=True, doc="odometry (v, omega) period (s); the paper's data period is 25 ms"
    )
    scan_period: float = _f(
        0.025,
        lo=0.001,
        hi=10.0,
        static=True,
        doc="laser scan period (s), scans at 0, scan_period, ...; the paper's data period is 25 ms",
    )
    static_time: float = _f(
        2.0,
        lo=0.0,
        static=True,
        doc="the vehicle stands still this long (s) before it drives (the paper's static state estimation)",
    )
    speed_min: float = _f(
        0.2,
        lo=0.0,
        lo_open=True,
        hi=2.0,
        static=True,
        doc="the speed profile swings between speed_min and speed_max (m/s) with a period of 20 to 40 s",
    )
    speed_max: float = _f(0.5, lo=0.0, lo_open=True, hi=2.0, static=True, doc="see speed_min (m/s)")
    max_turn_rate_deg: float = _f(
        40.0,
        lo=1.0,
        hi=360.0,
        static=True,
        doc="the vehicle slows down before arcs so that its turn rate stays below this (deg/s)",
    )
    turn_radius: float = _f(
        0.8,
        lo=0.05,
        hi=5.0,
        static=True,
        doc="radius (m) the path's corners are rounded with; smaller where the arc would pass within 0.5 m of a wall",
    )
    path_inset: float = _f(
        1.3,
        lo=0.5,
        hi=3.0,
        static=True,
        doc="rooms: the path runs this far (m) inside the walls (corridors: along their middle)",
    )
    sensor_ls: float = _f(
        0.18,
        lo=-2.0,
        hi=2.0,
        static=True,
        doc="the laser sits this far (m) behind the reference point (the centre of the wheel axle), the "
        "paper's Ls = 180 mm; negative: ahead. A run on the log uses model.motion unicycle with "
        "unicycle.sensor_x = -sensor_ls",
    )
    sigma_v: float = _f(0.01, lo=0.0, static=True, doc="odometry speed noise (m/s, one sigma, white per sample)")
    sigma_omega_deg: float = _f(
        1.0, lo=0.0, static=True, doc="odometry turn-rate noise (deg/s, one sigma, white per sample)"
    )
    slip_factor: float = _f(
        5.0,
        lo=1.0,
        static=True,
        doc="wheel slip: the odometry noise's standard deviations are this many times larger in slip episodes",
    )
    slip_fraction: float = _f(
        0.2, lo=0.0, hi=0.95, static=True, doc="mean fraction of the time in slip episodes (0: no slip)"
    )
    slip_duration: float = _f(
        4.0,
        lo=0.0,
        lo_open=True,
        static=True,
        doc="mean length of a slip episode (s); episodes and the stretches between them are exponentially distributed",
    )
    laser_beams: int = _f(
        361,
        lo=2,
        static=True,
        doc="beams per scan, evenly over fov_deg (nanoslam detect and data.detections: laser read 361-beam files)",
    )
    fov_deg: float = _f(180.0, lo=1.0, hi=360.0, static=True, doc="field of view (deg), symmetric about ahead")
    max_range: float = _f(
        10.0, lo=0.5, hi=80.0, static=True, doc="surfaces at or beyond this range (m) give no return (written as 81.91)"
    )
    range_noise: float = _f(0.01, lo=0.0, static=True, doc="range noise (m, one sigma) of a return")
    dropout: float = _f(
        0.002, lo=0.0, hi=1.0, static=True, doc="probability that a beam which hits a surface returns nothing"
    )
    spurious: float = _f(
        0.0005,
        lo=0.0,
        hi=1.0,
        static=True,
        doc="probability that a beam reports a spurious range, uniform between 0.1 m and its true range (or max_range)",
    )
    doors: int = _f(
        2,
        lo=0,
        static=True,
        doc="door gaps cut into the walls (their jambs are break points), 0.5 m at least from corners",
    )
    door_width: float = _f(0.9, lo=0.1, hi=5.0, static=True, doc="width of a door gap (m)")
    pillars: int = _f(1, lo=1, hi=6, static=True, doc="round pillars (arcs) in the world")
    pillar_radius_min: float = _f(
        0.15,
        lo=0.02,
        hi=1.0,
        static=True,
        doc="pillar radii are drawn between pillar_radius_min and pillar_radius_max (m)",
    )
    pillar_radius_max: float = _f(0.35, lo=0.02, hi=1.0, static=True, doc="see pillar_radius_min (m)")
    partitions: int = _f(
        1,
        lo=0,
        hi=6,
        static=True,
        doc="free-standing partition walls (screens, cabinets) at random angles, 0.5 m from the walls, the path "
        "and the pillars; their two free ends are break points",
    )
    partition_length: float = _f(1.2, lo=0.2, hi=5.0, static=True, doc="length of a partition wall (m)")
