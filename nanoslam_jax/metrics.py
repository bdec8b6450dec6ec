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
    "MIN_SCANS_OBSERVABLE",
]

#: Rotation (deg) already applied to the raw GPS in ``gps.dat``: ``R(-33 deg) (Lo + 67, La + 39)``.
GPS_DAT_ROTATION_DEG = -33.0


def rotation_matrix(deg: float) -> np.ndarray:
    """``(2, 2)`` counter-clockwise rotation matrix by ``deg`` degrees."""
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s], [s, c]])


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
    gps_xy: np.ndarray, rotation_deg: float = -35.4, *, source_rotation_deg: float = GPS_DAT_ROTATION_DEG
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


def rigid_align(est: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Best-fit 2-D rigid transform of ``est`` onto ``ref`` (least squares, no scale).

    Minimises ``sum_i |R est_i + t - ref_i|^2`` over rotations ``R`` (det +1: a reflection is
    never returned; Kabsch/Umeyama without scale) and translations ``t``.

    Args:
        est: ``(n, 2)`` points to move.
        ref: ``(n, 2)`` corresponding reference points.

    Returns:
        ``(R, t, aligned)``: ``(2, 2)`` rotation, ``(2,)`` translation and ``(n, 2)``
        ``est @ R.T + t``. With one point, ``R`` is the identity.
    """
    est = np.asarray(est, dtype=float)
    ref = np.asarray(ref, dtype=float)
    if est.shape != ref.shape or est.ndim != 2 or est.shape[1] != 2 or est.shape[0] == 0:
        raise ValueError(f"est and ref must be matching non-empty (n, 2) arrays, got {est.shape} and {ref.shape}")
    mu_e, mu_r = est.mean(axis=0), ref.mean(axis=0)
    if est.shape[0] == 1:
        R = np.eye(2)
    else:
        h = (est - mu_e).T @ (ref - mu_r)  # cross-covariance, (2, 2)
        u, _, vt = np.linalg.svd(h)
        d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
        R = vt.T @ np.diag([1.0, d]) @ u.T
    t = mu_r - R @ mu_e
    return R, t, est @ R.T + t


def jump_mask(gps_t: np.ndarray, gps_xy: np.ndarray, max_speed: float = 8.0) -> np.ndarray:
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


def _rmse(err: np.ndarray) -> float:
    return float(np.sqrt(np.mean(err**2))) if err.size else float("nan")


def error_over_time(
    est_t: np.ndarray,
    est_xy: np.ndarray,
    gps: np.ndarray,
    *,
    rotation_deg: float = -35.4,
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
    rotation_deg: float = -35.4,
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


def map_quality(est_landmarks: np.ndarray, true_landmarks: np.ndarray, radius: float = 1.0) -> dict:
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


def _angle_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.arctan2(R[1, 0], R[0, 0])))


def _pair_transforms(
    est: np.ndarray, tru: np.ndarray, tol: float, max_pairs: int, min_pairs: int = 16, budget: int = 300_000
) -> tuple[np.ndarray, np.ndarray]:
    """Candidate rigid transforms of ``est`` onto ``tru``, each mapping a pair of estimates onto a
    pair of true landmarks of about the same separation (within ``tol``), or with fewer than two
    points on a side, one point onto another (a translation).

    The pairs of estimates are taken in a fixed pseudo-random order, at most ``max_pairs`` of them,
    and fewer (but at least ``min_pairs``) when they would give more than ``budget`` candidates:
    with a mostly correct map most pairs give the right transform.

    Returns:
        ``(theta, t)``: ``(C,)`` rotation angles and ``(C, 2)`` translations.
    """
    E, L = est.shape[0], tru.shape[0]
    if E < 2 or L < 2:
        i, k = np.divmod(np.arange(E * L), L)
        return np.zeros(E * L), tru[k] - est[i]
    i, j = np.triu_indices(E, 1)
    order = np.random.default_rng(0).permutation(i.size)[:max_pairs]
    i, j = i[order], j[order]
    k, m = np.nonzero(~np.eye(L, dtype=bool))  # ordered pairs of true landmarks
    de, dt = est[j] - est[i], tru[m] - tru[k]
    close = np.abs(np.hypot(*de.T)[:, None] - np.hypot(*dt.T)[None, :]) <= tol
    used = np.searchsorted(np.cumsum(close.sum(axis=1)), budget, side="right")
    a, b = np.nonzero(close[: max(min_pairs, used)])
    theta = np.arctan2(dt[b, 1], dt[b, 0]) - np.arctan2(de[a, 1], de[a, 0])
    c, s = np.cos(theta), np.sin(theta)
    mid_e, mid_t = 0.5 * (est[i[a]] + est[j[a]]), 0.5 * (tru[k[b]] + tru[m[b]])
    t = mid_t - np.stack([c * mid_e[:, 0] - s * mid_e[:, 1], s * mid_e[:, 0] + c * mid_e[:, 1]], axis=1)
    return theta, t


def _score_transforms(
    est: np.ndarray, tree, theta: np.ndarray, t: np.ndarray, radius: float, chunk: int = 500_000
) -> tuple[np.ndarray, np.ndarray]:
    """Per candidate transform: how many moved estimates lie within ``radius`` of a true landmark
    (``tree``: a ``scipy.spatial.cKDTree`` of them), and the sum over the estimates of
    ``min(d^2, radius^2)`` (``d`` the distance to the nearest)."""
    n_in, cost = np.zeros(theta.size, dtype=np.int64), np.zeros(theta.size)
    step = max(1, chunk // max(1, est.shape[0]))
    for lo in range(0, theta.size, step):
        c, s, tt = np.cos(theta[lo : lo + step]), np.sin(theta[lo : lo + step]), t[lo : lo + step]
        x = c[:, None] * est[None, :, 0] - s[:, None] * est[None, :, 1] + tt[:, 0:1]
        y = s[:, None] * est[None, :, 0] + c[:, None] * est[None, :, 1] + tt[:, 1:2]
        d, _ = tree.query(np.stack([x, y], axis=-1), distance_upper_bound=radius)
        n_in[lo : lo + step] = np.isfinite(d).sum(axis=1)
        cost[lo : lo + step] = np.minimum(d, radius).__pow__(2).sum(axis=1)
    return n_in, cost


def _first_alignments(
    est: np.ndarray,
    tru: np.ndarray,
    radius: float,
    max_pairs: int,
    keep: int = 10,
    probe: int = 12,
    shortlist: int = 100,
) -> list[tuple[np.ndarray, np.ndarray]]:
    """The ``keep`` best candidate alignments ``(R, t)`` of :func:`_pair_transforms`: scored on
    ``probe`` of the estimates first, then the ``shortlist`` best on all of them (most estimates
    within ``radius`` of a true landmark, then the smallest truncated squared distance)."""
    from scipy.spatial import cKDTree

    tree = cKDTree(tru)
    theta, t = _pair_transforms(est, tru, 2.0 * radius, max_pairs)
    if est.shape[0] > probe:
        sub = est[np.random.default_rng(1).permutation(est.shape[0])[:probe]]
        n_in, cost = _score_transforms(sub, tree, theta, t, radius)
        top = np.lexsort((cost, -n_in))[:shortlist]
        theta, t = theta[top], t[top]
    n_in, cost = _score_transforms(est, tree, theta, t, radius)
    return [(rotation_matrix(math.degrees(theta[c])), t[c]) for c in np.lexsort((cost, -n_in))[:keep]]


def _assign(aligned: np.ndarray, tru: np.ndarray, radius: float) -> np.ndarray:
    """One-to-one pairs ``(est index, true index)`` within ``radius``: the assignment minimising
    the sum of ``min(d^2, radius^2)`` (scipy's ``linear_sum_assignment``), pairs beyond ``radius``
    dropped."""
    from scipy.optimize import linear_sum_assignment

    d2 = np.sum((aligned[:, None, :] - tru[None, :, :]) ** 2, axis=-1)
    rows, cols = linear_sum_assignment(np.minimum(d2, radius**2))
    keep = d2[rows, cols] <= radius**2
    return np.stack([rows[keep], cols[keep]], axis=1)


def map_alignment_metrics(
    est_xy: np.ndarray,
    true_xy: np.ndarray,
    est_ids: np.ndarray | None = None,
    true_ids: np.ndarray | None = None,
    match_radius: float = 0.5,
    *,
    max_iter: int = 50,
    max_pairs: int = 400,
) -> dict:
    """A map against surveyed landmarks in another frame: its RMSE after the best rigid alignment
    (rotation and translation, no scale; least squares, :func:`rigid_align`), the landmarks it
    found and its spurious ones.

    * **With ids** (``est_ids`` given): each estimate is paired with the true landmark of its id;
      the alignment is the least-squares fit over all pairs and ``rmse`` the RMS distance over all
      of them (however far). A true landmark is found when an estimate of its id lies within
      ``match_radius`` of it after the alignment; an estimate is spurious when it does not lie
      within ``match_radius`` of the true landmark of its id (or its id is none of ``true_ids``,
      e.g. -1).
    * **Without ids**: the pairs are found too. A first alignment is chosen robustly among the
      transforms that map a pair of estimates onto a pair of true landmarks of about the same
      separation (within ``2 match_radius``; from a fixed pseudo-random subset of the pairs of
      estimates, at most ``max_pairs`` and fewer for a large map): the one that brings the most
      estimates within ``match_radius`` of a true landmark (then the smallest truncated squared
      distance; a large map's candidates are shortlisted on 12 of its estimates). From the best ten,
      one-to-one assignment within ``match_radius`` (Hungarian, ``scipy.optimize.
      linear_sum_assignment``) and the least-squares alignment of the assigned pairs alternate
      until the pairs no longer change; the result with the most pairs (then the smallest squared
      error) is kept. ``rmse`` is over the assigned pairs, found landmarks are the assigned true
      ones, spurious estimates the unassigned ones.

    With one pair the alignment is a translation (``rmse`` 0); with none it is the identity and
    ``rmse`` NaN.

    Args:
        est_xy: ``(E, 2)`` the estimated landmark positions (in the map's own frame).
        true_xy: ``(L, 2)`` the surveyed positions.
        est_ids: ``(E,)`` the landmark id of each estimate (-1: unknown), or None: pair by position.
        true_ids: ``(L,)`` the id of each true landmark, distinct (default: the row index).
        match_radius: an aligned estimate within this distance (m) of a true landmark matches it.
        max_iter: at most this many assignment-alignment rounds (without ids).
        max_pairs: at most this many pairs of estimates seed the first alignment (without ids).

    Returns:
        A dict: ``rmse``; ``n_est``, ``n_true``, ``n_pairs`` (pairs in the alignment), ``n_found``,
        ``found_fraction``, ``n_spurious``; the alignment ``p -> R(align_rotation_deg) p +
        (align_x, align_y)`` (estimate frame onto the surveyed one) and as arrays ``rotation``
        ``(2, 2)`` and ``translation`` ``(2,)``; ``aligned`` ``(E, 2)`` the moved estimates,
        ``pairs`` ``(n_pairs, 2)`` the (estimate row, true row) pairs and ``pair_errors`` their
        distances after the alignment.

    Raises:
        ValueError: on bad shapes, ``true_ids`` without ``est_ids``, repeated ``true_ids`` or a
            ``match_radius`` <= 0.
    """
    est = np.asarray(est_xy, dtype=float).reshape(-1, 2) if np.size(est_xy) else np.zeros((0, 2))
    tru = np.asarray(true_xy, dtype=float).reshape(-1, 2) if np.size(true_xy) else np.zeros((0, 2))
    E, L = est.shape[0], tru.shape[0]
    if not match_radius > 0:
        raise ValueError(f"match_radius: expected a distance > 0, got {match_radius}")
    if est_ids is None and true_ids is not None:
        raise ValueError("true_ids given without est_ids: pass the estimates' ids too, or neither")
    R, shift = np.eye(2), np.zeros(2)
    if est_ids is not None:
        est_ids = np.asarray(est_ids).reshape(-1).astype(np.int64)
        true_ids = np.arange(L) if true_ids is None else np.asarray(true_ids).reshape(-1).astype(np.int64)
        if est_ids.shape[0] != E or true_ids.shape[0] != L:
            raise ValueError(
                f"est_ids must have E = {E} and true_ids L = {L} entries, got {est_ids.shape[0]} "
                f"and {true_ids.shape[0]}"
            )
        if np.unique(true_ids).size != L:
            raise ValueError("true_ids: expected distinct ids")
        row_of = {int(k): r for r, k in enumerate(true_ids.tolist())}
        rows = np.array([row_of.get(int(k), -1) for k in est_ids.tolist()], dtype=np.int64)
        pairs = np.stack([np.flatnonzero(rows >= 0), rows[rows >= 0]], axis=1)
        if pairs.shape[0]:
            R, shift, _ = rigid_align(est[pairs[:, 0]], tru[pairs[:, 1]])
    elif E and L:
        best = None
        for Rc, tc in _first_alignments(est, tru, match_radius, max_pairs):
            pc = None
            for _ in range(max_iter):
                p = _assign(est @ Rc.T + tc, tru, match_radius)
                if p.shape[0] == 0 or (pc is not None and np.array_equal(p, pc)):
                    break
                pc = p
                Rc, tc, _ = rigid_align(est[p[:, 0]], tru[p[:, 1]])
            if pc is None:
                continue
            sse = float(np.sum((est[pc[:, 0]] @ Rc.T + tc - tru[pc[:, 1]]) ** 2))
            if best is None or (pc.shape[0], -sse) > (best[0].shape[0], -best[3]):
                best = (pc, Rc, tc, sse)
        pairs = np.zeros((0, 2), dtype=np.int64) if best is None else best[0]
        if best is not None:
            R, shift = best[1], best[2]
    else:
        pairs = np.zeros((0, 2), dtype=np.int64)
    aligned = est @ R.T + shift
    err = np.hypot(*(aligned[pairs[:, 0]] - tru[pairs[:, 1]]).T) if pairs.shape[0] else np.zeros(0)
    close = pairs[err <= match_radius]
    n_found = int(np.unique(close[:, 1]).size)
    return {
        "rmse": _rmse(err),
        "n_est": E,
        "n_true": L,
        "n_pairs": int(pairs.shape[0]),
        "n_found": n_found,
        "found_fraction": n_found / L if L else float("nan"),
        "n_spurious": E - int(np.unique(close[:, 0]).size),
        "align_rotation_deg": _angle_deg(R),
        "align_x": float(shift[0]),
        "align_y": float(shift[1]),
        "rotation": R,
        "translation": shift,
        "aligned": aligned,
        "pairs": pairs,
        "pair_errors": err,
    }


# ---------------------------------------------------------------------------------------------
# Line and arc maps (the second paper's Table 1)


def _lines_np(lines: np.ndarray) -> np.ndarray:
    """``(n, 2)`` lines ``(rho, alpha)`` in normal form, normalised: ``rho >= 0``, ``alpha`` in (-pi, pi]."""
    a = np.asarray(lines, dtype=float).reshape(-1, 2) if np.size(lines) else np.zeros((0, 2))
    flip = a[:, 0] < 0
    alpha = np.where(flip, a[:, 1] + np.pi, a[:, 1])
    alpha = np.mod(alpha + np.pi, 2.0 * np.pi) - np.pi
    return np.stack([np.abs(a[:, 0]), np.where(alpha <= -np.pi, alpha + 2.0 * np.pi, alpha)], axis=1)


def _wrap_np(a: np.ndarray) -> np.ndarray:
    return np.mod(np.asarray(a) + np.pi, 2.0 * np.pi) - np.pi


def _oriented_differences(est: np.ndarray, tru: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(E, L)`` differences ``(rho_e - rho_t, alpha_e - alpha_t)`` of every estimated line from every
    true one, each estimate written in the orientation of its normal nearer the true line's
    (``(rho, alpha)`` or ``(-rho, alpha + pi)``, the same line)."""
    d_alpha = _wrap_np(est[:, None, 1] - tru[None, :, 1])
    flip = np.abs(d_alpha) > np.pi / 2
    d_rho = np.where(flip, -est[:, None, 0], est[:, None, 0]) - tru[None, :, 0]
    return d_rho, np.where(flip, _wrap_np(d_alpha + np.pi), d_alpha)


def _hungarian(cost: np.ndarray, gate: float) -> np.ndarray:
    """``(L,)`` the estimate row assigned to each column (-1: none): the one-to-one assignment
    minimising the sum of ``min(cost, gate)``, pairs with ``cost > gate`` dropped."""
    from scipy.optimize import linear_sum_assignment

    match = np.full(cost.shape[1], -1, dtype=np.int64)
    if cost.size:
        rows, cols = linear_sum_assignment(np.minimum(cost, gate))
        keep = cost[rows, cols] <= gate
        match[cols[keep]] = rows[keep]
    return match


def _paper_form(lines: np.ndarray, steep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Slope and intercept of lines in normal form: ``y = a x + b`` (``a = -cos/sin``, ``b = rho/sin``),
    or where ``steep``, ``x = a' y + c`` (``a' = -sin/cos``, ``c = rho/cos``)."""
    c, s = np.cos(lines[:, 1]), np.sin(lines[:, 1])
    den = np.where(steep, c, s)
    num = np.where(steep, s, c)
    with np.errstate(divide="ignore", invalid="ignore"):
        return -num / den, lines[:, 0] / den


def line_feature_errors(
    est_lines: np.ndarray, true_lines: np.ndarray, gate: float = 0.5, lever: float = 1.0, max_slope: float = 1.0
) -> dict:
    """Errors of estimated lines against true ones, all in normal form ``(rho, alpha)`` in the same frame.

    **Matching**: one-to-one (Hungarian, ``scipy.optimize.linear_sum_assignment``) minimising the
    sum of ``|rho_e - rho_t| + lever |alpha_e - alpha_t|`` (each estimate in the orientation of its
    normal nearer the true line's; ``lever`` in m per rad turns an angle error into a distance),
    pairs costing more than ``gate`` left unmatched.

    **Errors** of each matched true line, estimate minus truth: ``rho`` and ``alpha`` (wrapped);
    and in the second paper's form (its Table 1): ``y = a x + b`` for a line with ``|a| <=
    max_slope``, else ``x = a' y + c`` (the paper's vertical form ``x = c``, eq. 15, with a slope
    about the y axis so that a nearly vertical line has bounded parameters; the paper's vertical
    walls have ``a' = 0``): ``slope`` (``a`` or ``a'``) and ``intercept`` (``b`` or ``c``, m). The
    form is the true line's, and the estimate is written in the same form.

    Args:
        est_lines: ``(E, 2)`` estimated lines.
        true_lines: ``(L, 2)`` true lines.
        gate: the largest matching cost (m).
        lever: the weight of the angle in the matching cost (m per rad).
        max_slope: true lines steeper than this take the form ``x = a' y + c``.

    Returns:
        A dict of ``(L,)`` arrays per true line (NaN where unmatched): ``match`` (the estimate's
        row, -1 where unmatched), ``rho_error``, ``alpha_error``, ``slope_error``,
        ``intercept_error``, ``steep`` (the form ``x = a' y + c``); and ``n_est``, ``n_true``,
        ``n_matched``.
    """
    est, tru = _lines_np(est_lines), _lines_np(true_lines)
    d_rho, d_alpha = _oriented_differences(est, tru)
    match = _hungarian(np.abs(d_rho) + lever * np.abs(d_alpha), gate)
    ok = match >= 0
    n = tru.shape[0]
    rho_err, alpha_err = np.full(n, np.nan), np.full(n, np.nan)
    cols = np.flatnonzero(ok)
    rho_err[cols], alpha_err[cols] = d_rho[match[cols], cols], d_alpha[match[cols], cols]
    steep = np.abs(np.cos(tru[:, 1])) > max_slope * np.abs(np.sin(tru[:, 1]))
    slope_t, icpt_t = _paper_form(tru, steep)
    slope_err, icpt_err = np.full(n, np.nan), np.full(n, np.nan)
    if cols.size:
        # the matched estimate in the true line's orientation: (rho_t + d_rho, alpha_t + d_alpha)
        est_oriented = np.stack([tru[cols, 0] + rho_err[cols], tru[cols, 1] + alpha_err[cols]], axis=1)
        slope_e, icpt_e = _paper_form(est_oriented, steep[cols])
        slope_err[cols], icpt_err[cols] = slope_e - slope_t[cols], icpt_e - icpt_t[cols]
    return {
        "match": match,
        "rho_error": rho_err,
        "alpha_error": alpha_err,
        "slope_error": slope_err,
        "intercept_error": icpt_err,
        "steep": steep,
        "n_est": int(est.shape[0]),
        "n_true": int(n),
        "n_matched": int(ok.sum()),
    }


def arc_feature_errors(est_arcs: np.ndarray, true_arcs: np.ndarray, gate: float = 0.5) -> dict:
    """Errors of estimated arcs (circles) against true ones, ``(xc, yc, R)`` in the same frame.

    **Matching**: one-to-one (Hungarian) minimising the sum of the centre distances, pairs farther
    apart than ``gate`` left unmatched.

    Args:
        est_arcs: ``(E, 3)`` estimated circles.
        true_arcs: ``(L, 3)`` true circles.
        gate: the largest centre distance of a match (m).

    Returns:
        A dict of ``(L,)`` arrays per true arc (NaN where unmatched): ``match`` (-1 where
        unmatched), ``centre_error`` (distance, m), ``radius_error`` (estimate minus truth, m); and
        ``n_est``, ``n_true``, ``n_matched``.
    """
    est = np.asarray(est_arcs, dtype=float).reshape(-1, 3) if np.size(est_arcs) else np.zeros((0, 3))
    tru = np.asarray(true_arcs, dtype=float).reshape(-1, 3) if np.size(true_arcs) else np.zeros((0, 3))
    d = np.hypot(est[:, None, 0] - tru[None, :, 0], est[:, None, 1] - tru[None, :, 1])
    match = _hungarian(d, gate)
    cols = np.flatnonzero(match >= 0)
    centre, radius = np.full(tru.shape[0], np.nan), np.full(tru.shape[0], np.nan)
    centre[cols] = d[match[cols], cols]
    radius[cols] = est[match[cols], 2] - tru[cols, 2]
    return {
        "match": match,
        "centre_error": centre,
        "radius_error": radius,
        "n_est": int(est.shape[0]),
        "n_true": int(tru.shape[0]),
        "n_matched": int(cols.size),
    }


def point_feature_errors(est_points: np.ndarray, true_points: np.ndarray, gate: float = 0.2) -> dict:
    """Errors of estimated point features (break points, corners) against true ones.

    **Matching**: one-to-one (Hungarian) minimising the sum of the distances, pairs farther apart
    than ``gate`` left unmatched.

    Args:
        est_points: ``(E, 2)`` estimated points.
        true_points: ``(L, 2)`` true points.
        gate: the largest distance of a match (m).

    Returns:
        A dict: ``match`` ``(L,)`` (-1 where unmatched), ``error`` ``(L,)`` the distance (m; NaN
        where unmatched), ``n_est``, ``n_true``, ``n_matched``.
    """
    est = np.asarray(est_points, dtype=float).reshape(-1, 2) if np.size(est_points) else np.zeros((0, 2))
    tru = np.asarray(true_points, dtype=float).reshape(-1, 2) if np.size(true_points) else np.zeros((0, 2))
    d = np.hypot(est[:, None, 0] - tru[None, :, 0], est[:, None, 1] - tru[None, :, 1])
    match = _hungarian(d, gate)
    cols = np.flatnonzero(match >= 0)
    err = np.full(tru.shape[0], np.nan)
    err[cols] = d[match[cols], cols]
    return {
        "match": match,
        "error": err,
        "n_est": int(est.shape[0]),
        "n_true": int(tru.shape[0]),
        "n_matched": int(cols.size),
    }


def line_intersections(lines_a: np.ndarray, lines_b: np.ndarray) -> np.ndarray:
    """``(K, 2)`` the intersection of each pair of lines in normal form (NaN where parallel).

    Args:
        lines_a: ``(K, 2)`` lines ``(rho, alpha)``.
        lines_b: ``(K, 2)`` the lines they meet.
    """
    a = np.asarray(lines_a, dtype=float).reshape(-1, 2)
    b = np.asarray(lines_b, dtype=float).reshape(-1, 2)
    det = np.sin(b[:, 1] - a[:, 1])
    ok = np.abs(det) > 1e-12
    det = np.where(ok, det, 1.0)
    x = (a[:, 0] * np.sin(b[:, 1]) - b[:, 0] * np.sin(a[:, 1])) / det
    y = (b[:, 0] * np.cos(a[:, 1]) - a[:, 0] * np.cos(b[:, 1])) / det
    return np.where(ok[:, None], np.stack([x, y], axis=1), np.nan)


def _summary(errors: np.ndarray) -> tuple[float, float]:
    e = np.abs(np.asarray(errors, dtype=float))
    e = e[np.isfinite(e)]
    return (float(np.median(e)), float(e.max())) if e.size else (float("nan"), float("nan"))


def feature_map_errors(
    est_lines: np.ndarray,
    true_lines: np.ndarray,
    *,
    est_arcs: np.ndarray | None = None,
    true_arcs: np.ndarray | None = None,
    corners: np.ndarray | None = None,
    est_break_points: np.ndarray | None = None,
    true_break_points: np.ndarray | None = None,
    line_gate: float = 0.5,
    lever: float = 1.0,
    max_slope: float = 1.0,
    arc_gate: float = 0.5,
    point_gate: float = 0.2,
) -> dict:
    """The second paper's Table 1 for a map of lines (and arcs): line slope and intercept errors, arc
    centre and radius errors, corner and break point position errors, with a summary.

    Lines are matched by :func:`line_feature_errors`, arcs by :func:`arc_feature_errors`. A corner
    is where two true lines meet (``corners`` names them); its estimate is where their matched
    estimated lines meet (:func:`line_intersections`), so a corner error is the map's error where
    the walls meet, and a corner of an unmatched line has none. Break points (a wall's end at a
    range discontinuity) are points: the estimated ones (e.g. the ends of the estimated walls'
    segments) are matched to the true ones by :func:`point_feature_errors`.

    Args:
        est_lines: ``(E, 2)`` estimated lines ``(rho, alpha)``.
        true_lines: ``(L, 2)`` true lines.
        est_arcs: ``(A', 3)`` estimated arcs ``(xc, yc, R)``, or None.
        true_arcs: ``(A, 3)`` true arcs, or None.
        corners: ``(K, 2)`` rows of indices into ``true_lines`` of the two lines meeting at each
            corner, or None.
        est_break_points: ``(B', 2)`` estimated break points, or None.
        true_break_points: ``(B, 2)`` true break points, or None.
        line_gate, lever, max_slope: see :func:`line_feature_errors`.
        arc_gate: see :func:`arc_feature_errors`.
        point_gate: see :func:`point_feature_errors` (break points).

    Returns:
        A dict: ``lines`` (:func:`line_feature_errors`), ``arcs`` (:func:`arc_feature_errors`, or
        None), ``corners`` (``error`` ``(K,)`` distances, NaN where a line is unmatched or the
        lines are parallel; ``true`` and ``estimate`` ``(K, 2)``; or None), ``break_points``
        (:func:`point_feature_errors`, or None), and ``summary``: for each of ``line_slope``,
        ``line_intercept``, ``line_rho``, ``line_alpha``, ``arc_centre``, ``arc_radius``,
        ``corner``, ``break_point`` the median and the worst absolute error over the matched
        features (``<name>_median``, ``<name>_worst``; NaN when there are none) and the counts
        ``n_<kind>`` and ``n_<kind>_matched``. Unmatched features enter the counts only.

    Raises:
        ValueError: when ``corners`` names a line that ``true_lines`` does not hold.
    """
    lines = line_feature_errors(est_lines, true_lines, line_gate, lever, max_slope)
    summary: dict = {"n_lines": lines["n_true"], "n_lines_matched": lines["n_matched"]}
    for name, key in (
        ("line_slope", "slope_error"),
        ("line_intercept", "intercept_error"),
        ("line_rho", "rho_error"),
        ("line_alpha", "alpha_error"),
    ):
        summary[f"{name}_median"], summary[f"{name}_worst"] = _summary(lines[key])
    arcs = None
    if true_arcs is not None:
        arcs = arc_feature_errors(np.zeros((0, 3)) if est_arcs is None else est_arcs, true_arcs, arc_gate)
        summary["n_arcs"], summary["n_arcs_matched"] = arcs["n_true"], arcs["n_matched"]
        for name, key in (("arc_centre", "centre_error"), ("arc_radius", "radius_error")):
            summary[f"{name}_median"], summary[f"{name}_worst"] = _summary(arcs[key])
    corner = None
    if corners is not None:
        pairs = np.asarray(corners, dtype=np.int64).reshape(-1, 2)
        n_true = lines["n_true"]
        if pairs.size and (pairs.min() < 0 or pairs.max() >= n_true):
            raise ValueError(
                f"corners: expected indices into the {n_true} true lines, got {pairs.min()}..{pairs.max()}"
            )
        tru = _lines_np(true_lines)
        est = _lines_np(est_lines)
        true_xy = line_intersections(tru[pairs[:, 0]], tru[pairs[:, 1]])
        m = lines["match"][pairs]
        ok = np.all(m >= 0, axis=1)
        est_xy = np.full_like(true_xy, np.nan)
        if ok.any():
            est_xy[ok] = line_intersections(est[m[ok, 0]], est[m[ok, 1]])
        err = np.hypot(*(est_xy - true_xy).T)
        corner = {"error": err, "true": true_xy, "estimate": est_xy}
        summary["n_corners"], summary["n_corners_matched"] = int(pairs.shape[0]), int(np.isfinite(err).sum())
        summary["corner_median"], summary["corner_worst"] = _summary(err)
    breaks = None
    if true_break_points is not None:
        breaks = point_feature_errors(
            np.zeros((0, 2)) if est_break_points is None else est_break_points, true_break_points, point_gate
        )
        summary["n_break_points"], summary["n_break_points_matched"] = breaks["n_true"], breaks["n_matched"]
        summary["break_point_median"], summary["break_point_worst"] = _summary(breaks["error"])
    return {"lines": lines, "arcs": arcs, "corners": corner, "break_points": breaks, "summary": summary}


# The scoring of a whole run and the summary over seeds under the failed-seed rule: the one scorer of
# every command (run, compare, sweep, study), in nanoslam_jax._scoring (which builds on this module,
# hence loaded on first use).
_SCORING = ("MapEstimate", "metric_goal", "score_run", "seed_summary", "summarize_runs")
__all__ += list(_SCORING)


def __getattr__(name: str):
    if name in _SCORING:
        from . import _scoring

        return getattr(_scoring, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
