"""Evaluation against GPS and ground truth, numpy on the host.

The protocol:

1. the estimated positions are interpolated linearly in time at every GPS fix time inside the
   estimate's time span (:func:`interpolate_at`); fixes outside it are excluded and counted;
2. ``rmse_fixed``: against GPS in a fixed frame with no fitting. ``frame="relative"``: the
   relative-GPS frame of the Unscented FastSLAM authors (GPS minus the first fix, rotated by
   ``rotation_deg``, default -35.4 deg, see :func:`relative_gps`); ``frame="slam"``: the GPS as
   given (simulated logs, whose GPS is already in the SLAM frame);
3. ``rmse_aligned``: after the best-fit 2-D rigid alignment of the estimate onto the GPS
   (:func:`rigid_align`: rotation + translation, least squares, no scale);
4. the same two with the fixes flagged by :func:`jump_mask` removed (``*_clean``).

**Frames of the real GPS.** The -35.4 deg rotation of the relative-GPS frame applies to the
*raw* GPS (``Lo_m, La_m`` of ``aa3_gpsx.mat``). ``gps.dat``, the frame of
:attr:`RawLog.gps <nanoslam_jax.data._types.RawLog>`, is already ``R(-33 deg) (Lo + 67, La + 39)``.
:func:`relative_gps` therefore takes the rotation already applied to its input,
``source_rotation_deg`` (default :data:`GPS_DAT_ROTATION_DEG` = -33, i.e. ``gps.dat``; pass 0
for raw ``Lo/La``), and rotates by ``rotation_deg - source_rotation_deg`` (-2.4 deg for
``gps.dat``), not by a further -35.4 deg.

Rotations are counter-clockwise positive: a point ``p`` rotated by ``theta`` is ``R(theta) p`` with
``R = [[cos, -sin], [sin, cos]]``. The protocol and the frames are described in the docs, page
"The Victoria Park model and scoring" (``docs/method/victoria-park.md``).
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np

from nanoslam_jax.eval._align import _rmse, rigid_align, rotation_matrix
from nanoslam_jax.eval._settings import MetricsConfig

#: The configuration's ``metrics`` section: the one source of the protocol's defaults here.
_METRICS = MetricsConfig()

__all__ = [
    "GPS_DAT_ROTATION_DEG",
    "rotation_matrix",
    "interpolate_at",
    "relative_gps",
    "rigid_align",
    "jump_mask",
    "evaluate",
    "error_over_time",
    "heading_errors",
    "rmse_heading_deg",
    "landmark_errors",
    "observable_landmarks",
    "map_quality",
    "map_summary",
    "survey_summary",
    "map_alignment_metrics",
    "line_feature_errors",
    "arc_feature_errors",
    "point_feature_errors",
    "line_intersections",
    "feature_map_errors",
    "FeatureGates",
    "MIN_SCANS_OBSERVABLE",
]

#: Rotation (deg) already applied to the raw GPS in ``gps.dat``: ``R(-33 deg) (Lo + 67, La + 39)``.
GPS_DAT_ROTATION_DEG = -33.0


def interpolate_at(times: np.ndarray, est_t: np.ndarray, est_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Linear interpolation of an estimated trajectory at query times.

    Args:
        times: ``(G,)`` query times (the GPS fix times), any order.
        est_t: ``(T,)`` times of the estimate, non-decreasing (repeated times allowed).
        est_xy: ``(T, 2)`` estimated positions.

    Returns:
        ``(xy, inside)``: ``(G, 2)`` interpolated positions (NaN where outside) and the ``(G,)``
        boolean mask of the query times inside the closed span ``[est_t[0], est_t[-1]]``.

    Raises:
        ValueError: on mismatched shapes, an empty estimate or decreasing ``est_t``.
    """
    times = np.asarray(times, dtype=float).reshape(-1)
    est_t = np.asarray(est_t, dtype=float).reshape(-1)
    est_xy = np.asarray(est_xy, dtype=float)
    if est_xy.ndim != 2 or est_xy.shape[1] != 2 or est_xy.shape[0] != est_t.shape[0]:
        raise ValueError(f"est_xy must be (T, 2) with T = len(est_t) = {est_t.shape[0]}, got {est_xy.shape}")
    if est_t.shape[0] == 0:
        raise ValueError("the estimate is empty")
    if np.any(np.diff(est_t) < 0):
        raise ValueError("est_t must be non-decreasing")
    inside = (times >= est_t[0]) & (times <= est_t[-1])
    xy = np.full((times.shape[0], 2), np.nan)
    ti = times[inside]
    xy[inside, 0] = np.interp(ti, est_t, est_xy[:, 0])
    xy[inside, 1] = np.interp(ti, est_t, est_xy[:, 1])
    return xy, inside


