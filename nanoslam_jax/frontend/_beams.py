"""Per-beam detections: the raw returns that the front end puts on a line segment or an arc, one
detection per beam (``data.detections: laser_beams``; docs/method/nasrukf-beams.md).

The second paper's measurement of a feature is one range ``rho(k)`` along a known beam angle
``phi(k)`` (its eq. 14-17). A scan's kept beams become its detections, in the layout of a log's
detections so that :func:`~nanoslam_jax.data.make_segments` cuts them into fixed-shape segments:

- ``z = (range, phi)``: the measured range (m) and the beam's angle in the sensor frame (rad, 0
  ahead, left positive), an exact input of the measurement, not a measured bearing;
- ``diam``: 0 for a beam on a line segment, the fitted diameter ``2 R`` (m) for a beam on an arc;
- ``z_id``: the index of the front-end feature the beam lies on within its scan (line segments
  first, in beam order, then arcs): the beams of one segment or arc share it.

A beam on two features (the vertex of two segments) is kept once, on the first. ``beam_step``
keeps only every ``beam_step``-th beam of the scanner (beam index divisible by it).
"""

from __future__ import annotations

import numpy as np
from jaxtyping import Float, Int

from nanoslam_jax.data._laser import LaserScans

__all__ = ["beam_detections"]


def _feature_beams(
    scan: Int[np.ndarray, " F"], first: Int[np.ndarray, " F"], last: Int[np.ndarray, " F"]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every beam ``first..last`` of each feature: ``(feature, scan, beam)`` per row."""
    n = np.maximum(last - first + 1, 0)
    feat = np.repeat(np.arange(n.size), n)
    offset = np.arange(feat.size) - np.repeat(np.cumsum(n) - n, n)
    return feat, scan[feat], first[feat] + offset


def beam_detections(
    scans: LaserScans, detector=None, beam_step: int = 1
) -> tuple[Float[np.ndarray, "M 4"], Int[np.ndarray, " M"]]:
    """The beams the front end puts on line segments and arcs, as detection rows.

    Args:
        scans: the raw scans.
        detector: the ``detector`` settings (:class:`~nanoslam_jax.app.config.DetectorConfig`; None: defaults).
        beam_step: keep every ``beam_step``-th beam (``data.beam_step``).

    Returns:
        ``(rows, group)``: ``(M, 4)`` rows ``time, range, phi, diameter`` (diameter 0 on a line) ordered
        by time, then beam; ``(M,)`` the front-end feature each beam lies on, numbered from 0 within
        its scan (lines, then arcs).

    Raises:
        ValueError: ``beam_step`` below 1.
    """
    from nanoslam_jax.frontend import extract_features

    if beam_step < 1:
        raise ValueError(f"data.beam_step: expected an integer >= 1, got {beam_step}")
    f = extract_features(scans, detector)
    ln, ci = f.lines, f.circles
    n_scans = scans.time.size
    lines_per_scan = np.bincount(ln.scan, minlength=n_scans)
    # features of a scan numbered lines first (in the front end's order), then arcs
    line_rank = np.arange(ln.scan.size) - (np.cumsum(lines_per_scan) - lines_per_scan)[ln.scan]
    order = np.argsort(ci.scan, kind="stable")
    arcs_per_scan = np.bincount(ci.scan, minlength=n_scans)
    arc_rank = np.empty(ci.scan.size, np.int64)
    arc_rank[order] = np.arange(ci.scan.size) - (np.cumsum(arcs_per_scan) - arcs_per_scan)[ci.scan[order]]
    scan = np.concatenate([ln.scan, ci.scan]).astype(np.int64)
    first = np.concatenate([ln.first_beam, ci.first_beam]).astype(np.int64)
    last = np.concatenate([ln.last_beam, ci.last_beam]).astype(np.int64)
    group = np.concatenate([line_rank, lines_per_scan[ci.scan] + arc_rank]).astype(np.int64)
    diam = np.concatenate([np.zeros(ln.scan.size), 2.0 * ci.radius])
    feat, b_scan, beam = _feature_beams(scan, first, last)
    r = scans.ranges[b_scan, beam]
    keep = (r > 0) & (r < scans.max_range) & (beam % beam_step == 0)
    if detector is not None:
        keep &= r < detector.max_range
    feat, b_scan, beam, r = feat[keep], b_scan[keep], beam[keep], r[keep]
    key = b_scan * scans.n_beams + beam
    key, first_row = np.unique(key, return_index=True)  # sorted by scan, then beam; a shared vertex kept once
    feat, b_scan, beam, r = feat[first_row], b_scan[first_row], beam[first_row], r[first_row]
    rows = np.stack([scans.time[b_scan], r, scans.angles[beam], diam[feat]], axis=1).reshape(-1, 4)
    return rows, group[feat]
