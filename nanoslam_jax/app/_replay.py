"""``output.rerun``: a finished run (:class:`~nanoslam_jax.app.experiment.RunResult`) as a Rerun
recording, from what the run returned (no output of the filter's program is added for it)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Optional

import numpy as np

from nanoslam_jax.eval._rerun import RecordingOptions, RerunMap, polar_points, write_rerun

#: How far (s) a raw scan's time may be from a segment's for its returns to be that segment's scan.
SCAN_TIME_TOLERANCE = 1e-3


def rerun_path(out_dir: str | Path, rerun: str) -> Path:
    """Where ``output.rerun`` writes: ``rerun`` itself when absolute, else inside ``out_dir``."""
    p = Path(rerun).expanduser()
    return p if p.is_absolute() else Path(out_dir) / p


def scan_points(segments: Any, scans: Any = None) -> list[np.ndarray]:
    """Per segment, ``(n, 2)`` the points of its scan in the sensor's frame: the returns of the raw
    scan at its time (within :data:`SCAN_TIME_TOLERANCE`) when ``scans`` (a
    :class:`~nanoslam_jax.data.LaserScans`) is given and has one, else its detections, their first
    two values read as a range and a bearing (a point's or a circle's centre; a line's ``rho,
    alpha``: the foot of its perpendicular)."""
    t = np.asarray(segments.time, dtype=float)
    z = np.asarray(segments.z, dtype=float)
    mask = np.asarray(segments.z_mask, dtype=bool)
    out = [polar_points(z[i, mask[i], 0], z[i, mask[i], 1]) for i in range(t.shape[0])]
    if scans is None or not len(scans.time):
        return out
    st = np.asarray(scans.time, dtype=float)
    j = np.clip(np.searchsorted(st, t), 1, len(st) - 1) if len(st) > 1 else np.zeros(len(t), int)
    if len(st) > 1:
        j = np.where(np.abs(st[j - 1] - t) <= np.abs(st[j] - t), j - 1, j)
    near = np.abs(st[j] - t) <= SCAN_TIME_TOLERANCE
    ranges, angles = np.asarray(scans.ranges, dtype=float), np.asarray(scans.angles, dtype=float)
    for i in np.flatnonzero(near):
        r = ranges[j[i]]
        hit = np.isfinite(r) & (r > 0) & (r < scans.max_range)
        out[i] = polar_points(r[hit], angles[hit])
    return out


def _map(
    result: Any, columns: list[str], names: Optional[tuple[str, ...]]
) -> tuple[Optional[np.ndarray], Optional[np.ndarray], Optional[np.ndarray]]:
    """The final map of ``result`` (its ``map.csv`` table of ``columns``; a composite model's type
    ``names``) as ``(points, confirmed, lines)``: point landmarks (and circles' centres) as points,
    lines ``(rho, alpha)`` as lines; NASRUKF's per-beam features: none."""
    cfg, table = result.config, result.landmarks
    if table is None or cfg.data.detections == "laser_beams":
        return None, None, None
    confirmed = table[:, columns.index("confirmed")] > 0
    if names is not None:  # a composite map: each landmark's type in its column `kind`
        is_line = np.asarray([n == "line" for n in names])[table[:, columns.index("kind")].astype(int)]
    else:
        is_line = np.full(len(table), cfg.model.measurement == "line")
    return table[~is_line, :2], confirmed[~is_line], table[is_line, :2]


def record_run(result: Any, out_dir: str | Path, columns: list[str], names: Optional[tuple[str, ...]] = None) -> Path:
    """Write the Rerun recording of ``result`` (a :class:`~nanoslam_jax.app.experiment.RunResult`;
    ``columns`` and ``names``: the layout of its map table) to ``output.rerun`` (relative to ``out_dir``): the
    reported path, the particles (kept with ``filter.estimate: path``), a Gaussian method's final
    pose covariance (its ellipse at the last scan; none after the smoother), every scan's raw
    returns or detections and the final map (:func:`~nanoslam_jax.eval._rerun.write_rerun`)."""
    cfg, log = result.config, result.log
    o = result.outputs
    particles = None if o is None or getattr(o, "poses", None) is None else np.asarray(o.poses)
    cov = None
    state_cov = getattr(result.state, "pose_cov", None)
    if state_cov is not None and result.path_before_smoother is None:
        c = np.asarray(state_cov)
        cov = c if c.shape == (3, 3) else None  # a particle filter's is one per particle: no single ellipse
    points, confirmed, lines = _map(result, columns, names)
    return write_rerun(
        rerun_path(out_dir, cfg.output.rerun),
        result.times,
        result.trajectory,
        scan_points(log.segments, log.scans),
        particles=particles,
        pose_cov=cov,
        final_map=RerunMap(landmarks=points, confirmed=confirmed, lines=lines),
        options=RecordingOptions(name=f"nanoslam {cfg.name}"),
    )