def relative_gps(
    gps_xy: np.ndarray,
    rotation_deg: float = _METRICS.gps_rotation_deg,
    *,
    source_rotation_deg: float = GPS_DAT_ROTATION_DEG,
) -> np.ndarray:
    """The relative-GPS frame: GPS minus its first fix, rotated.

    Args:
        gps_xy: ``(G, 2)`` GPS positions; the first row is the origin.
        rotation_deg: rotation of the relative frame with respect to the *raw* GPS
            (``Lo_m, La_m``); -35.4 deg (``atan(-0.71)``) in the Unscented FastSLAM code.
        source_rotation_deg: rotation already applied to ``gps_xy`` relative to the raw GPS:
            -33 for ``gps.dat`` (the default, the frame of ``RawLog.gps``), 0 for raw ``Lo/La``.

    Returns:
        ``(G, 2)`` ``R(rotation_deg - source_rotation_deg) (gps_xy - gps_xy[0])``.
    """
    gps_xy = np.asarray(gps_xy, dtype=float)
    if gps_xy.ndim != 2 or gps_xy.shape[1] != 2 or gps_xy.shape[0] == 0:
        raise ValueError(f"gps_xy must be a non-empty (G, 2) array, got {gps_xy.shape}")
    return (gps_xy - gps_xy[0]) @ rotation_matrix(rotation_deg - source_rotation_deg).T


def jump_mask(gps_t: np.ndarray, gps_xy: np.ndarray, max_speed: float = _METRICS.jump_speed) -> np.ndarray:
    """Which GPS fixes to keep once jumps are removed.

    The rule, applied in time order: the first fix is kept; fix ``i`` is kept when the speed
    implied from the **last kept** fix ``j``, ``|xy_i - xy_j| / (t_i - t_j)``, is at most
    ``max_speed``; otherwise it is dropped and ``j`` stays the reference. A fix with the same
    time as the last kept one is kept only if it is at the same position. Because the reference
    is the last *kept* fix, an isolated outlier costs one fix, and after a lasting offset the
    fixes are accepted again once the elapsed time makes the implied speed plausible. Speeds
    are invariant under rotation and translation, so any GPS frame gives the same mask.

    Args:
        gps_t: ``(G,)`` fix times, non-decreasing.
        gps_xy: ``(G, 2)`` positions (m).
        max_speed: largest plausible speed (m/s).

    Returns:
        ``(G,)`` boolean mask, True for fixes kept.
    """
    gps_t = np.asarray(gps_t, dtype=float).reshape(-1)
    gps_xy = np.asarray(gps_xy, dtype=float)
    if gps_xy.shape != (gps_t.shape[0], 2):
        raise ValueError(f"gps_xy must be (G, 2) with G = len(gps_t) = {gps_t.shape[0]}, got {gps_xy.shape}")
    keep = np.zeros(gps_t.shape[0], dtype=bool)
    if gps_t.shape[0] == 0:
        return keep
    keep[0] = True
    tj, xj, yj = gps_t[0], gps_xy[0, 0], gps_xy[0, 1]
    for i in range(1, gps_t.shape[0]):
        d = math.hypot(gps_xy[i, 0] - xj, gps_xy[i, 1] - yj)
        dt = gps_t[i] - tj
        ok = d <= max_speed * dt if dt > 0 else d == 0.0
        if ok:
            keep[i] = True
            tj, xj, yj = gps_t[i], gps_xy[i, 0], gps_xy[i, 1]
    return keep


def _reference(gps: np.ndarray, frame: str, rotation_deg: float, source_rotation_deg: float) -> np.ndarray:
    gps = np.asarray(gps, dtype=float)
    if gps.ndim != 2 or gps.shape[1] != 3:
        raise ValueError(f"gps must be (G, 3) rows of time, x, y, got {gps.shape}")
    if frame == "relative":
        return relative_gps(gps[:, 1:3], rotation_deg, source_rotation_deg=source_rotation_deg)
    if frame == "slam":
        return gps[:, 1:3].copy()
    raise ValueError(f"frame must be 'relative' or 'slam', got {frame!r}")


