"""The log as host arrays (:class:`RawLog`) and as fixed-shape device segments (:class:`Segments`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple, Optional

import numpy as np
from jaxtyping import Array, Bool, Float, Int


@dataclass(frozen=True)
class RawLog:
    """A Victoria Park-format log on the host, in the SLAM conventions of the spec.

    Attributes:
        dr: ``(N, 1 + C)`` dead reckoning ``time_s`` and the ``C`` controls held from it (the car's
            ``ve_mps, alpha_rad``; ``v, omega`` of a differential-drive robot; ``vx, vy, omega``
            of the odometry model), strictly increasing time.
        detections: ``(M, 4)`` tree detections ``time_s, range_m, bearing_rad, diameter_m`` with
            the bearing already in the **vehicle frame** (file bearing minus pi/2, wrapped);
            rows sharing a time form one scan; time non-decreasing. Detections of another
            measurement model have ``(M, 2 + d)`` rows: the time, the ``d`` values of the
            detection (a line's ``rho, alpha``; a circle's centre range, bearing and radius) and
            a last value (a segment's length, a circle's diameter).
        gps: ``(G, 3)`` GPS fixes ``time_s, x_m, y_m`` in the frame of ``gps.dat``.
        truth_poses: ``(T, 4)`` true laser poses ``time_s, x, y, phi`` (simulated logs only).
        truth_landmarks: ``(L, 2)`` true landmark positions (simulated logs only).
        truth_diameters: ``(L,)`` true tree diameters (simulated logs only).
        source: where the log came from (directory or "simulated").
        detection_ids: ``(M,)`` the landmark each detection is of, where the log knows it (e.g.
            barcodes), -1 where not; None: unknown for every detection.
        landmark_ids: ``(L,)`` the id of each row of ``truth_landmarks`` (the ids of
            ``detection_ids``); None: the row index.
        detection_kinds: ``(M,)`` each detection's landmark type (the index of its model in a
            :class:`~nanoslam_jax.models.Composite` measurement model; its values past its type's
            ``measurement_dim`` are 0), or None: one type.
    """

    dr: np.ndarray
    detections: np.ndarray
    gps: np.ndarray
    truth_poses: Optional[np.ndarray] = None
    truth_landmarks: Optional[np.ndarray] = None
    truth_diameters: Optional[np.ndarray] = None
    source: str = ""
    detection_ids: Optional[np.ndarray] = None
    landmark_ids: Optional[np.ndarray] = None
    detection_kinds: Optional[np.ndarray] = None

    @property
    def scan_times(self) -> np.ndarray:
        """Distinct detection times (one per scan with at least one detection)."""
        return np.unique(self.detections[:, 0])


class Segments(NamedTuple):
    """One segment per laser scan, padded to fixed shapes (docs/method/victoria-park.md, "Time and segments").

    Segment ``t`` moves the pose from the previous segment's time to ``time[t]`` through the
    held DR samples (``dt`` = the part of each sample's interval inside the segment; padding
    has ``dt = 0`` and ``dr_mask = False``), then applies the scan's detections.

    Attributes:
        time: scan time of each segment (s).
        dt: integration interval of each DR piece (s).
        u: controls of each DR piece (``(ve, alpha)`` for the car; as many as the log's DR rows have).
        dr_mask: which DR pieces are real.
        z: detections ``(range, bearing)``, bearing in the vehicle frame, wrapped (``d``: the
            measurement model's ``measurement_dim`` values).
        z_mask: which detections are real.
        diam: the tree diameter reported with each detection (m; the 4th column of
            ``measurements.dat``; 0 for padding).
        is_scan: the segment ends at a laser scan (False for the extra segments that split a long
            gap between scans, and for padding): only a scan is evidence that a landmark in view
            was not detected.
        z_id: the landmark id of each detection where the log knows it, else -1 (used by
            ``filter.association: known``).
        z_kind: each detection's landmark type (a composite measurement model; 0 for padding and
            for a log of one type; None where the segments were built without it).
    """

    time: Float[Array, " segments"]
    dt: Float[Array, "segments dr"]
    u: Float[Array, "segments dr c"]
    dr_mask: Bool[Array, "segments dr"]
    z: Float[Array, "segments k_max d"]
    z_mask: Bool[Array, "segments k_max"]
    diam: Float[Array, "segments k_max"]
    is_scan: Bool[Array, " segments"]
    z_id: Int[Array, "segments k_max"]
    z_kind: Optional[Int[Array, "segments k_max"]] = None

    @property
    def n_segments(self) -> int:
        return int(self.time.shape[0])

    @property
    def k_max(self) -> int:
        return int(self.z.shape[1])
