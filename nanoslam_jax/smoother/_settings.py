"""The offline smoother's settings."""

from __future__ import annotations

from dataclasses import dataclass

from nanoslam_jax.lib._fields import _f

__all__ = ["SmootherConfig"]


@dataclass(frozen=True)
class SmootherConfig:
    """Offline smoothing of the final best particle's path and map by least squares
    (:mod:`nanoslam_jax.smoother._smoother`). It needs ``filter.estimate: path``."""

    enabled: bool = _f(
        False,
        static=True,
        doc="after the run, refine the final best particle's ancestral path and confirmed landmarks by "
        "least squares over all odometry and detections (an offline estimate: trajectory.csv and the "
        "rmse_* metrics are then the smoothed path's; the filter's own beside it)",
    )
    odometry_scale: float = _f(
        0.3,
        lo=0.0,
        lo_open=True,
        static=True,
        doc="the odometry factors' covariance is the filter's segment prior covariance times this",
    )
    floor_xy: float = _f(
        0.1,
        lo=0.0,
        static=True,
        doc="standard deviation added to each position coordinate of every odometry factor (m)",
    )
    floor_phi_deg: float = _f(
        0.3, lo=0.0, static=True, doc="standard deviation added to the heading of every odometry factor (deg)"
    )
    huber: float = _f(
        2.0, lo=0.0, lo_open=True, static=True, doc="Huber threshold on a detection's whitened residual norm"
    )
    max_iter: int = _f(50, lo=1, static=True, doc="Levenberg-Marquardt iterations at most")
    tol: float = _f(
        1e-3, lo=0.0, lo_open=True, static=True, doc="converged when no coordinate moves more than this (m, rad)"
    )
    loop_closure: bool = _f(
        True,
        static=True,
        doc="after a first solve, find trees the run mapped twice (a stretch of new landmarks that a rigid "
        "transform lays onto earlier ones) and join them, then solve again (docs/method/smoother.md)",
    )
    loop_closure_window: float = _f(
        50.0,
        lo=0.0,
        lo_open=True,
        static=True,
        doc="the landmarks first seen in a window this long (s) are registered together against earlier ones",
    )
    loop_closure_radius: float = _f(
        1.0,
        lo=0.0,
        lo_open=True,
        static=True,
        doc="a copy lies within this distance (m) of its original after the transform; two landmarks this close "
        "and never detected together are joined",
    )
    loop_closure_search: float = _f(
        40.0,
        lo=0.0,
        static=True,
        doc="the transform moves a window's landmarks by at most this (m): the drift searched for",
    )
    loop_closure_max_turn_deg: float = _f(
        30.0, lo=0.0, hi=180.0, static=True, doc="the transform turns a window's landmarks by at most this (deg)"
    )
    loop_closure_min_inliers: int = _f(
        6,
        lo=2,
        static=True,
        doc="a transform is taken when at least this many landmarks of the window fall onto earlier ones",
    )
    loop_closure_accept: float = _f(
        0.75,
        lo=0.0,
        hi=1.0,
        static=True,
        doc="a group of joins (a window, a close pair) is kept when, solved again, at least this fraction of its "
        "copies' detections lies within filter.gate of a landmark",
    )
    loop_closure_rounds: int = _f(2, lo=1, static=True, doc="searches for copies (each followed by a solve) at most")
    map_history: bool = _f(
        True,
        static=True,
        doc="the map also holds the confirmed landmarks the best particle held at the end of a chunk of the run "
        "(output.chunk segments) but not at its end: trees that a drifted particle removed and mapped again "
        "elsewhere, which the loop closure can then join (docs/method/smoother.md)",
    )
    map_history_radius: float = _f(
        1.0,
        lo=0.0,
        static=True,
        doc="a held landmark within this distance (m) of one of the final map, or of one held later, is the same tree",
    )
    map_history_min: int = _f(
        5,
        lo=1,
        static=True,
        doc="a held landmark joins the map when it explains at least this many detections the final map leaves "
        "unexplained along the path ...",
    )
    map_history_below: float = _f(
        0.8,
        lo=0.0,
        hi=1.0,
        static=True,
        doc="... when the final map explains less than this fraction of the log's detections along the path (a "
        "particle that lost the trees of its first visit)",
    )