def _prepare(est_t, est_xy, gps, frame, rotation_deg, source_rotation_deg):
    """Reference positions, interpolated estimate and the in-span mask; errors when none overlap."""
    gps = np.asarray(gps, dtype=float)
    ref = _reference(gps, frame, rotation_deg, source_rotation_deg)
    if np.any(np.diff(gps[:, 0]) < 0):
        raise ValueError("gps times must be non-decreasing")
    xy, inside = interpolate_at(gps[:, 0], est_t, est_xy)
    if not inside.any():
        span = f"[{gps[0, 0]}, {gps[-1, 0]}] s" if gps.shape[0] else "nothing"
        raise ValueError(
            f"no GPS fix falls inside the estimate's time span [{np.min(est_t)}, {np.max(est_t)}] s "
            f"(the GPS covers {span})"
        )
    return gps, ref, xy, inside


def error_over_time(
    est_t: np.ndarray,
    est_xy: np.ndarray,
    gps: np.ndarray,
    *,
    rotation_deg: float = _METRICS.gps_rotation_deg,
    frame: Literal["relative", "slam"] = "relative",
    source_rotation_deg: float = GPS_DAT_ROTATION_DEG,
) -> tuple[np.ndarray, np.ndarray]:
    """Position error in the fixed frame at every GPS fix inside the estimate's span.

    Args:
        est_t: ``(T,)`` estimate times, non-decreasing.
        est_xy: ``(T, 2)`` estimated positions in the SLAM frame.
        gps: ``(G, 3)`` fixes ``time, x, y``.
        rotation_deg: relative-GPS rotation (``frame="relative"``).
        frame: ``"relative"`` (:func:`relative_gps`) or ``"slam"`` (GPS used as given).
        source_rotation_deg: rotation already in ``gps`` (see :func:`relative_gps`).

    Returns:
        ``(t, err)``: ``(n,)`` fix times and ``(n,)`` distances (m).

    Raises:
        ValueError: when no fix falls inside the estimate's span.
    """
    gps, ref, xy, inside = _prepare(est_t, est_xy, gps, frame, rotation_deg, source_rotation_deg)
    return gps[inside, 0], np.hypot(*(xy[inside] - ref[inside]).T)


def evaluate(
    est_t: np.ndarray,
    est_xy: np.ndarray,
    gps: np.ndarray,
    *,
    rotation_deg: float = _METRICS.gps_rotation_deg,
    jump_speed: float = 8.0,
    frame: Literal["relative", "slam"] = "relative",
    source_rotation_deg: float = GPS_DAT_ROTATION_DEG,
) -> dict:
    """Score an estimated trajectory against GPS (the protocol above; ``docs/method/victoria-park.md``).

    Args:
        est_t: ``(T,)`` estimate times (s), non-decreasing.
        est_xy: ``(T, 2)`` estimated laser positions in the SLAM frame.
        gps: ``(G, 3)`` fixes ``time, x, y`` (``RawLog.gps``).
        rotation_deg: rotation of the relative-GPS frame (``MetricsConfig.gps_rotation_deg``).
        jump_speed: fixes implying a faster jump are removed in the ``*_clean`` figures
            (:func:`jump_mask`, computed over all fixes, then restricted to the span).
        frame: ``"relative"``: compare in the relative-GPS frame; ``"slam"``: compare with the
            GPS as given (simulated logs: ``rmse_fixed`` is then the plain error).
        source_rotation_deg: rotation already applied to ``gps`` (-33 for ``gps.dat``); only
            used with ``frame="relative"``.

    Returns:
        A dict of Python numbers: ``rmse_fixed``, ``rmse_aligned``, ``rmse_fixed_clean``,
        ``rmse_aligned_clean``, ``mean_error``, ``max_error``, ``final_error`` (fixed frame,
        last fix in the span), ``align_rotation_deg``, ``align_x``, ``align_y`` (the best-fit
        alignment ``p -> R(align_rotation_deg) p + (align_x, align_y)``), ``align_rotation_clean_deg``, and the counts ``n_fixes`` (fixes used), ``n_fixes_clean``,
        ``n_fixes_outside`` (fixes outside the estimate's span, excluded), ``n_gps`` (all fixes).
        A ``*_clean`` value is NaN when no clean fix is in the span.

    Raises:
        ValueError: when no GPS fix falls inside the estimate's span, or on bad shapes/frame.
    """
    gps, ref, xy, inside = _prepare(est_t, est_xy, gps, frame, rotation_deg, source_rotation_deg)
    err = np.hypot(*(xy[inside] - ref[inside]).T)
    clean = jump_mask(gps[:, 0], gps[:, 1:3], jump_speed) & inside

    R, shift, aligned = rigid_align(xy[inside], ref[inside])
    out = {
        "rmse_fixed": _rmse(err),
        "rmse_aligned": _rmse(np.hypot(*(aligned - ref[inside]).T)),
        "mean_error": float(np.mean(err)),
        "max_error": float(np.max(err)),
        "final_error": float(err[-1]),
        "align_rotation_deg": float(np.degrees(np.arctan2(R[1, 0], R[0, 0]))),
        "align_x": float(shift[0]),
        "align_y": float(shift[1]),
        "n_fixes": int(inside.sum()),
        "n_fixes_clean": int(clean.sum()),
        "n_fixes_outside": int((~inside).sum()),
        "n_gps": int(gps.shape[0]),
    }
    if clean.any():
        err_c = np.hypot(*(xy[clean] - ref[clean]).T)
        Rc, _, aligned_c = rigid_align(xy[clean], ref[clean])
        out["rmse_fixed_clean"] = _rmse(err_c)
        out["rmse_aligned_clean"] = _rmse(np.hypot(*(aligned_c - ref[clean]).T))
        out["align_rotation_clean_deg"] = float(np.degrees(np.arctan2(Rc[1, 0], Rc[0, 0])))
    else:
        out["rmse_fixed_clean"] = out["rmse_aligned_clean"] = out["align_rotation_clean_deg"] = float("nan")
    return out


