"""The floor: how much of the RMSE against GPS is the GPS's own error.

An estimate that was exactly the laser's path would still score a non-zero RMSE against the GPS:
the fixes are noisy, some jump, and the fixed frame's rotation is only known to about 2 degrees.
Without ground truth these can be estimated only where dead reckoning (DR) is itself accurate:
over short stretches. :func:`estimate_gps_floor` measures, from the GPS and the DR path alone:

- **Antenna offset and clock offset**: one body-frame offset of the GPS antenna from the laser
  and one time shift of the GPS clock, fitted jointly with a rigid transform per window
  (``scipy.optimize.least_squares``); both change what an exact laser path would score. The
  estimates below compare the GPS with the path the antenna follows by them.
- **GPS jumps**: the fixes :func:`~nanoslam_jax.eval.metrics.jump_mask` removes, and how far they lie
  from the track of the clean fixes around them (linear in time between the nearest clean fixes
  before and after), which is where an exact path is. Every fix counts in ``rmse_fixed`` and
  ``rmse_aligned``, so these offsets alone add ``sqrt(sum offset^2 / fixes)`` to any path's RMSE,
  including a fix between two gaps, which no window fit below scores.
- **Short-term GPS error**: each fix against the DR path rigidly fitted (rotation + translation)
  to the clean fixes within +-W/2 seconds of it, the fix itself left out. DR is accurate over a few
  seconds, so for small W this is the GPS's own error apart from errors slower than W (a fitted
  window absorbs those); it grows with W as DR drift enters. Its RMS over the clean fixes at
  ``reference_window``, with the jumps' offsets (above) added over all fixes, is the floor of
  ``rmse_aligned``: the rigid alignment removes any frame error.
- **White noise**: the second differences of consecutive 5 Hz fixes minus those of the DR path
  (the motion), ``sigma = 1.4826 MAD / sqrt(6)`` per axis.
- **The fixed frame**: the rotation (and translation) that maps DR onto the clean fixes of the
  first T seconds, for several T. The fixed frame assumes the rotation ``rotation_deg``; the
  fitted rotation departs from it by ``delta``, so an exact path scores
  ``RMS_i |R(delta) g_i - g_i|`` in the fixed frame (``g_i`` the fixes in the fixed frame, the first
  at the origin). The fits disagree by degrees (DR drifts over the longer stretches), which is the
  frame's uncertainty: the floor of ``rmse_fixed`` is the short-term error and this cost added in
  quadrature, from the smallest to the largest ``delta`` fitted. (The fitted translations are
  reported but not used: over tens of seconds they hold DR drift.) Also reported: what a frame
  error of 1 and 2 degrees alone costs at the track's distances.

Run on the real log by ``python experiments/gps_floor.py`` (and by every study on the real log).
The scoring protocol is in the docs, page "The Victoria Park model and scoring"
(``docs/method/victoria-park.md``); the floor of the Victoria Park log on the results page, "The GPS
floor".
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, NamedTuple, Optional, Sequence

import numpy as np

from nanoslam_jax.eval.metrics import GPS_DAT_ROTATION_DEG, jump_mask, relative_gps, rigid_align, rotation_matrix

__all__ = ["FloorWindows", "GpsFloor", "estimate_gps_floor", "gps_floor_of_log", "floor_markdown"]


@dataclasses.dataclass(frozen=True)
class GpsFloor:
    """What the GPS allows (see the module docstring). Distances in metres.

    Attributes:
        n_fixes: fixes inside the DR path's time span.
        n_jumps: of these, the fixes flagged as jumps.
        gaps_over_1s: gaps of more than 1 s between consecutive fixes; ``longest_gap_s`` the longest.
        jump_offset_median, jump_offset_max: distance of the jump fixes from the track of the
            clean fixes (linear in time between the nearest clean fixes before and after).
        jump_rmse: what the jumps alone add to any path's RMSE: ``sqrt(sum offset^2 / n_fixes)``.
        local_rms: ``(W, rms over all fixes, rms over clean fixes, fixes scored)`` per window length W (s).
        white_sigma: white noise per axis (m), from second differences.
        antenna_offset: fitted ``(forward, left)`` offset of the GPS antenna from the laser.
        clock_offset_s: fitted time shift of the GPS (positive: the GPS lags).
        offset_fit_rms: RMS residual of that fit; ``offset_fit_rms_without`` the same fit with no
            offset and no shift.
        r_rms: RMS distance of the fixes from the first fix (the frame's lever).
        frame: ``(T, delta_deg, tx, ty, fixed-frame RMS of an exact path by delta)`` per initial window T (s).
        frame_rmse_1deg, frame_rmse_2deg: RMS displacement of the fixes by a frame rotation of 1
            and 2 degrees about the first fix.
        aligned_floor: floor of ``rmse_aligned``: the clean fixes' ``local_rms`` at
            ``reference_window`` as their share of all fixes, and ``jump_rmse``, in quadrature:
            ``sqrt(clean_rms^2 n_clean / n_fixes + jump_rmse^2)``.
        fixed_floor_low, fixed_floor_high: floor of ``rmse_fixed``: the frame's cost at the
            smallest and largest ``delta`` fitted, with ``aligned_floor`` added in quadrature.
        reference_window: the W (s) of ``aligned_floor``.
    """

    n_fixes: int
    n_jumps: int
    gaps_over_1s: int
    longest_gap_s: float
    jump_offset_median: float
    jump_offset_max: float
    jump_rmse: float
    local_rms: tuple
    white_sigma: float
    antenna_offset: tuple
    clock_offset_s: float
    offset_fit_rms: float
    offset_fit_rms_without: float
    r_rms: float
    frame: tuple
    frame_rmse_1deg: float
    frame_rmse_2deg: float
    aligned_floor: float
    fixed_floor_low: float
    fixed_floor_high: float
    reference_window: float


def _pose_at(tq: np.ndarray, t: np.ndarray, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """DR positions ``(n, 2)`` and headings ``(n,)`` at times ``tq`` (linear; heading unwrapped)."""
    xy = np.stack([np.interp(tq, t, pose[:, 0]), np.interp(tq, t, pose[:, 1])], axis=1)
    return xy, np.interp(tq, t, np.unwrap(pose[:, 2]))


def _local_residuals(gt, ref, P, keep, inside, window: float) -> tuple[np.ndarray, np.ndarray]:
    """Each fix's distance from the DR path rigidly fitted to the clean fixes within ``window / 2``
    seconds of it (the fix left out), and that fit's rotation (rad); NaN where fewer than half the
    window's fixes are there.

    The fits are the closed-form 2-D least-squares rotation ``atan2(sum(p'x q'y - p'y q'x),
    sum(p'x q'x + p'y q'y))`` of the centred points (as :func:`~nanoslam_jax.eval.metrics.rigid_align`
    gives), from running sums, so all fixes cost one pass."""
    use = (keep & inside).astype(float)
    px, py, qx, qy = P[:, 0], P[:, 1], ref[:, 0], ref[:, 1]
    cols = np.stack([use, px, py, qx, qy, px * qx, px * qy, py * qx, py * qy]) * use
    csum = np.concatenate([np.zeros((9, 1)), np.cumsum(cols, axis=1)], axis=1)
    lo = np.searchsorted(gt, gt - window / 2)
    hi = np.searchsorted(gt, gt + window / 2, side="right")
    n, sx, sy, tx, ty, xx, xy, yx, yy = csum[:, hi] - csum[:, lo] - cols  # the window, fix i left out
    rate = 1.0 / np.median(np.diff(gt))
    ok = inside & (n >= max(5, int(0.5 * rate * window)))
    n = np.where(ok, n, 1.0)
    mx, my, nx, ny = sx / n, sy / n, tx / n, ty / n
    theta = np.arctan2((xy - n * mx * ny) - (yx - n * my * nx), (xx - n * mx * nx) + (yy - n * my * ny))
    c, s = np.cos(theta), np.sin(theta)
    ex = c * (px - mx) - s * (py - my) + nx - qx
    ey = s * (px - mx) + c * (py - my) + ny - qy
    return np.where(ok, np.hypot(ex, ey), np.nan), np.where(ok, theta, np.nan)


def _jump_offsets(gt, ref, keep, inside) -> np.ndarray:
    """Each jump fix's (``~keep & inside``) distance from the track of the clean fixes: their
    positions interpolated linearly in time at its time (the nearest clean fix's where it has
    none on one side)."""
    k = np.flatnonzero(keep)
    jump = ~keep & inside
    if k.size == 0 or not jump.any():
        return np.zeros(0)
    track = np.stack([np.interp(gt[jump], gt[k], ref[k, 0]), np.interp(gt[jump], gt[k], ref[k, 1])], axis=1)
    return np.hypot(*(ref[jump] - track).T)


def _white_sigma(gt, ref, P, keep, inside, rot) -> float:
    dt = np.diff(gt)
    nominal = np.median(dt)
    regular = np.abs(dt - nominal) < 0.1 * nominal
    ok = keep & inside & np.isfinite(rot)
    i = np.flatnonzero(regular[:-1] & regular[1:] & ok[:-2] & ok[1:-1] & ok[2:])
    if i.size < 10:
        return math.nan
    g2 = ref[i] - 2 * ref[i + 1] + ref[i + 2]
    d2 = P[i] - 2 * P[i + 1] + P[i + 2]
    c, s = np.cos(rot[i + 1]), np.sin(rot[i + 1])
    e = g2 - np.stack([c * d2[:, 0] - s * d2[:, 1], s * d2[:, 0] + c * d2[:, 1]], axis=1)
    mad = np.median(np.abs(e - np.median(e, axis=0)), axis=0)
    return float(np.sqrt(np.mean((1.4826 * mad) ** 2 / 6.0)))


def _offset_fit(gt, ref, t, pose, keep, inside, window: float) -> tuple[tuple, float, float, float]:
    """Joint fit of a body-frame antenna offset, a clock shift and a rigid transform per window."""
    from scipy.optimize import least_squares
    from scipy.sparse import coo_matrix

    use = keep & inside & (gt >= t[0] + 1.0) & (gt <= t[-1] - 1.0)
    win = np.floor((gt - gt[0]) / window).astype(int)
    rate = 1.0 / np.median(np.diff(gt))
    groups = [np.flatnonzero(use & (win == w)) for w in np.unique(win[use])]
    groups = [g for g in groups if g.size >= max(5, 0.5 * rate * window)]
    if len(groups) < 2:
        return (math.nan, math.nan), math.nan, math.nan, math.nan
    idx = np.concatenate(groups)
    wid = np.concatenate([np.full(g.size, k) for k, g in enumerate(groups)])
    nw = len(groups)

    def resid(q):
        xy, phi = _pose_at(gt[idx] + q[2], t, pose)
        c, s = np.cos(phi), np.sin(phi)
        px, py = xy[:, 0] + c * q[0] - s * q[1], xy[:, 1] + s * q[0] + c * q[1]
        th, tr = q[3 : 3 + nw][wid], q[3 + nw :].reshape(nw, 2)[wid]
        C, S = np.cos(th), np.sin(th)
        return np.concatenate([C * px - S * py + tr[:, 0] - ref[idx, 0], S * px + C * py + tr[:, 1] - ref[idx, 1]])

    q0 = np.zeros(3 + 3 * nw)
    xy0, _ = _pose_at(gt[idx], t, pose)
    for k in range(nw):
        R, tr, _ = rigid_align(xy0[wid == k], ref[idx[wid == k]])
        q0[3 + k], q0[3 + nw + 2 * k : 5 + nw + 2 * k] = math.atan2(R[1, 0], R[0, 0]), tr
    rms = lambda r: float(np.sqrt(np.mean(r[: idx.size] ** 2 + r[idx.size :] ** 2)))  # noqa: E731
    # Each residual depends on the offset, the shift and its own window's three parameters.
    rows = np.arange(2 * idx.size)
    w2 = np.concatenate([wid, wid])
    cols = np.concatenate([np.tile([0, 1, 2], rows.size), 3 + w2, 3 + nw + 2 * w2, 4 + nw + 2 * w2])
    sparsity = coo_matrix(
        (np.ones(cols.size), (np.concatenate([np.repeat(rows, 3), rows, rows, rows]), cols)), shape=(rows.size, q0.size)
    )
    sol = least_squares(resid, q0, x_scale="jac", jac_sparsity=sparsity)
    return (float(sol.x[0]), float(sol.x[1])), float(sol.x[2]), rms(sol.fun), rms(resid(q0))


@dataclasses.dataclass(frozen=True)
class FloorWindows:
    """The windows :func:`estimate_gps_floor` measures over (seconds).

    Attributes:
        local: window lengths W of the short-term error.
        reference: the W of the ``rmse_aligned`` floor (added to ``local`` if absent).
        frame: lengths T of the initial stretches the frame is fitted on.
        offset: window length of the antenna/clock offset fit.
    """

    local: Sequence[float] = (5.0, 10.0, 20.0, 60.0)
    reference: float = 10.0
    frame: Sequence[float] = (30.0, 40.0, 60.0, 80.0, 120.0)
    offset: float = 20.0


def estimate_gps_floor(
    gps: np.ndarray,
    t: np.ndarray,
    pose: np.ndarray,
    *,
    rotation_deg: float = -35.4,
    jump_speed: float = 8.0,
    source_rotation_deg: float = GPS_DAT_ROTATION_DEG,
    windows: FloorWindows = FloorWindows(),
) -> GpsFloor:
    """Estimate the GPS's share of the RMSE (see the module docstring).

    Args:
        gps: ``(G, 3)`` fixes ``time, x, y`` (``RawLog.gps``: the ``gps.dat`` frame).
        t: ``(T,)`` times of the DR path, increasing.
        pose: ``(T, 3)`` DR laser poses ``x, y, phi`` in the SLAM frame.
        rotation_deg, source_rotation_deg: the fixed frame (:func:`~nanoslam_jax.eval.metrics.relative_gps`).
        jump_speed: fixes implying a faster jump are jumps (:func:`~nanoslam_jax.eval.metrics.jump_mask`).
        windows: the lengths of the windows the errors are measured over (:class:`FloorWindows`).
    """
    gps = np.asarray(gps, float)
    t, pose = np.asarray(t, float), np.asarray(pose, float)
    gt = gps[:, 0]
    ref = relative_gps(gps[:, 1:3], rotation_deg, source_rotation_deg=source_rotation_deg)
    keep = jump_mask(gt, gps[:, 1:3], jump_speed)
    inside = (gt >= t[0]) & (gt <= t[-1])
    if inside.sum() < 10:
        raise ValueError(f"only {int(inside.sum())} GPS fixes fall inside the DR path's span [{t[0]}, {t[-1]}] s")
    offset, clock, fit_rms, fit_rms0 = _offset_fit(gt, ref, t, pose, keep, inside, windows.offset)
    # The path the GPS antenna follows by the fitted offset and shift (the DR path when the fit failed).
    o, tau = (offset, clock) if math.isfinite(clock) else ((0.0, 0.0), 0.0)
    P, phi = _pose_at(gt + tau, t, pose)
    P = P + np.stack([np.cos(phi) * o[0] - np.sin(phi) * o[1], np.sin(phi) * o[0] + np.cos(phi) * o[1]], axis=1)
    local, ref_rot = [], None
    for w in sorted(set(windows.local) | {windows.reference}):
        res, rot = _local_residuals(gt, ref, P, keep, inside, w)
        ok = np.isfinite(res)
        local.append(
            (
                float(w),
                float(np.sqrt(np.mean(res[ok] ** 2))),
                float(np.sqrt(np.mean(res[ok & keep] ** 2))),
                int(ok.sum()),
            )
        )
        if w == windows.reference:
            ref_rot = rot
    jumps = _jump_offsets(gt, ref, keep, inside)
    n_in, n_clean = int(inside.sum()), int((keep & inside).sum())
    jump_rmse = float(np.sqrt(np.sum(jumps**2) / n_in))
    clean = next(c for w, _, c, _ in local if w == windows.reference)
    aligned = float(np.sqrt(clean**2 * n_clean / n_in + jump_rmse**2))
    g = ref[inside]
    # What a frame rotated by `deg` about the first fix costs an exact path, RMS over the fixes.
    shift = lambda deg: float(np.sqrt(np.mean(np.sum((g @ rotation_matrix(deg).T - g) ** 2, axis=1))))  # noqa: E731
    frame = []
    for T in windows.frame:
        m = inside & keep & (gt <= t[0] + T)
        if m.sum() < 5:
            continue
        R, tr, _ = rigid_align(P[m], ref[m])
        delta = math.degrees(math.atan2(R[1, 0], R[0, 0]))
        frame.append((float(T), delta, float(tr[0]), float(tr[1]), shift(delta)))
    fr = [f[4] for f in frame] or [math.nan]
    gaps = np.diff(gt[inside])
    return GpsFloor(
        n_fixes=int(inside.sum()),
        n_jumps=int((~keep & inside).sum()),
        gaps_over_1s=int((gaps > 1.0).sum()),
        longest_gap_s=float(gaps.max(initial=0.0)),
        jump_offset_median=float(np.median(jumps)) if jumps.size else math.nan,
        jump_offset_max=float(jumps.max()) if jumps.size else math.nan,
        jump_rmse=jump_rmse,
        local_rms=tuple(local),
        white_sigma=_white_sigma(gt, ref, P, keep, inside, ref_rot),
        antenna_offset=offset,
        clock_offset_s=clock,
        offset_fit_rms=fit_rms,
        offset_fit_rms_without=fit_rms0,
        r_rms=float(np.sqrt(np.mean(np.sum(g**2, axis=1)))),
        frame=tuple(frame),
        frame_rmse_1deg=shift(1.0),
        frame_rmse_2deg=shift(2.0),
        aligned_floor=aligned,
        fixed_floor_low=float(math.hypot(min(fr), aligned)),
        fixed_floor_high=float(math.hypot(max(fr), aligned)),
        reference_window=float(windows.reference),
    )


class _MotionOnly(NamedTuple):
    """The part of the filter's hyperparameters dead reckoning reads: the motion model."""

    motion: Any


def gps_floor_of_log(motion, metrics, log, segments: Optional[int] = None) -> GpsFloor:
    """:func:`estimate_gps_floor` of a real log, with the dead-reckoned path of a motion model.

    Args:
        motion: the vehicle's motion model (an :class:`~nanoslam_jax.models.AbstractMotionModel`).
        metrics: the evaluation protocol's settings (:class:`~nanoslam_jax.eval.MetricsConfig`:
            the GPS frame's rotation and the jump speed).
        log: the log's segments and GPS: a :class:`~nanoslam_jax.app.experiment.LoadedLog` or a
            :class:`~nanoslam_jax.app.sweep.LogData`.
        segments: use only the first this many segments (the span a study scores).
    """
    import jax

    from nanoslam_jax.methods import dead_reckoning

    seg = log.segments
    if segments is not None:
        seg = type(seg)(*(np.asarray(a)[:segments] for a in seg))
    pose = np.asarray(jax.jit(dead_reckoning)(_MotionOnly(motion), seg))
    gps = log.raw.gps if hasattr(log, "raw") else log.gps
    return estimate_gps_floor(
        gps, np.asarray(seg.time), pose, rotation_deg=metrics.gps_rotation_deg, jump_speed=metrics.jump_speed
    )


def floor_markdown(f: GpsFloor) -> str:
    """The floor as a Markdown report."""
    lines = [
        "# The GPS floor",
        "",
        f"{f.n_fixes} GPS fixes in the span; {f.n_jumps} jumps ({100 * f.n_jumps / max(f.n_fixes, 1):.1f} %), "
        f"{f.jump_offset_median:.2f} m (median) and {f.jump_offset_max:.2f} m (largest) from the track of the "
        f"clean fixes; alone they add {f.jump_rmse:.2f} m to the RMSE of any path (both variants; not to the "
        f"`*_clean` ones). {f.gaps_over_1s} gaps over 1 s, the longest {f.longest_gap_s:.1f} s.",
        "",
        "| window W [s] | short-term GPS error, RMS all fixes [m] | RMS clean fixes [m] | fixes scored |",
        "|---|---|---|---|",
        *[f"| {w:g} | {a:.3f} | {c:.3f} | {n} |" for w, a, c, n in f.local_rms],
        "",
        f"White noise (second differences against DR): {f.white_sigma:.3f} m per axis.",
        "",
        f"Antenna offset from the laser (forward, left): ({f.antenna_offset[0]:.2f}, {f.antenna_offset[1]:.2f}) m; "
        f"GPS clock shift {f.clock_offset_s:+.3f} s; fit RMS {f.offset_fit_rms:.3f} m against "
        f"{f.offset_fit_rms_without:.3f} m without them.",
        "",
        f"The fixed frame: RMS distance of the fixes from the first fix {f.r_rms:.1f} m; a frame rotated by 1 deg "
        f"moves them by {f.frame_rmse_1deg:.2f} m RMS, by 2 deg {f.frame_rmse_2deg:.2f} m.",
        "",
        "| DR fitted over the first T [s] | rotation off the fixed frame [deg] | translation [m] | its cost to an exact path in the fixed frame, RMS [m] |",
        "|---|---|---|---|",
        *[f"| {T:g} | {d:+.2f} | ({tx:.2f}, {ty:.2f}) | {r:.2f} |" for T, d, tx, ty, r in f.frame],
        "",
        f"**Floor of rmse_aligned** (short-term error of the clean fixes, W = {f.reference_window:g} s, and the jumps): "
        f"{f.aligned_floor:.2f} m. "
        f"**Floor of rmse_fixed** (with the cost of the smallest and the largest rotation fitted): "
        f"{f.fixed_floor_low:.2f}-{f.fixed_floor_high:.2f} m.",
        "",
    ]
    return "\n".join(lines)
