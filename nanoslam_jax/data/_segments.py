"""Cutting a log into fixed-shape segments, one per laser scan (docs/method/victoria-park.md, "Time and segments").

The SLAM frame starts at the first DR sample time ``t0`` with pose ``(0, 0, 0)``. DR sample
``i`` holds its controls over ``[t_i, t_{i+1})`` (the last one until the end of the log). The
segment of a scan at time ``s`` holds the pieces of those intervals between the previous
segment's time and ``s``, so the prediction lands exactly on the scan time. Gaps needing more
than ``max_dr_per_segment`` pieces are split by extra segments without detections, ending at
intermediate DR sample times. Everything is built with ``searchsorted`` and gathers.
"""

from __future__ import annotations

from typing import Any, Optional

import numpy as np
from jaxtyping import Bool, Float, Int

from nanoslam_jax.data._types import RawLog, Segments

__all__ = ["make_segments", "segment_summary"]


def _check_inputs(
    raw: RawLog, min_range: float, max_range: float, k_max: Optional[int], max_dr_per_segment: int
) -> None:
    """Raise ``ValueError`` on arguments or a log that :func:`make_segments` cannot cut."""
    if not min_range < max_range:
        raise ValueError(f"data.min_range ({min_range}) must be below data.max_range ({max_range})")
    if k_max is not None and k_max < 1:
        raise ValueError(f"data.k_max must be >= 1 or None, got {k_max}")
    if max_dr_per_segment < 1:
        raise ValueError(f"data.max_dr_per_segment must be >= 1, got {max_dr_per_segment}")
    if np.ndim(raw.dr) != 2 or np.shape(raw.dr)[1] < 1:
        raise ValueError(
            f"log {raw.source!r}: dead-reckoning rows must be (time, controls...), got shape {np.shape(raw.dr)}"
        )
    t = raw.dr[:, 0]
    if t.size == 0:
        raise ValueError(f"log {raw.source!r} has no dead-reckoning samples")
    if np.any(np.diff(t) <= 0):
        raise ValueError(f"log {raw.source!r}: dead-reckoning times must be strictly increasing")