def heading_errors(est_t: np.ndarray, est_phi: np.ndarray, truth_poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Heading error, wrapped to [-180, 180) deg, at every estimate time inside the truth's span.

    The true heading is interpolated linearly in time (unwrapped first, so an interpolation never
    crosses the +-180 deg cut the long way round); the error is ``estimate - truth``, wrapped.

    Args:
        est_t: ``(T,)`` estimate times (s).
        est_phi: ``(T,)`` estimated headings (rad, any branch).
        truth_poses: ``(N, 4)`` true poses ``time, x, y, phi`` (``RawLog.truth_poses``), times
            non-decreasing.

    Returns:
        ``(t, err_deg)``: the estimate times inside the truth's span and the errors there (deg).

    Raises:
        ValueError: on bad shapes, or when no estimate time falls inside the truth's span.
    """
    tp = np.asarray(truth_poses, dtype=float)
    est_t, est_phi = np.asarray(est_t, dtype=float), np.asarray(est_phi, dtype=float)
    if tp.ndim != 2 or tp.shape[1] != 4:
        raise ValueError(f"truth_poses must be (N, 4) rows of time, x, y, phi, got {tp.shape}")
    if est_t.shape != est_phi.shape or est_t.ndim != 1:
        raise ValueError(f"est_t and est_phi must be matching (T,) arrays, got {est_t.shape} and {est_phi.shape}")
    inside = (est_t >= tp[0, 0]) & (est_t <= tp[-1, 0]) if tp.shape[0] else np.zeros(est_t.shape, bool)
    if not inside.any():
        raise ValueError("no estimate time falls inside the true path's time span")
    truth = np.interp(est_t[inside], tp[:, 0], np.unwrap(tp[:, 3]))
    err = np.mod(est_phi[inside] - truth + np.pi, 2.0 * np.pi) - np.pi
    return est_t[inside], np.degrees(err)


def rmse_heading_deg(est_t: np.ndarray, est_phi: np.ndarray, truth_poses: np.ndarray) -> float:
    """Root mean square of the wrapped heading error (deg) against a true path (:func:`heading_errors`)."""
    return _rmse(heading_errors(est_t, est_phi, truth_poses)[1])


def landmark_errors(est_landmarks: np.ndarray, true_landmarks: np.ndarray, radius: float = 2.0) -> dict:
    """Map quality against the true landmarks of a simulated log (same frame, no alignment).

    Args:
        est_landmarks: ``(E, 2)`` estimated landmark positions (only the valid ones).
        true_landmarks: ``(L, 2)`` true positions.
        radius: matching radius (m).

    Returns:
        A dict: ``est_to_true`` ``(E,)`` distance of each estimate to its nearest true landmark;
        ``true_to_est`` ``(L,)`` distance of each true landmark to its nearest estimate (inf when
        there is no estimate); ``n_est``, ``n_true``; ``n_matched`` estimates within ``radius``
        of a true landmark; ``n_spurious = n_est - n_matched``; ``n_found`` true landmarks with an
        estimate within ``radius``; ``rmse_matched`` RMS of ``est_to_true`` over matched
        estimates (NaN when none); ``median_est_to_true``. Memory is ``O(E L)``.
    """
    est = np.asarray(est_landmarks, dtype=float).reshape(-1, 2)
    tru = np.asarray(true_landmarks, dtype=float).reshape(-1, 2)
    if est.shape[0] and tru.shape[0]:
        d = np.sqrt(np.sum((est[:, None, :] - tru[None, :, :]) ** 2, axis=-1))
        e2t, t2e = d.min(axis=1), d.min(axis=0)
    else:
        e2t = np.full(est.shape[0], np.inf)
        t2e = np.full(tru.shape[0], np.inf)
    matched = e2t <= radius
    return {
        "est_to_true": e2t,
        "true_to_est": t2e,
        "n_est": int(est.shape[0]),
        "n_true": int(tru.shape[0]),
        "n_matched": int(matched.sum()),
        "n_spurious": int((~matched).sum()),
        "n_found": int((t2e <= radius).sum()),
        "rmse_matched": _rmse(e2t[matched]),
        "median_est_to_true": float(np.median(e2t)) if e2t.size else float("nan"),
    }


#: A true landmark counts as observable when the sensor footprint held it at this many scans.
MIN_SCANS_OBSERVABLE = 10


def observable_landmarks(
    true_landmarks: np.ndarray,
    truth_poses: np.ndarray,
    scan_times: np.ndarray,
    max_range: float,
    fov_deg: float = 180.0,
    min_range: float = 0.0,
    min_scans: int = MIN_SCANS_OBSERVABLE,
) -> np.ndarray:
    """Which true landmarks a filter could map: those inside the sensor footprint of the true pose
    at ``min_scans`` scans or more (a tree never or only fleetingly in view cannot be mapped, and a
    map's completeness is judged against the others).

    Args:
        true_landmarks: ``(L, 2)`` true positions.
        truth_poses: ``(T, 4)`` true laser poses ``time, x, y, phi`` (sorted by time).
        scan_times: times of the scans.
        max_range: the sensor's range (m): a landmark is in view at ``min_range <= r < max_range``.
        fov_deg: the field of view (deg), centred on the forward axis.
        min_range: the sensor's minimum range (m).
        min_scans: scans in view needed.

    Returns:
        ``(L,)`` boolean mask.
    """
    tru = np.asarray(true_landmarks, dtype=float).reshape(-1, 2)
    tp = np.asarray(truth_poses, dtype=float)
    t = np.asarray(scan_times, dtype=float)
    x, y = np.interp(t, tp[:, 0], tp[:, 1]), np.interp(t, tp[:, 0], tp[:, 2])
    phi = np.interp(t, tp[:, 0], np.unwrap(tp[:, 3]))
    dx, dy = tru[None, :, 0] - x[:, None], tru[None, :, 1] - y[:, None]
    r = np.hypot(dx, dy)
    b = np.mod(np.arctan2(dy, dx) - phi[:, None] + np.pi, 2 * np.pi) - np.pi
    inside = (r >= min_range) & (r < max_range) & (np.abs(b) <= np.radians(fov_deg) / 2)
    return inside.sum(axis=0) >= min_scans


def map_quality(est_landmarks: np.ndarray, true_landmarks: np.ndarray, radius: float = _METRICS.map_radius) -> dict:
    """Map-quality figures of a simulated log (what ``metrics.json`` reports as ``map_*``).

    Args:
        est_landmarks: ``(E, 2)`` the map's (confirmed) landmarks.
        true_landmarks: ``(L, 2)`` the true landmarks it is judged against (the observable ones).
        radius: a landmark within this distance of a true one matches it (m).

    Returns:
        ``n_est``, ``n_true``, ``n_found`` (true landmarks with an estimate within ``radius``),
        ``found_fraction = n_found / n_true``, ``n_spurious`` (estimates with no true landmark
        within ``radius``), ``spurious_fraction = n_spurious / n_est``, ``rmse_matched`` and
        ``median_est_to_true`` (see :func:`landmark_errors`).
    """
    le = landmark_errors(est_landmarks, true_landmarks, radius)
    out = {k: le[k] for k in ("n_est", "n_true", "n_found", "n_spurious", "rmse_matched", "median_est_to_true")}
    out["found_fraction"] = le["n_found"] / le["n_true"] if le["n_true"] else float("nan")
    out["spurious_fraction"] = le["n_spurious"] / le["n_est"] if le["n_est"] else float("nan")
    return out


def map_summary(
    xy: np.ndarray,
    confirmed: np.ndarray,
    map_truth: np.ndarray | None,
    radius: float,
    alignment: dict | None = None,
) -> dict:
    """What ``metrics.json`` (and a sweep's results) report of a map.

    Args:
        xy: ``(L, 2)`` the map's active landmarks (tentative and confirmed).
        confirmed: ``(L,)`` which of them are confirmed.
        map_truth: the true landmarks the map is judged against (the observable ones of a simulated
            log), or None without ground truth.
        radius: matching radius (m) of :func:`map_quality`.
        alignment: the trajectory's best-fit rigid alignment (:func:`evaluate`'s
            ``align_rotation_deg``, ``align_x``, ``align_y``), or None.

    Returns:
        ``n_landmarks`` and ``n_confirmed``, and with ``map_truth`` the ``map_*`` figures of
        :func:`map_quality` over the confirmed landmarks in the SLAM frame, and with ``alignment``
        too the same figures ``map_*_aligned`` after moving the map by the trajectory's
        alignment (a map is judged free of the global rotation and shift that ``rmse_aligned``
        removes from the trajectory).
    """
    confirmed = np.asarray(confirmed, bool)
    out: dict = {"n_landmarks": int(confirmed.shape[0]), "n_confirmed": int(confirmed.sum())}
    if map_truth is not None:
        est = np.asarray(xy, dtype=float).reshape(-1, 2)[confirmed]
        out.update({f"map_{k}": v for k, v in map_quality(est, map_truth, radius).items()})
        if alignment is not None:
            R = rotation_matrix(alignment["align_rotation_deg"])
            moved = est @ R.T + np.array([alignment["align_x"], alignment["align_y"]])
            quality = map_quality(moved, map_truth, radius)
            out.update(
                {
                    f"map_{k}_aligned": quality[k]
                    for k in ("n_found", "found_fraction", "n_spurious", "spurious_fraction", "rmse_matched")
                }
            )
    return out


def survey_summary(
    xy: np.ndarray,
    confirmed: np.ndarray,
    true_xy: np.ndarray,
    radius: float,
    ids: np.ndarray | None = None,
    true_ids: np.ndarray | None = None,
) -> dict:
    """A map against surveyed landmarks in a frame of their own (a real log's survey, e.g. MRCLAM's):
    :func:`map_alignment_metrics` over the confirmed landmarks.

    Args:
        xy: ``(L, 2)`` the map's active landmarks.
        confirmed: ``(L,)`` which of them are confirmed (only those are scored).
        true_xy: ``(S, 2)`` the surveyed positions.
        radius: match radius (m): an aligned landmark within it of a surveyed one matches it.
        ids: ``(L,)`` the landmark id each estimate carries (known association), or None.
        true_ids: ``(S,)`` the ids of the surveyed landmarks (default: the row index).

    Returns:
        ``survey_rmse``, ``survey_found``, ``survey_spurious`` (pairs found by position: the
        estimates matched one-to-one to surveyed landmarks after the best rigid alignment; RMSE over
        the matched pairs) and ``survey_landmarks`` (surveyed ones); with ``ids`` also
        ``survey_rmse_by_id``, ``survey_found_by_id``, ``survey_spurious_by_id`` (each estimate
        paired with the surveyed landmark of its id, however far).
    """
    conf = np.asarray(confirmed, bool)
    est = np.asarray(xy, dtype=float).reshape(-1, 2)[conf]
    geo = map_alignment_metrics(est, true_xy, match_radius=radius)
    out = {
        "survey_rmse": geo["rmse"],
        "survey_found": geo["n_found"],
        "survey_spurious": geo["n_spurious"],
        "survey_landmarks": geo["n_true"],
    }
    if ids is not None:
        by_id = map_alignment_metrics(est, true_xy, np.asarray(ids).reshape(-1)[conf], true_ids, match_radius=radius)
        out.update(
            survey_rmse_by_id=by_id["rmse"],
            survey_found_by_id=by_id["n_found"],
            survey_spurious_by_id=by_id["n_spurious"],
        )
    return out


from nanoslam_jax.eval._feature_metrics import (  # noqa: E402
    FeatureGates,
    arc_feature_errors,
    feature_map_errors,
    line_feature_errors,
    line_intersections,
    point_feature_errors,
)
from nanoslam_jax.eval._map_alignment import map_alignment_metrics  # noqa: E402
