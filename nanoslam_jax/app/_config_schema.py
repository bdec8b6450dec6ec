"""The configuration's schema: one frozen dataclass per section, each field with its default, its
valid range, whether it is static (changes array shapes or the compiled program) or traced
(sweepable without recompiling), and its meaning (``dataclasses.field`` metadata, read by the
validation in :mod:`nanoslam_jax.app.config` and by :mod:`nanoslam_jax.app.config_reference`).

The sections of the core's own settings are defined next to what they set and imported here:
``noise``, ``filter`` and ``map`` (:mod:`nanoslam_jax.methods`), the methods' sections, the
models', the detector's, the simulators', the smoother's and the metrics'.

Import these names from :mod:`nanoslam_jax.app.config`, which loads and validates them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, Optional

from nanoslam_jax.lib._fields import _f
from nanoslam_jax.methods._builtin import ADAPTIVE_NOISE_METHODS as ADAPTIVE_NOISE_METHODS
from nanoslam_jax.methods._method_settings import IteratedConfig, NanoConfig, NasrukfConfig
from nanoslam_jax.methods._settings import FilterConfig, MapConfig, NoiseConfig
from nanoslam_jax.eval._settings import MetricsConfig
from nanoslam_jax.frontend._settings import DetectorConfig
from nanoslam_jax.models._settings import (
    OdometryConfig,
    RandomWalkConfig,
    SensorDefaults,
    UnicycleConfig,
    VehicleConfig,
)
from nanoslam_jax.sim._settings import CityConfig, IndoorConfig, SimConfig
from nanoslam_jax.smoother._settings import SmootherConfig

#: The built-in models' sensor defaults, which the data section takes.
_SENSOR = SensorDefaults()


@dataclass(frozen=True)
class DataConfig:
    """Where the log comes from and how it is cut into fixed-shape segments."""

    kind: Literal["victoria_park", "simulated", "city", "indoor"] = _f(
        "victoria_park",
        static=True,
        doc="'victoria_park': read a log directory (Victoria Park-format, or another data.format); 'simulated': "
        "simulate one (see sim); 'city': simulate a city-sized log in memory (section city, with the sensor "
        "and noise of sim); 'indoor': simulate an indoor log in memory (section indoor), or read the "
        "directory --data (or data.path) that `nanoslam simulate --scenario indoor` wrote; its true walls, "
        "corners and pillars score a map of lines (Table 1's metrics)",
    )
    path: Optional[str] = _f(
        None,
        static=True,
        doc="log directory; null: --data, $NANOSLAM_DATA, or ../shared/data/victoria_park "
        "(format mrclam: ../shared/data/utias_mrclam/MRCLAM_Dataset1)",
    )
    format: Literal["auto", "ascii", "mat", "mrclam", "carmen", "rosbag"] = _f(
        "auto",
        static=True,
        doc="'ascii': inputs.dat/measurements.dat/gps.dat; 'mat': aa3_dr.mat/aa3_gpsx.mat (+ measurements.dat); "
        "'auto': ascii when present; 'mrclam': a UTIAS MRCLAM dataset directory (Barcodes.dat, "
        "Landmark_Groundtruth.dat, RobotN_Odometry.dat, RobotN_Measurement.dat): robot data.robot's (v, omega) "
        "odometry (model.motion unicycle) and sightings, the barcodes as landmark ids; 'carmen' (with "
        "data.kind victoria_park): a CARMEN log "
        "(.clf/.log, optionally .gz, or a directory holding one): its laser scans (FLASER, ROBOTLASER1, "
        "RAWLASER1-4) and odometry as (v, omega) controls (model.motion unicycle, unicycle.sensor_x/sensor_y the "
        "laser's mounting) or as pose increments (model.motion odometry, odometry.sensor_x/sensor_y), with detections from the scans (data.detections laser_lines, laser_beams, ...); "
        "'rosbag': a ROS 1 .bag file or a ROS 2 bag directory (--data or data.path) with LaserScan on "
        "data.scan_topic and Odometry on data.odom_topic (data.detections one of the laser values)",
    )
    laser_start_deg: Optional[float] = _f(
        None,
        static=True,
        doc="data.format carmen: the first beam's angle (deg, 0 ahead, left positive); null: the scan line's "
        "(ROBOTLASER1, RAWLASER), else the convention for FLASER (-90)",
    )
    laser_step_deg: Optional[float] = _f(
        None,
        lo=0.0,
        lo_open=True,
        static=True,
        doc="data.format carmen: the spacing of the beams (deg); null: the scan line's, else the convention "
        "(180 or 181 beams: 1; 360 or 361: 0.5)",
    )
    no_return_m: Optional[float] = _f(
        None,
        lo=0.0,
        lo_open=True,
        static=True,
        doc="data.format carmen: readings at or above this (m) are no returns; null: the maximum range the scan "
        "lines state, else 80 (the SICK's)",
    )
    reference: Optional[str] = _f(
        None,
        static=True,
        doc="data.format carmen or rosbag: a reference path scored in metrics.json (ref_* for the estimate, dr_ref_* for "
        "dead reckoning: RMSE and worst error after a rigid alignment, mean relative-motion error between "
        "consecutive reference poses): a corrected CARMEN log (matched by identical ranges), a CSV "
        "(time,x,y,theta) or TUM file (matched by time); a relative path is looked up from the working "
        "directory, then beside the log (data.path or --data); null: none",
    )
    robot: int = _f(1, lo=1, hi=5, static=True, doc="data.format mrclam: which robot's log (1-5)")
    scan_topic: str = _f(
        "/scan", static=True, doc="data.format rosbag: the topic of the sensor_msgs/msg/LaserScan scans"
    )
    odom_topic: str = _f("/odom", static=True, doc="data.format rosbag: the topic of the nav_msgs/msg/Odometry poses")
    laser_pose: Optional[tuple[float, float, float]] = _f(
        None,
        static=True,
        doc="data.format rosbag: the laser's mounting [x, y, theta] (m, m, rad) in the odometry's base frame "
        "(child_frame_id), used when the bag's /tf_static does not give it; null: zero (with a warning)",
    )
    min_range: float = _f(
        _SENSOR.min_range, lo=0.0, static=True, doc="detections with range below this are dropped (m)"
    )
    max_range: float = _f(
        _SENSOR.max_range, lo=0.0, lo_open=True, static=True, doc="detections with range >= this are dropped (m)"
    )
    k_max: Optional[int] = _f(None, lo=1, static=True, doc="detections per segment; null: the most in any kept scan")
    max_dr_per_segment: int = _f(
        12, lo=2, static=True, doc="DR pieces per segment; longer gaps between scans are split with empty segments"
    )
    t_end: Optional[float] = _f(None, lo=0.0, lo_open=True, static=True, doc="use the log only up to this time (s)")
    detections: Literal["file", "laser", "laser_lines", "laser_beams", "laser_circles", "laser_features"] = _f(
        "file",
        static=True,
        doc="'file': the detections of measurements.dat; 'laser': detect the trees in the log's raw scans "
        "(LASER.txt or aa3_lsr2.mat) on load with the detector section (what `nanoslam detect` writes); "
        "'laser_lines': the line segments the front end fits to the raw scans, at least "
        "detector.min_line_length long, as (rho, alpha) of the segment's line in the sensor frame (for "
        "model.measurement line; data.min_range and data.max_range apply to rho); 'laser_beams': every "
        "return the front end puts on a line segment or an arc, one detection per beam (range, beam angle), "
        "for NASRUKF's per-beam measurement (nasrukf.measurement beams; data.min_range and data.max_range "
        "apply to the range, data.k_max counts beams); 'laser_circles': the arcs (round pillars) the front end "
        "fits, as the range and bearing of the centre and the radius (for model.measurement circle); "
        "'laser_features': the line segments and the arcs, each with its type, in one map (for model.measurement "
        "line+circle)",
    )
    beam_step: int = _f(
        1,
        lo=1,
        static=True,
        doc="data.detections laser_beams: keep every beam_step-th beam of the scanner (beam index divisible by "
        "it); 1: every beam",
    )


@dataclass(frozen=True)
class ModelConfig:
    """Which motion and measurement models the filter uses (see the page "Your own robot and sensor")."""

    motion: str = _f(
        "ackermann",
        static=True,
        doc="motion model: 'ackermann' (the Victoria Park car; sections vehicle and noise), 'unicycle' "
        "(differential drive with (v, omega) odometry; section unicycle), 'odometry' (a pose stream as odometry: "
        "body-frame increments (vx, vy, omega) with Thrun's rotation-translation-rotation noise; section "
        "odometry; CARMEN logs, ROS bags and simulated logs), 'random_walk' (no odometry; section random_walk), or an import path 'module:Class' of a nanoslam_jax.models.AbstractMotionModel subclass",
    )
    motion_params: Optional[dict] = _f(
        None, doc="parameters of a model named by import path: a mapping of the class's field names to numbers"
    )
    measurement: str = _f(
        "range_bearing",
        static=True,
        doc="measurement model: 'range_bearing' (range and bearing to a point landmark; noise from section "
        "noise, footprint from data.min_range, data.max_range, map.fov_deg and the map.view_margin keys), "
        "'line' (a wall as a line (rho, alpha), detected as a segment's line in the sensor frame; parameters "
        "in model.measurement_params), 'circle' (an arc or round pillar (xc, yc, R), detected as its centre's "
        "range and bearing and its radius; parameters in model.measurement_params), several of them joined by "
        "'+' in one map ('line+circle': walls and pillars; parameters in model.measurement_params.line and "
        "model.measurement_params.circle), or an import "
        "path 'module:Class' of a nanoslam_jax.models.AbstractMeasurementModel subclass",
    )
    measurement_params: Optional[dict] = _f(
        None,
        doc="parameters of the 'line' and 'circle' models or of a measurement model named by import path: a "
        "mapping of the class's field names to numbers",
    )


@dataclass(frozen=True)
class OutputConfig:
    """What a run writes."""

    plots: bool = _f(True, static=True, doc="write the figures (trajectory.png, error.png, ess.png)")
    progress: bool = _f(True, static=True, doc="show a progress indicator")
    chunk: int = _f(1000, lo=1, static=True, doc="segments per compiled chunk (progress granularity)")
    rerun: Optional[str] = _f(
        None,
        static=True,
        doc="write a Rerun recording (.rrd) of the run to this file, relative to the result directory unless "
        "absolute: per scan the path so far, the pose, the particles (filter.estimate: path) or a Gaussian "
        "method's ellipse (last scan), the scan's points from the estimated pose, and the final map; open it "
        "with `rerun FILE.rrd`; needs pip install 'nanoslam-jax[viz]'; null: none",
    )


@dataclass(frozen=True)
class Config:
    """A whole run."""

    name: str = _f("default", static=True, doc="names the result directory; a config file's name by default")
    seed: int = _f(0, lo=0, static=True, doc="PRNG seed of the filter (sampling, resampling)")
    data: DataConfig = field(default_factory=DataConfig)
    detector: DetectorConfig = field(default_factory=DetectorConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    vehicle: VehicleConfig = field(default_factory=VehicleConfig)
    unicycle: UnicycleConfig = field(default_factory=UnicycleConfig)
    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    random_walk: RandomWalkConfig = field(default_factory=RandomWalkConfig)
    noise: NoiseConfig = field(default_factory=NoiseConfig)
    filter: FilterConfig = field(default_factory=FilterConfig)
    map: MapConfig = field(default_factory=MapConfig)
    nano: NanoConfig = field(default_factory=NanoConfig)
    iterated: IteratedConfig = field(default_factory=IteratedConfig)
    nasrukf: NasrukfConfig = field(default_factory=NasrukfConfig)
    smoother: SmootherConfig = field(default_factory=SmootherConfig)
    metrics: MetricsConfig = field(default_factory=MetricsConfig)
    sim: SimConfig = field(default_factory=SimConfig)
    city: CityConfig = field(default_factory=CityConfig)
    indoor: IndoorConfig = field(default_factory=IndoorConfig)
    output: OutputConfig = field(default_factory=OutputConfig)