def _segment_layout(
    t: Float[np.ndarray, " n_dr"], scan_times: Float[np.ndarray, " scans"], max_pieces: int
) -> dict[str, np.ndarray]:
    """Where each output segment starts and ends and which DR samples it integrates.

    Args:
        t: DR sample times, strictly increasing.
        scan_times: distinct scan times, increasing.
        max_pieces: the most DR pieces a segment may hold.

    Returns:
        Per output segment: ``scan`` (index of the scan it belongs to), ``is_scan`` (it is
        the scan's own segment, the last of its chunks), ``time``, ``lo`` / ``hi`` (the
        integration interval, clipped to ``t0``), ``first`` (index of its first DR sample)
        and ``count`` (number of pieces).
    """
    t0 = t[0]
    hi_scan = np.maximum(scan_times, t0)
    lo_scan = np.concatenate([[t0], hi_scan[:-1]])
    first_scan = np.searchsorted(t, lo_scan, side="right") - 1  # t[i] <= lo < t[i + 1]
    last_scan = np.searchsorted(t, hi_scan, side="left") - 1  # last i with t[i] < hi
    pieces = np.where(hi_scan > lo_scan, last_scan - first_scan + 1, 0)
    chunks = np.maximum(1, -(-pieces // max_pieces))

    scan = np.repeat(np.arange(scan_times.size), chunks)
    chunk = np.arange(scan.size) - (np.cumsum(chunks) - chunks)[scan]
    is_scan = chunk == chunks[scan] - 1
    first = first_scan[scan] + chunk * max_pieces
    count = np.where(is_scan, pieces[scan] - chunk * max_pieces, max_pieces)
    # An extra segment ends at the DR sample after its last piece (which exists); the index is
    # clipped only for the scans' own segments, where the value is not used.
    split_time = t[np.minimum(first + max_pieces, t.size - 1)]
    lo = np.where(chunk == 0, lo_scan[scan], t[first])
    hi = np.where(is_scan, hi_scan[scan], split_time)
    time = np.where(is_scan, scan_times[scan], split_time)
    return dict(scan=scan, is_scan=is_scan, time=time, lo=lo, hi=hi, first=first, count=count)


def _dr_pieces(
    dr: Float[np.ndarray, "n_dr cols"], layout: dict[str, np.ndarray], max_pieces: int
) -> tuple[Float[np.ndarray, "segments dr"], Float[np.ndarray, "segments dr c"], Bool[np.ndarray, "segments dr"]]:
    """The padded DR pieces ``(dt, u, dr_mask)`` of every segment (``u``: the rows' columns after
    the time, as many as the log has).

    Args:
        dr: ``time, u...`` rows (``time, ve, alpha`` for the car), strictly increasing time.
        layout: the output of :func:`_segment_layout`.
        max_pieces: padded number of pieces per segment.
    """
    t = dr[:, 0]
    t_next = np.append(t[1:], np.inf)  # the last sample holds until the end
    k = np.arange(max_pieces)
    mask = k < layout["count"][:, None]
    idx = np.minimum(layout["first"][:, None] + k, t.size - 1)
    dt = np.minimum(t_next[idx], layout["hi"][:, None]) - np.maximum(t[idx], layout["lo"][:, None])
    dt = np.where(mask, dt, 0.0)
    u = np.where(mask[..., None], dr[idx, 1:], 0.0)
    return dt, u, mask


def _detections(
    ranges_bearings: Float[np.ndarray, "m c"],
    scan_of_det: Int[np.ndarray, " m"],
    scan_times: Float[np.ndarray, " scans"],
    segment_of_scan: Int[np.ndarray, " scans"],
    n_segments: int,
    k_max: Optional[int],
    range_rule: str,
    measurement_dim: int = 2,
) -> tuple[
    Float[np.ndarray, "segments k_max d"],
    Bool[np.ndarray, "segments k_max"],
    Float[np.ndarray, "segments k_max"],
    Int[np.ndarray, "segments k_max"],
    Float[np.ndarray, "segments k_max e"],
]:
    """The padded detections ``(z, z_mask, diam, z_id, extra)`` of every segment, file order kept
    within a scan (``extra``: the rows' columns after the id; padding 0).

    Args:
        ranges_bearings: kept detections ``(z, diameter, landmark id or -1)``, ``z`` of
            ``measurement_dim`` values (range and bearing for range-bearing).
        scan_of_det: index of each kept detection's scan.
        scan_times: distinct scan times (for messages).
        segment_of_scan: index of each scan's own segment.
        n_segments: number of output segments.
        k_max: padded detections per segment; ``None``: the most in any scan (at least 1).
        range_rule: the range filter in words (for messages).
        measurement_dim: the values of a detection.

    Raises:
        ValueError: a scan has more than an explicit ``k_max`` kept detections.
    """
    counts = np.bincount(scan_of_det, minlength=scan_times.size)
    most = int(counts.max(initial=0))
    if k_max is None:
        k_max = max(most, 1)
    elif most > k_max:
        worst = int(np.argmax(counts > k_max))
        raise ValueError(
            f"data.k_max={k_max} is too small: the scan at t={scan_times[worst]:.3f} s has {counts[worst]} "
            f"detections with {range_rule} (the most in any scan is {most}); raise data.k_max to at "
            f"least {most} or set it to null"
        )
    order = np.argsort(scan_of_det, kind="stable")
    scans = scan_of_det[order]
    slot = np.arange(scans.size) - (np.cumsum(counts) - counts)[scans]
    z = np.zeros((n_segments, k_max, ranges_bearings.shape[1]))
    z_mask = np.zeros((n_segments, k_max), dtype=bool)
    z[segment_of_scan[scans], slot] = ranges_bearings[order]
    z_mask[segment_of_scan[scans], slot] = True
    d = measurement_dim
    return z[..., :d], z_mask, z[..., d], np.where(z_mask, z[..., d + 1], -1).astype(np.int32), z[..., d + 2 :]


def make_segments(
    raw: RawLog,
    *,
    min_range: float = 0.0,
    max_range: float = 30.0,
    k_max: Optional[int] = None,
    max_dr_per_segment: int = 12,
    t_end: Optional[float] = None,
    measurement_dim: int = 2,
) -> Segments:
    """Cut a log into fixed-shape segments, one per laser scan (plus splits of long gaps).

    Every distinct detection time is a scan and gets a segment, even when the range filter
    leaves it no detections (``z_mask`` all False). Scans before the first DR sample get
    segments without DR pieces (the pose stays at the origin). A gap needing more than
    ``max_dr_per_segment`` pieces is split by extra segments without detections whose ``time``
    is the intermediate DR sample time they end at. Time is conserved: the pieces of segment
    ``t`` sum to ``max(time[t], t0) - max(time[t - 1], t0)`` (``t0`` before the first).

    Args:
        raw: the log (bearings in the vehicle frame).
        min_range: detections with range below this are dropped (m).
        max_range: detections with range at or above this are dropped (m).
        k_max: detections per segment (padding); ``None``: the most in any scan after the
            range filter (at least 1). Never truncates: a scan with more raises.
        max_dr_per_segment: DR pieces per segment (padding and split threshold).
        t_end: keep only scans at or before this time (s); ``None``: the whole log.
        measurement_dim: the values of a detection (the measurement model's ``measurement_dim``):
            the log's detection rows are ``time``, the detection's ``measurement_dim`` values
            (the first its range, which the range filter reads) and a last one (a tree's
            diameter).

    Returns:
        :class:`Segments` of numpy arrays: ``time (S,)``, ``dt (S, D)``, ``u (S, D, C)`` (``C``
        the DR rows' columns after the time: 2 for ``(ve, alpha)`` or ``(v, omega)``, 3 for the
        odometry model's ``(vx, vy, omega)``),
        ``dr_mask (S, D)``, ``z (S, K, measurement_dim)``, ``z_mask (S, K)``, ``diam (S, K)``, ``is_scan (S,)``, ``z_id (S, K)`` (-1: unknown), ``z_kind (S, K)`` (0 for one type) with ``D = max_dr_per_segment``
        and ``K = k_max``; padding is zero with the mask False.

    Raises:
        ValueError: bad arguments, no DR samples or DR times not strictly increasing, no scan
            up to ``t_end``, or a scan with more than ``k_max`` kept detections (the message
            names ``data.k_max``, the scan time and the count).
    """
    _check_inputs(raw, min_range, max_range, k_max, max_dr_per_segment)
    det = raw.detections
    if det.ndim != 2 or det.shape[1] != measurement_dim + 2:
        raise ValueError(
            f"log {raw.source!r}: detections of {measurement_dim} values need rows of {measurement_dim + 2} "
            f"columns (time, the detection, a diameter or length), got shape {det.shape}"
        )
    if t_end is not None:
        det = det[det[:, 0] <= t_end]
    if det.shape[0] == 0:
        cut = "" if t_end is None else f" up to t_end={t_end}"
        raise ValueError(f"log {raw.source!r} has no laser scan{cut}")
    scan_times, scan_of_det = np.unique(det[:, 0], return_inverse=True)

    layout = _segment_layout(raw.dr[:, 0], scan_times, max_dr_per_segment)
    dt, u, dr_mask = _dr_pieces(raw.dr, layout, max_dr_per_segment)
    keep = (det[:, 1] >= min_range) & (det[:, 1] < max_range)
    ids = np.full(raw.detections.shape[0], -1.0) if raw.detection_ids is None else np.asarray(raw.detection_ids, float)
    kinds = None if raw.detection_kinds is None else np.asarray(raw.detection_kinds, float)
    if t_end is not None:
        ids = ids[raw.detections[:, 0] <= t_end]
        kinds = None if kinds is None else kinds[raw.detections[:, 0] <= t_end]
    rows = np.c_[det[keep, 1:], ids[keep]]
    if kinds is not None:  # the kind travels as one more column, after the id
        rows = np.c_[rows, kinds[keep]]
    z, z_mask, diam, z_id, extra = _detections(
        rows,
        scan_of_det[keep],
        scan_times,
        np.flatnonzero(layout["is_scan"]),
        layout["time"].size,
        k_max,
        f"{min_range} <= range < {max_range} m",
        measurement_dim,
    )
    # Numpy arrays: the segments live on the host until a run transfers them (jax arrays under jit).
    fields: dict[str, Any] = dict(
        time=layout["time"],
        dt=dt,
        u=u,
        dr_mask=dr_mask,
        z=z,
        z_mask=z_mask,
        diam=diam,
        is_scan=layout["is_scan"],
        z_id=z_id,
    )
    fields["z_kind"] = extra[..., 0].astype(np.int32) if kinds is not None else np.zeros_like(z_id)
    return Segments(**fields)


def segment_summary(seg: Segments) -> dict[str, int]:
    """Counts describing a :class:`Segments` (host or device arrays).

    Args:
        seg: the segments.

    Returns:
        ``n_segments``; ``n_detections`` (real ones); ``n_scans_with_detections``;
        ``max_detections_per_scan``; ``max_pieces`` (most real DR pieces in a segment);
        ``k_max`` and ``dr_per_segment`` (the padded sizes).
    """
    z_count = np.asarray(seg.z_mask).sum(axis=1)
    dr_count = np.asarray(seg.dr_mask).sum(axis=1)
    return dict(
        n_segments=int(z_count.size),
        n_detections=int(z_count.sum()),
        n_scans_with_detections=int(np.count_nonzero(z_count)),
        max_detections_per_scan=int(z_count.max(initial=0)),
        max_pieces=int(dr_count.max(initial=0)),
        k_max=int(np.asarray(seg.z_mask).shape[1]),
        dr_per_segment=int(np.asarray(seg.dr_mask).shape[1]),
    )
