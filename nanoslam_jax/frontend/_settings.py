"""The front end's settings: how raw scans become clusters, segments, arcs and trees."""

from __future__ import annotations

from dataclasses import dataclass

from nanoslam_jax.lib._fields import _f

__all__ = ["DetectorConfig"]


@dataclass(frozen=True)
class DetectorConfig:
    """The raw laser front end (:mod:`nanoslam_jax.frontend`, docs/frontend.md): clusters by an adaptive
    breakpoint detector, split-and-merge line segments, circle fits and the tree detector. Its keys
    change the detections (the data), so all are static: a sweep runs each value on its own log."""

    max_range: float = _f(
        75.0, static=True, lo=0.0, lo_open=True, doc="returns at or beyond this range (m) are treated as no return"
    )
    breakpoint_lambda_deg: float = _f(
        10.0,
        static=True,
        lo=0.0,
        lo_open=True,
        hi=89.0,
        doc="adaptive breakpoint detector: the shallowest incidence angle (deg) of a surface still taken as "
        "continuous; neighbouring returns r, r' split when |p - p'| > min(r, r') sin(dphi) / sin(lambda - dphi) "
        "+ 3 breakpoint_sigma_r",
    )
    breakpoint_sigma_r: float = _f(0.03, static=True, lo=0.0, doc="range noise (m) in the breakpoint threshold")
    max_dropout_beams: int = _f(
        2,
        static=True,
        lo=0,
        doc="this many no-return beams at most between two returns do not end a cluster (dropouts), "
        "when the two returns pass the breakpoint test",
    )
    split_distance: float = _f(
        0.08,
        static=True,
        lo=0.0,
        lo_open=True,
        doc="split-and-merge d_max: a segment is split at its point farthest from the chord when that "
        "point is farther than this (m)",
    )
    merge_distance: float = _f(
        0.03,
        static=True,
        lo=0.0,
        lo_open=True,
        doc="split-and-merge md_max: neighbouring segments of a cluster merge when the mean distance (m) of "
        "their points to the joint chord is below this (and none is beyond split_distance)",
    )
    min_line_length: float = _f(
        0.5, static=True, lo=0.0, doc="L_min: a segment at least this long (m) with min_line_points points is a line"
    )
    min_line_points: int = _f(5, static=True, lo=2, doc="points a line segment has at least")
    split_rounds: int = _f(24, lo=1, static=True, doc="rounds of splitting (and of merging) at most")
    collinear_angle_deg: float = _f(
        5.0,
        static=True,
        lo=0.0,
        doc="lines of neighbouring clusters merge when their directions differ by less than this (deg) ...",
    )
    collinear_distance: float = _f(
        0.1, static=True, lo=0.0, doc="... each one's end lies within this distance (m) of the other's line ..."
    )
    collinear_gap: float = _f(2.0, static=True, lo=0.0, doc="... and the gap between them is below this (m)")
    corner_min_angle_deg: float = _f(
        30.0,
        static=True,
        lo=0.0,
        hi=90.0,
        doc="two lines meeting at a vertex make a corner when their directions differ by at least this (deg)",
    )
    circle_min_points: int = _f(4, static=True, lo=3, doc="clusters with at least this many points get a circle fit")
    circle_max_residual: float = _f(
        0.02,
        static=True,
        lo=0.0,
        lo_open=True,
        doc="a circle fit whose RMS geometric residual exceeds this (m) is rejected (not an arc)",
    )
    circle_max_radius: float = _f(
        2.0, static=True, lo=0.0, lo_open=True, doc="arcs of larger radius (m) are not reported"
    )
    tree_min_diameter: float = _f(0.0, static=True, lo=0.0, doc="trees thinner than this (m) are rejected")
    tree_max_diameter: float = _f(
        1.2,
        static=True,
        lo=0.0,
        lo_open=True,
        doc="trees (and clusters spanning a chord) wider than this (m) are rejected",
    )
    tree_min_range: float = _f(1.0, static=True, lo=0.0, doc="trees whose surface is nearer than this (m) are rejected")
    tree_max_range: float = _f(
        75.0, static=True, lo=0.0, lo_open=True, doc="trees whose centre is beyond this (m) are rejected"
    )
    tree_min_separation: float = _f(
        3.0,
        static=True,
        lo=0.0,
        doc="a tree's end returns lie at least this far (m) from the nearest returns of the clusters beside it "
        "in the scan (a trunk stands alone; foliage, hedges and fences come in pieces)",
    )
    tree_min_clearance: float = _f(
        2.0,
        static=True,
        lo=0.0,
        doc="no return of the scan outside a tree's cluster lies within this distance (m) of the trunk's surface "
        "(0: no such test)",
    )
    tree_max_asymmetry: float = _f(
        0.33,
        static=True,
        lo=0.0,
        doc="a tree's first and last returns differ in range by at most this fraction of its diameter "
        "(an oblique surface is not a trunk)",
    )
    tree_fit_min_points: int = _f(
        8,
        static=True,
        lo=3,
        doc="from this many returns on, a cluster is a tree only if its circle fit is convex (centre beyond "
        "its middle return), smooth (tree_max_residual) and not flat (tree_max_fit_ratio), and the tree's "
        "diameter and centre come from that fit; below, from its angular width",
    )
    tree_max_residual: float = _f(
        0.1,
        static=True,
        lo=0.0,
        lo_open=True,
        doc="a cluster whose circle fit's RMS residual exceeds this (m) is rough (foliage, a bush): no tree",
    )
    tree_max_fit_ratio: float = _f(
        3.0,
        static=True,
        lo=1.0,
        doc="a tree whose circle fit's radius exceeds its angular-width radius by more than this factor is "
        "flat (a wall or fence piece) and rejected",
    )
    edge_margin_deg: float = _f(
        2.5,
        static=True,
        lo=0.0,
        doc="clusters reaching within this angle (deg) of the field of view's edges are partly seen: no tree",
    )
    reject_occluded: bool = _f(
        True,
        static=True,
        doc="a cluster whose neighbouring beam on either side returned nearer (occluded at an edge) is no tree",
    )
    tree_min_returns: int = _f(
        1,
        static=True,
        lo=1,
        doc="a tree has at least this many returns (2: a single return, which may be a stray one, is never a "
        "tree; the Victoria Park log's own detector reports thin trunks seen by one beam)",
    )
    tree_range_noise: float = _f(
        0.02,
        static=True,
        lo=0.0,
        lo_open=True,
        doc="range noise (m) with which the trunk profile fit weighs where a tree's edges lie between its edge "
        "beams and the beams beside them (smaller: trust the ranges more)",
    )
    tree_max_profile_residual: float = _f(
        0.2,
        static=True,
        lo=0.0,
        lo_open=True,
        doc="a cluster of 3 or more returns whose ranges depart from the near side of a trunk as wide as the "
        "cluster by more than this RMS (m) is no tree (bush fragments, oblique wall pieces)",
    )
    reject_no_return_edge: bool = _f(
        False,
        static=True,
        doc="a cluster next to a no-return beam is no tree (off: a trunk against open sky is a tree)",
    )
