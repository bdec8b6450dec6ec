"""The configuration's schema: one frozen dataclass per section, each field with its default, its
valid range, whether it is static (changes array shapes or the compiled program) or traced
(sweepable without recompiling), and its meaning (``dataclasses.field`` metadata, read by the
validation in :mod:`nanoslam_jax.app.config` and by :mod:`nanoslam_jax.app.config_reference`).

Import these names from :mod:`nanoslam_jax.app.config`, which loads and validates them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, Optional

from nanoslam_jax.lib._fields import _f
from nanoslam_jax.methods._builtin import ADAPTIVE_NOISE_METHODS as ADAPTIVE_NOISE_METHODS
from nanoslam_jax.methods._method_settings import IteratedStatic, NanoStatic, NasrukfStatic
from nanoslam_jax.methods._params import ROW_BUCKETS_FROM, ROW_BUCKETS_WORK, SPLIT_DEVICES_FROM, Static
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

#: The built-in models' noise and sensor defaults, which the noise, data and map sections take.
_SENSOR = SensorDefaults()

#: The filter's static defaults, which the filter, map and noise sections take.
_STATIC = Static()
#: The built-in methods' static defaults, which their sections take.
_NANO, _ITERATED, _NASRUKF = NanoStatic(), IteratedStatic(), NasrukfStatic()


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
class NoiseConfig:
    """Control and measurement noise (published setting by default)."""

    sigma_v: float = _f(_SENSOR.sigma_v, lo=0.0, lo_open=True, doc="encoder speed noise (m/s) per DR sample")
    sigma_alpha_deg: float = _f(_SENSOR.sigma_alpha_deg, lo=0.0, lo_open=True, doc="steering noise (deg) per DR sample")
    sigma_r: float = _f(_SENSOR.sigma_r, lo=0.0, lo_open=True, doc="range noise (m)")
    sigma_beta_deg: float = _f(_SENSOR.sigma_beta_deg, lo=0.0, lo_open=True, doc="bearing noise (deg)")
    adaptive: bool = _f(
        _STATIC.adaptive_noise,
        static=True,
        doc="re-estimate the measurement noise online from the residuals of the associated detections (the "
        "NASRUKF paper's eq. 11: R_k = (1 - d_k) R_k-1 + d_k diag(nu nu' - predicted covariance), "
        "d_k = (1 - b) / (1 - b^(k+1))), starting from sigma_r, sigma_beta (and nasrukf.sigma_diameter); "
        "for nasrukf, nano, fastslam2, ufastslam. It credits the sensor with the residuals' variance less the "
        "predicted one, so it is only as good as the predicted pose and landmark covariances: where they "
        "exceed the residuals' spread it falls to adaptive_floor and detections of mapped trees then fail the "
        "gate. A run reports noise_sigma_*_final and noise_at_floor_* in metrics.json and warns when most "
        "particles end at the floor",
    )
    forgetting: float = _f(
        0.99,
        lo=0.0,
        lo_open=True,
        doc="forgetting factor b of the adaptive estimate, 0 < b < 1 (its memory is about 1 / (1 - b) detections)",
    )
    adaptive_floor: float = _f(
        0.01,
        lo=0.0,
        lo_open=True,
        hi=1.0,
        doc="smallest variance the adaptive estimate may reach, as a fraction of the configured one",
    )


@dataclass(frozen=True)
class FilterConfig:
    """The Rao-Blackwellised particle filter shared by all particle methods."""

    method: str = _f(
        _STATIC.method.name,
        static=True,
        doc="the method: a particle filter with the proposal of nano, fastslam1 (the prior), fastslam2 "
        "(EKF-linearised), ufastslam (unscented) or iterated (Gauss-Newton MAP); ekf_slam (one joint "
        "Gaussian); nasrukf; dead_reckoning (the motion model alone); or a method registered with "
        "nanoslam_jax.app.registry.register (by its name, or by import path 'module:METHOD')",
    )
    method_params: Optional[dict] = _f(
        None, doc="parameters of a registered method that declares them: a mapping of name to number (traced)"
    )
    n_particles: int = _f(_STATIC.n_particles, lo=1, static=True, doc="particles")
    capacity: int = _f(_STATIC.capacity, lo=1, static=True, doc="landmark slots per particle")
    window: int = _f(
        _STATIC.window,
        lo=1,
        static=True,
        doc="landmarks per particle considered for association in a scan (local window)",
    )
    window_margin: float = _f(5.0, lo=0.0, doc="the window holds landmarks within max_range + this (m)")
    prior: Literal["unscented", "linearized"] = _f(
        _STATIC.prior.name, static=True, doc="how control noise is mapped to the pose covariance"
    )
    prior_cov: Literal["reset", "carry"] = _f(
        "reset" if _STATIC.prior.reset else "carry",
        static=True,
        doc="'reset': start each segment from the sampled pose with init_cov; 'carry': from the last proposal covariance",
    )
    init_cov: float = _f(1e-8, lo=0.0, lo_open=True, doc="near-zero pose variance at the start and after a reset")
    ut_alpha: float = _f(0.9, lo=0.0, lo_open=True, doc="unscented alpha of the prior (and of UFastSLAM)")
    ut_beta: float = _f(2.0, lo=0.0, doc="unscented beta of the prior (and of UFastSLAM); 2 is optimal for Gaussians")
    ut_kappa: float = _f(0.0, doc="unscented kappa of the prior (and of UFastSLAM)")
    gate: float = _f(5.991, lo=0.0, lo_open=True, doc="chi-square (2 dof) association gate on d2")
    new_landmark: float = _f(
        9.21,
        lo=0.0,
        lo_open=True,
        doc="a detection whose best d2 exceeds this starts a landmark (9.21: chi-square 99 %, 2 dof; "
        "with landmark management a spurious one is removed again)",
    )
    sequential: bool = _f(_STATIC.sequential, static=True, doc="associate detections one after another within a scan")
    association: Literal["nearest", "known"] = _f(
        _STATIC.association.name,
        static=True,
        doc="'nearest': nearest neighbour within filter.gate, a new landmark above filter.new_landmark; 'known': "
        "the log's landmark ids (e.g. MRCLAM's barcodes): a detection matches the landmark started by its "
        "id and starts one when none has it; detections without an id are ignored",
    )
    weight: Literal["product", "marginal"] = _f(
        _STATIC.weight.name, static=True, doc="'product': eq. 17 at the proposal; 'marginal': likelihood at the prior"
    )
    p0: float = _f(0.05, lo=0.0, lo_open=True, doc="likelihood factor of a new landmark")
    resampler: Literal["systematic", "stratified", "multinomial", "residual"] = _f(
        _STATIC.resampler.name, static=True, doc="resampling scheme"
    )
    resample_threshold: float = _f(0.5, lo=0.0, hi=1.0, doc="resample when ESS < threshold * N")
    estimate: Literal["best", "mean", "path"] = _f(
        _STATIC.estimate.name,
        static=True,
        doc="reported trajectory: at each segment the highest-weight particle's pose (best, the paper's) or the "
        "weighted mean (mean); or path: the history of the particle that is best at the end of the log, "
        "followed back through the resampling steps (the path its final map was built along; an offline, "
        "smoothed estimate; particle methods only; records every particle's pose per segment)",
    )
    row_buckets: Literal["auto", "always", "never"] = _f(
        "auto",
        static=True,
        doc="run the proposal, the weight's likelihoods and the landmarks' updates over only 4, 8 or k_max "
        "detection rows, the fewest that hold the scan's detections, and the association over the "
        "16, 32 or all window slots that hold the particles' landmarks (the same results to rounding; "
        "compiled three times, so compilation takes longer): 'auto' from "
        f"{ROW_BUCKETS_FROM} particles per call up, for a program that runs at least {ROW_BUCKETS_WORK:,} "
        "particle-segments over all its calls (a sweep's batches): below that the longer compilation costs more "
        "than the split saves",
    )
    split_devices: Literal["auto", "always", "never"] = _f(
        "auto",
        static=True,
        doc="split a single run's particles over the JAX CPU devices (one per core; `nanoslam run` sets them "
        f"up) when they divide evenly; the same results to rounding. 'auto': from {SPLIT_DEVICES_FROM} particles up "
        "(below that the devices' exchange at every scan outweighs the split work); never for "
        "filter.method iterated or nano.init gauss_newton (optimistix's least squares cannot run split)",
    )


@dataclass(frozen=True)
class MapConfig:
    """Landmark management: tentative and confirmed landmarks, existence by negative evidence, tree
    diameters (all particle methods, EKF-SLAM and NASRUKF).

    How the defaults were chosen: docs/method/landmarks.md, "Settings and how they were chosen".

    A detection that starts a landmark makes it *tentative*, with existence log-odds
    ``logit(birth_probability)``. Every detection associated with it adds ``log(p_detect / p_false)``;
    every scan in which it lay inside the sensor's footprint (shrunk by the view margins) at the
    particle's pose, was not hidden behind a nearer object, and was not detected adds
    ``log((1 - p_detect) / (1 - p_false))``. The log-odds are clamped at ``logit(max_probability)``.
    A tentative landmark is confirmed once its existence probability reaches
    ``confirm_probability`` with at least ``confirm_hits`` detections, and dropped if that has not
    happened within ``tentative_scans`` scans of its birth. Any landmark whose existence probability
    falls below ``remove_probability`` is removed and its slot reused.
    """

    manage: bool = _f(
        _STATIC.manage,
        static=True,
        doc="landmark management on; false: every detection beyond filter.new_landmark starts a permanent "
        "landmark that is used at once (the published methods' rule), and the other keys here are ignored",
    )
    p_detect: float = _f(
        0.75,
        lo=0.0,
        lo_open=True,
        hi=1.0,
        doc="probability that a landmark inside the sensor footprint is detected in a scan",
    )
    p_false: float = _f(
        0.075,
        lo=0.0,
        lo_open=True,
        hi=1.0,
        doc="probability that a landmark that does not exist (clutter) is 'detected' again in a scan "
        "(a clutter detection falling in its gate); must be below p_detect",
    )
    birth_probability: float = _f(
        0.5,
        lo=0.0,
        lo_open=True,
        hi=1.0,
        doc="existence probability of a landmark right after the detection that starts it",
    )
    confirm_probability: float = _f(
        0.9,
        lo=0.0,
        lo_open=True,
        hi=1.0,
        doc="a tentative landmark is confirmed when its existence probability reaches this ...",
    )
    confirm_hits: int = _f(4, lo=1, doc="... and it has at least this many detections (its first included)")
    tentative_scans: int = _f(
        40, lo=1, doc="a tentative landmark not confirmed within this many scans after its birth is dropped"
    )
    remove_probability: float = _f(
        0.02, lo=0.0, hi=1.0, doc="a landmark whose existence probability falls below this is removed (its slot reused)"
    )
    max_probability: float = _f(
        0.99,
        lo=0.0,
        lo_open=True,
        hi=1.0,
        doc="existence probabilities are capped here, so a tree that has gone can still be removed after a few misses",
    )
    fov_deg: float = _f(_SENSOR.fov_deg, lo=0.0, lo_open=True, hi=360.0, doc="the sensor's field of view (deg)")
    view_margin: float = _f(
        _SENSOR.view_margin,
        lo=0.0,
        doc="a miss is counted only when the landmark is at least this far (m) inside the sensor's range "
        "limits (data.min_range, data.max_range)",
    )
    view_margin_deg: float = _f(_SENSOR.view_margin_deg, lo=0.0, doc="... and this far (deg) inside the field of view")
    occlusion: bool = _f(
        _STATIC.occlusion,
        static=True,
        doc="no miss for a landmark hidden behind a nearer object at a similar bearing (a detection of "
        "the scan or a confirmed landmark)",
    )
    occlusion_width: float = _f(
        1.0, lo=0.0, doc="half-width (m) added to an occluder's radius (half its diameter) in the occlusion test"
    )
    use_tentative: bool = _f(
        True,
        doc="tentative landmarks also shape the proposal and the weight; false: only confirmed ones do "
        "(a detection matching a tentative landmark then weighs as a new one, filter.p0)",
    )
    use_diameter: bool = _f(
        False,
        doc="add the tree-diameter term (d - d_j)^2 / (var_j + sigma_diameter^2) to the association "
        "distance (then filter.gate and filter.new_landmark apply to a 3-dof chi-square: 7.815 and "
        "16.266 at 95 % and 99.9 %)",
    )
    sigma_diameter: float = _f(
        0.05,
        lo=0.0,
        lo_open=True,
        doc="diameter measurement noise (m): the per-landmark diameter filter and the association term",
    )


@dataclass(frozen=True)
class NanoConfig:
    """The NANO proposal (the docs, page method/proposals.md)."""

    quadrature: Literal["cubature", "unscented", "gauss_hermite"] = _f(
        _NANO.quadrature,
        static=True,
        doc="rule for the expectations over the proposal: cubature (6 points), unscented (7), gauss_hermite (gh_order^3)",
    )
    gh_order: int = _f(_NANO.gh_order, lo=1, hi=10, static=True, doc="Gauss-Hermite order p (p^3 points)")
    ut_alpha: float = _f(1.0, lo=0.0, lo_open=True, doc="unscented alpha (nano.quadrature: unscented)")
    ut_beta: float = _f(2.0, lo=0.0, doc="unscented beta (nano.quadrature: unscented)")
    ut_kappa: float = _f(0.0, doc="unscented kappa (nano.quadrature: unscented)")
    hessian: Literal["gauss_newton", "exact"] = _f(
        _NANO.hessian,
        static=True,
        doc="expected Hessian of the log-likelihood: Gauss-Newton (J' R^-1 J, positive semi-definite) or exact (autodiff)",
    )
    gamma: float = _f(1e-4, lo=0.0, lo_open=True, doc="KL stopping threshold")
    max_iter: int = _f(_NANO.max_iter, lo=1, static=True, doc="iteration cap")
    step: float = _f(1.0, lo=0.0, lo_open=True, hi=1.0, doc="natural-gradient step beta (damping below 1)")
    landmark_noise: bool = _f(_NANO.landmark_noise, static=True, doc="use R + Gm Sigma Gm' in the likelihood")
    init: Literal["prior", "gauss_newton"] = _f(
        _NANO.init, static=True, doc="start from the prior or the Gauss-Newton MAP"
    )
    solver: Literal["optimistix", "while_loop"] = _f(
        _NANO.solver,
        static=True,
        doc="the iteration as a plain lax.while_loop (default, the faster) or as an optimistix "
        "fixed-point solve with a KL stopping rule (same iterates)",
    )


@dataclass(frozen=True)
class IteratedConfig:
    """The iterated (Gauss-Newton / Levenberg-Marquardt MAP) proposal, method ``iterated``."""

    solver: Literal["gauss_newton", "levenberg_marquardt"] = _f(
        _ITERATED.solver, static=True, doc="optimistix least-squares solver for the MAP of prior x likelihood"
    )
    max_iter: int = _f(_ITERATED.max_iter, lo=1, static=True, doc="solver step cap")
    tol: float = _f(_ITERATED.tol, lo=0.0, lo_open=True, static=True, doc="solver rtol = atol")
    landmark_noise: bool = _f(
        _ITERATED.landmark_noise,
        static=True,
        doc="weigh residuals with (R + Gm Sigma Gm')^-1 as FastSLAM 2.0 does (one step = FastSLAM 2.0)",
    )


@dataclass(frozen=True)
class NasrukfConfig:
    """NASRUKF FastSLAM (the second paper), method ``nasrukf``: per-feature joint states (pose and
    one tree), each a square-root unscented Kalman filter, with an information-weighted global pose.

    Its unscented transforms use ``filter.ut_alpha``, ``ut_beta``, ``ut_kappa``; association uses
    ``filter.gate``, ``filter.new_landmark``, ``filter.window``; ``filter.capacity`` feature slots."""

    feature: Literal["point", "arc"] = _f(
        _NASRUKF.feature,
        static=True,
        doc="'point': a tree is its centre, a 5-D joint state (pose + centre); 'arc': the paper's arc "
        "feature, a 6-D joint state (pose + centre + radius) with the detection's diameter as a third "
        "measurement (diameter = 2 radius, noise map.sigma_diameter)",
    )
    new_feature_hits: int = _f(
        1,
        lo=1,
        doc="the paper's 'enough new feature data' count N_new: a feature's detections update the pose "
        "only once it has been detected this many times (1: from its second detection on, as the "
        "other methods' landmarks); until then they refine the feature only",
    )
    adaptive_process: bool = _f(
        _NASRUKF.adaptive_process,
        static=True,
        doc="estimate the process noise Q of the time update online (eq. 9's estimated Q): a Sage-Husa "
        "estimate from the pose corrections K nu and covariance changes of each scan's fused joint states, "
        "with the weights d_k = (1 - b) / (1 - b^(k+1)) of process_forgetting, scaling the motion model's "
        "configured noise "
        "(noise.sigma_v and sigma_alpha_deg, unicycle or random_walk sigmas, the odometry model's "
        "rotation-translation-rotation noise) by a matrix Lambda, Q = S Lambda "
        "S'. A run reports process_noise_ratio_<j> (estimated over configured standard deviation of each noise "
        "component) in metrics.json; method nasrukf only",
    )
    process_forgetting: float = _f(
        0.99,
        lo=0.0,
        lo_open=True,
        doc="forgetting factor b of the adaptive process-noise estimate, 0 < b < 1 (its memory is about "
        "1 / (1 - b) scans with an update)",
    )
    process_floor: float = _f(
        0.01,
        lo=0.0,
        lo_open=True,
        hi=1.0,
        doc="smallest eigenvalue of the adaptive process-noise scale Lambda: the estimate stays at or above this "
        "fraction of the configured noise in every direction",
    )
    measurement: Literal["detections", "beams"] = _f(
        _NASRUKF.measurement,
        static=True,
        doc="'detections': a feature's measurement is a detection (a tree's range and bearing, data.detections "
        "file or laser); 'beams': the paper's per-beam range rho(k) along the beam angle phi(k) against line "
        "and arc features (eq. 14-17; data.detections laser_beams), each feature's beams stacked as one "
        "vector measurement; docs/method/nasrukf-beams.md",
    )
    line_form: Literal["normal", "slope_intercept"] = _f(
        _NASRUKF.line_form,
        static=True,
        doc="measurement beams: a line's state, 'normal' (rho, alpha), every line alike; 'slope_intercept': the "
        "paper's y = a x + b (eq. 14), or x = c (eq. 15) for a line steeper than 1000",
    )
    sigma_beam: float = _f(
        0.01,
        lo=0.0,
        lo_open=True,
        doc="measurement beams: the range noise of one beam (m); the adaptive estimate (noise.adaptive) starts here",
    )
    beam_gate: float = _f(
        0.06,
        lo=0.0,
        lo_open=True,
        doc="measurement beams: a beam is associated with the feature whose predicted range (eq. 14-16, at the "
        "prior pose) is nearest its measured range, if nearer than this (m)",
    )
    beams_per_feature: int = _f(
        _NASRUKF.beams_per_feature,
        lo=1,
        static=True,
        doc="measurement beams: a feature's update stacks at most this many of its associated beams of a scan "
        "(evenly spread over them)",
    )
    arc_capacity: int = _f(
        _NASRUKF.arc_capacity, lo=1, static=True, doc="measurement beams: arc feature slots (lines: filter.capacity)"
    )
    max_groups: int = _f(
        _NASRUKF.groups,
        lo=1,
        static=True,
        doc="measurement beams: front-end features (line segments and arcs) a scan holds at most; also the slots "
        "of the buffer of unmatched features (n_new)",
    )
    noise_residual: Literal["innovation", "posterior", "projected"] = _f(
        _NASRUKF.noise_residual,
        static=True,
        doc="measurement beams, noise.adaptive: the beam noise estimate with eq. 11's weights d_k from each "
        "updated feature's residuals: 'projected' (the default): before its update, the innovations with the "
        "part the state's uncertainty explains projected out, whose mean square is the beam noise whatever "
        "that uncertainty; 'innovation': eq. 11 as printed, before its update, the innovations' mean square "
        "less their predicted variance (falls to noise.adaptive_floor when the state's covariance is "
        "overestimated, e.g. a too large process noise); 'posterior': after its update, mean (z - h(x+))^2 "
        "plus the predicted variance there. With nasrukf.adaptive_process the last two trade the beam noise "
        "against the estimated process noise and the two estimates run away (docs/method/nasrukf-beams-results.md)",
    )
    n_new: int = _f(
        1,
        lo=1,
        doc="measurement beams: the paper's N_new: a front-end segment or arc that no feature explains is stored, "
        "and a feature is created once this many such data of the same line or arc have been stored (1: at once)",
    )
    merge_gate: float = _f(
        0.15,
        lo=0.0,
        lo_open=True,
        doc="measurement beams: unmatched segments (arcs) are data of the same stored line (arc) when their "
        "lines differ by less than this, |d rho| + 1 m |d alpha| (centres by less than this, m)",
    )
    static_scans: int = _f(
        40,
        lo=0,
        doc="measurement beams: static initialisation: the first scans, at most this many and only while the "
        "odometry reports no motion, hold the pose at the origin and build the initial features (0: none)",
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
