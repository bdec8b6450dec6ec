"""Offline smoothing of a run: the final best particle's path and map refined by batch least squares.

A particle filter reports at each scan what it knew then. Where the car drives new ground with few
trees (1000-1400 s of Victoria Park), a particle's path drifts and its map is built along the
drift; when the car meets trees mapped earlier the particle is corrected, but its path before
stays where it was: a Rao-Blackwellised particle's history is never revised, and the particles'
histories coalesce a few seconds back, so the ancestral path (``filter.estimate: path``) is every
particle's. This module revises it after the run, as a full smoothing-and-mapping problem over the
whole log (GraphSLAM / SAM):

* **Variables**: the pose of every segment and the position of every confirmed landmark of the
  final best particle's map, started from its ancestral path and its map; with
  ``smoother.map_history`` also the landmarks it held at the end of an earlier chunk of the run
  and lost since (a drifted particle removes the trees it no longer detects where it expects them),
  where they explain detections the final map does not (:func:`held_landmarks`).
* **Odometry factors**: between consecutive poses, the segment's motion in the frame of its start
  pose, ``x_{t-1}^{-1} (+) x_t`` (with the heading difference wrapped), against the prior mean
  the filter used (:func:`~nanoslam_jax.methods.relative_prior`, the unscented transform over the
  controls and their noise), with that prior's covariance times ``smoother.odometry_scale`` plus
  a floor (``smoother.floor_xy``, ``floor_phi_deg``). The filter's control noise is set large so
  that its particles cover the drift; the smoother reads the controls as what they are, much
  better than that between two scans. The floor stands for what the car model misses (slip, the
  nonholonomic constraint's exactness) and keeps the factors from being a stiff constraint.
* **Detection factors**: each detection the run's final map explains, ``z - h(x_t, m_j)`` with
  the measurement noise ``(sigma_r, sigma_beta)`` and a Huber loss (``smoother.huber``, on the
  whitened residual's norm) so that a wrong association pulls with a bounded force. Detections
  are associated once, before the iterations, to the nearest confirmed landmark of the final map
  seen from the ancestral path within the chi-square ``filter.gate``; the rest are left out.
* **Loop closure** (``smoother.loop_closure``): a particle that came back to ground it had mapped
  with its pose drifted beyond the gate mapped the trees there a second time, and along its path
  the copies agree with each other. After a first solve, stretches of newly mapped landmarks are
  registered against the earlier map (:mod:`nanoslam_jax.smoother._loop_closure`); copies found are joined
  to their originals, the problem is solved again from the path moved by the registration's
  transforms (:func:`~nanoslam_jax.smoother._loop_closure.path_moved_by_copies`) or, where the joins do not
  fit from there, from the path as it was, and the joins are kept only where their detections then
  fit.
* **Solver**: Levenberg-Marquardt on the normal equations, whose matrix is sparse (block
  tridiagonal over the poses, block diagonal over the landmarks, plus each detection's
  pose-landmark block): the poses are eliminated by a banded Cholesky factorisation
  (:func:`scipy.linalg.cholesky_banded`) and the landmarks' dense Schur complement solved. The
  first pose's predecessor is the origin, which fixes the gauge as the filter's start does.
  Residual Jacobians come from autodiff (:mod:`nanoslam_jax.smoother._least_squares`).

The result uses every scan of the log to place every pose: an offline estimate, not a filtering
one. It is compared with the filter's own estimate of the same run wherever it is reported.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import NamedTuple

import jax
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from nanoslam_jax.smoother._settings import SmootherConfig
from nanoslam_jax.methods._params import Params
from nanoslam_jax.methods import AbstractPrior, UnscentedPrior, relative_priors
from nanoslam_jax.smoother._loop_closure import (
    LoopClosureSettings,
    co_observed,
    find_duplicates,
    path_moved_by_copies,
    loop_closure_settings,
)
from nanoslam_jax.smoother._least_squares import Factors, Observations, _solve
from nanoslam_jax.models import wrap_angle_np

__all__ = [
    "DetectionNoise",
    "LoopClosureSettings",
    "SegmentData",
    "SmootherSettings",
    "Smoothed",
    "associate_path",
    "final_map",
    "held_landmarks",
    "segment_motion",
    "smooth_filter_run",
    "smooth_path",
    "smooth_run",
    "smoother_map",
    "smoother_metrics",
]

#: The config's defaults (:class:`nanoslam_jax.app.config.SmootherConfig`), the one source of the settings' defaults.
_DEFAULT = SmootherConfig()


class SmootherSettings(NamedTuple):
    """The ``smoother`` section (:class:`nanoslam_jax.app.config.SmootherConfig`).

    Its defaults are the config's: ``SmootherSettings()`` equals
    ``SmootherSettings.from_config(SmootherConfig())`` (loop closure and map history on).

    Attributes:
        odometry_scale: the odometry factors' covariance is the filter's segment prior covariance
            times this, plus the floors below.
        floor_xy, floor_phi: standard deviations (m, rad) added to every odometry factor, in each
            position coordinate and in the heading. The motion prior of the car model is nearly
            singular (the laser cannot move sideways but through a turn of the car), which makes
            the odometry factors a stiff nonlinear constraint along which Levenberg-Marquardt
            crawls; the floors, the model's own error, let it converge in about ten iterations.
        huber: the Huber loss's threshold on a detection's whitened residual norm.
        max_iter: Levenberg-Marquardt iterations at most.
        tol: converged when no pose or landmark coordinate moves more than this (m, rad).
        loop_closure: how trees mapped twice are searched for and joined after a first solve
            (:class:`LoopClosureSettings`); ``None``: not searched for.
        loop_closure_rounds: searches (each followed by a solve) at most.
        map_history: the map also holds the landmarks the best particle held at the end of a chunk
            of the run but no longer at its end (:func:`smoother_map`).
        map_history_radius: a held landmark nearer than this (m) to a kept one is the same tree.
        map_history_min: a held landmark joins the map when it explains at least this many
            detections that the final map leaves unexplained along the path ...
        map_history_below: ... and the final map explains less than this fraction of the log's
            detections along the path: a particle that removed the trees of its first visit.
            Otherwise the history is not used (what a run's management removed for cause, which
            its history also holds, stays out).
    """

    odometry_scale: float = _DEFAULT.odometry_scale
    floor_xy: float = _DEFAULT.floor_xy
    floor_phi: float = float(np.deg2rad(_DEFAULT.floor_phi_deg))
    huber: float = _DEFAULT.huber
    max_iter: int = _DEFAULT.max_iter
    tol: float = _DEFAULT.tol
    loop_closure: LoopClosureSettings | None = loop_closure_settings(_DEFAULT) if _DEFAULT.loop_closure else None
    loop_closure_rounds: int = _DEFAULT.loop_closure_rounds
    map_history: bool = _DEFAULT.map_history
    map_history_radius: float = _DEFAULT.map_history_radius
    map_history_min: int = _DEFAULT.map_history_min
    map_history_below: float = _DEFAULT.map_history_below

    @classmethod
    def from_config(cls, sc) -> "SmootherSettings":
        """From the config's ``smoother`` section (:class:`nanoslam_jax.app.config.SmootherConfig`)."""
        return cls(
            odometry_scale=sc.odometry_scale,
            floor_xy=sc.floor_xy,
            floor_phi=float(np.deg2rad(sc.floor_phi_deg)),
            huber=sc.huber,
            max_iter=sc.max_iter,
            tol=sc.tol,
            loop_closure=loop_closure_settings(sc) if sc.loop_closure else None,
            loop_closure_rounds=sc.loop_closure_rounds,
            map_history=sc.map_history,
            map_history_radius=sc.map_history_radius,
            map_history_min=sc.map_history_min,
            map_history_below=sc.map_history_below,
        )


class Smoothed(NamedTuple):
    """A smoothed run.

    Attributes:
        poses: the pose at each segment.
        landmarks: the landmarks' positions (the final map's confirmed landmarks, in its order,
            then the held landmarks taken back; a copy joined to its original by the loop closure
            at the original's position).
        associated: detections that entered as factors.
        detections: detections of the log.
        iterations: Levenberg-Marquardt iterations taken over all solves (the loop closure solves again;
            ``max_iter`` bounds each solve).
        initial_cost, cost: the objective (half the sum of squared whitened residuals, Huber for
            detections) at the start and at the end.
        converged: whether the last solve's last step moved nothing by more than ``tol``.
        seconds: wall time of the smoothing.
        merged: landmarks joined to another as copies of the same tree (loop closure).
        rejected: groups of joins (a window's registration, a close pair) found but dropped: their
            detections did not fit after a solve.
    """

    poses: Float[np.ndarray, "segments 3"]
    landmarks: Float[np.ndarray, "landmarks 2"]
    associated: int
    detections: int
    iterations: int
    initial_cost: float
    cost: float
    converged: bool
    seconds: float
    merged: int = 0
    rejected: int = 0


_relative_priors = jax.jit(relative_priors, static_argnums=2)  # one compilation per log shape and prior


def segment_motion(
    segments, params: Params, prior: AbstractPrior = UnscentedPrior()
) -> tuple[Float[Array, "segments 3"], Float[Array, "segments 3 3"]]:
    """Each segment's motion prior in the frame of its start pose (mean and covariance), as the
    filter's prior computes it (:func:`~nanoslam_jax.methods.relative_prior`; ``prior``:
    ``filter.prior``)."""
    return _relative_priors(segments, params, prior)


def _whitened_d2(x, m, z, sigma_r: float, sigma_beta: float) -> np.ndarray:
    """Squared residual of detections ``z`` (range, bearing) of landmarks ``m`` seen from poses
    ``x``, whitened by the measurement noise; the arrays broadcast over their leading axes."""
    dx, dy = m[..., 0] - x[..., 0], m[..., 1] - x[..., 1]
    return ((z[..., 0] - np.hypot(dx, dy)) / sigma_r) ** 2 + (
        wrap_angle_np(z[..., 1] - np.arctan2(dy, dx) + x[..., 2]) / sigma_beta
    ) ** 2


def associate_path(
    path: Float[np.ndarray, "segments 3"],
    landmarks: Float[np.ndarray, "landmarks 2"],
    z: Float[np.ndarray, "segments k 2"],
    z_mask: Bool[np.ndarray, "segments k"],
    sigma_r: float,
    sigma_beta: float,
    gate: float,
) -> tuple[Int[np.ndarray, " n"], Int[np.ndarray, " n"], Int[np.ndarray, " n"]]:
    """Each detection's nearest landmark seen from ``path`` within the chi-square ``gate`` (on the
    measurement noise alone). Returns the segment, the detection's index in it and the landmark of
    every associated detection."""
    seg, det = np.nonzero(np.asarray(z_mask))
    lm = np.asarray(landmarks)
    if len(lm) == 0 or len(seg) == 0:
        empty = np.zeros(0, int)
        return empty, empty, empty
    x = np.asarray(path)[seg]
    zz = np.asarray(z)[seg, det]
    best = np.full(len(seg), np.inf)
    idx = np.zeros(len(seg), int)
    for start in range(0, len(lm), 256):  # bounded memory: detections x 256 landmarks at a time
        m = lm[start : start + 256]
        d2 = _whitened_d2(x[:, None], m[None], zz[:, None], sigma_r, sigma_beta)
        j = np.argmin(d2, axis=1)
        d = d2[np.arange(len(seg)), j]
        better = d < best
        best[better], idx[better] = d[better], start + j[better]
    ok = best < gate
    return seg[ok], det[ok], idx[ok]


class SegmentData(NamedTuple):
    """What the log gives the smoother at each segment.

    Attributes:
        z, z_mask: the detections per segment (``Segments.z``, ``Segments.z_mask``).
        motion_mean, motion_cov: each segment's motion prior in its start pose's frame
            (:func:`segment_motion`); the pose before the first segment is the origin.
        time_s: each segment's time (s), or None; needed by the loop closure (``SmootherSettings.loop_closure``).
    """

    z: Float[np.ndarray, "segments k 2"]
    z_mask: Bool[np.ndarray, "segments k"]
    motion_mean: Float[np.ndarray, "segments 3"]
    motion_cov: Float[np.ndarray, "segments 3 3"]
    time_s: Float[np.ndarray, " segments"] | None = None


class DetectionNoise(NamedTuple):
    """The detections' noise and association gate.

    Attributes:
        sigma_r, sigma_beta: measurement noise (m, rad).
        gate: chi-square gate of the association.
    """

    sigma_r: float
    sigma_beta: float
    gate: float


def _associate(path, landmarks, z, z_mask, noise: DetectionNoise):
    """:func:`associate_path` with the noise and gate of ``noise``."""
    return associate_path(path, landmarks, z, z_mask, noise.sigma_r, noise.sigma_beta, noise.gate)


def _map_with_held(path, lm_all, data: SegmentData, noise: DetectionNoise, settings: SmootherSettings, held):
    """The landmarks to solve for and the association to them: ``lm_all``, joined by the ``held`` landmarks
    that explain at least ``settings.map_history_min`` detections it leaves unexplained when it explains
    less than ``settings.map_history_below`` of them. Returns ``(landmarks, (seg, det, lid))``."""
    z, z_mask = data.z, data.z_mask
    seg, det, lid = _associate(path, lm_all, z, z_mask, noise)
    if held is not None and len(held) and len(seg) < settings.map_history_below * np.sum(z_mask):
        left = np.array(z_mask, bool)
        left[seg, det] = False
        _, _, j = _associate(path, held, z, left, noise)
        held = np.asarray(held, float).reshape(-1, 2)
        back = held[np.bincount(j, minlength=len(held)) >= settings.map_history_min]
        if len(back):
            lm_all = np.concatenate([lm_all, back])
            seg, det, lid = _associate(path, lm_all, z, z_mask, noise)
    return lm_all, (seg, det, lid)


def _factors(data: SegmentData, noise: DetectionNoise, settings: SmootherSettings) -> Factors:
    """The factors' weights: the odometry's whitening from the motion prior's covariance scaled and floored
    (``settings``), the detections' from the measurement noise."""
    cov = (
        settings.odometry_scale * np.asarray(data.motion_cov, float)
        + np.diag([settings.floor_xy**2, settings.floor_xy**2, settings.floor_phi**2])
        + 1e-12 * np.eye(3)
    )
    w_odo = np.transpose(np.linalg.cholesky(np.linalg.inv(cov)), (0, 2, 1))  # whitened e = W e, W'W = cov^-1
    w_det = np.array([1.0 / noise.sigma_r, 1.0 / noise.sigma_beta])
    motion = np.asarray(data.motion_mean, float)
    return Factors(motion, w_odo, w_det, settings.huber, settings.max_iter, settings.tol)


@dataclass
class _Solution:
    """The smoothing's current solution and its account (what :class:`Smoothed` reports)."""

    poses: np.ndarray
    landmarks: np.ndarray
    seg: np.ndarray  # the associated detections: segment, landmark, range and bearing
    lid: np.ndarray
    zz: np.ndarray
    iterations: int
    cost: float
    converged: bool
    owner: np.ndarray  # each landmark's original (itself unless joined as a copy)
    merged: int = 0
    rejected: int = 0


def _solve_from(start, sol: _Solution, seg, zz, lid, factors: Factors):
    """:func:`_solve` from the poses ``start`` and the current landmarks over the detections given."""
    return _solve(start, sol.landmarks, Observations(seg, zz, lid), factors)


def _best_start(sol: _Solution, starts, joined, keep, noise: DetectionNoise, settings: SmootherSettings, factors):
    """Solve from each of ``starts`` (poses and association) in turn, until the copies' detections (``joined``)
    fit the landmarks that are not copies (``keep``) well enough. Returns the solve whose copies' detections
    fit best and which of them fit (within the gate)."""
    assert settings.loop_closure is not None
    best = None
    for start, a_seg, a_z, a_lid in starts:
        s = _solve_from(start, sol, a_seg, a_z, a_lid, factors)
        sol.iterations += s[2]
        # Verification: a true loop closure lets the copies' detections fit a landmark
        # as the others do once the path has moved; a false one leaves them outside the
        # gate. A group that does not fit is dropped and the rest solved again.
        fit = (
            np.min(
                _whitened_d2(
                    s[0][sol.seg[joined]][:, None],
                    s[1][keep][None],
                    sol.zz[joined][:, None],
                    noise.sigma_r,
                    noise.sigma_beta,
                ),
                axis=1,
            )
            < noise.gate
        )
        if best is None or np.mean(fit) > np.mean(best[1]):
            best = (s, fit)
        if np.mean(fit) >= settings.loop_closure.accept:
            break
    assert best is not None  # starts is never empty
    return best


def _join_copies(sol: _Solution, parent, group, t, data: SegmentData, noise, settings: SmootherSettings, factors):
    """Solve with each copy (``parent``) joined to its original; a group of joins whose detections do not fit
    is dropped (``parent`` reset in place) and the rest tried once more. Returns the solve's
    ``(poses, landmarks, cost, converged)`` where every group fits, else None."""
    assert settings.loop_closure is not None
    seg, lid, zz = sol.seg, sol.lid, sol.zz
    for _ in range(2):
        new_lid = parent[lid]
        joined = new_lid != lid
        if not np.any(joined):
            return None
        keep = np.nonzero(parent == np.arange(len(parent)))[0]
        # Two starts: the path moved as the copies' transforms say, every detection
        # associated again to the landmarks that are not copies (a large correction, which
        # Levenberg-Marquardt does not make from the drifted path); and, unless the joins
        # fit from there as a whole, the path as it is with the copies' detections given to
        # their originals. The solution that explains more of the copies' detections is kept.
        moved = path_moved_by_copies(sol.poses, sol.landmarks, seg, lid, parent, group, t, settings.loop_closure)
        starts = [(sol.poses, seg, zz, new_lid)]
        if moved is not sol.poses:
            s2, d2, j2 = _associate(moved, sol.landmarks[keep], data.z, data.z_mask, noise)
            starts.insert(0, (moved, s2, np.asarray(data.z)[s2, d2].reshape(-1, 2), keep[j2]))
        (p2, l2, _, _, c2, conv2), fit = _best_start(sol, starts, joined, keep, noise, settings, factors)
        g = group[lid[joined]]
        bad = [k for k in np.unique(g) if np.mean(fit[g == k]) < settings.loop_closure.accept]
        if not bad:
            return p2, l2, c2, conv2
        sol.rejected += len(bad)
        drop = np.isin(group, bad)
        parent[drop] = np.nonzero(drop)[0]
    return None


def _close_loops(sol: _Solution, data: SegmentData, noise: DetectionNoise, settings: SmootherSettings, factors):
    """Up to ``settings.loop_closure_rounds`` times: find the landmarks mapped twice, join them where their
    detections fit (:func:`_join_copies`), associate every detection again and solve (``sol`` in place)."""
    assert settings.loop_closure is not None and data.time_s is not None
    t = np.asarray(data.time_s, float)
    for _ in range(settings.loop_closure_rounds):
        first = np.full(len(sol.landmarks), np.inf)
        np.minimum.at(first, sol.lid, t[sol.seg])
        together = co_observed(sol.seg, sol.lid, len(sol.landmarks))
        parent, group = find_duplicates(sol.landmarks, first, together, settings.loop_closure)
        while np.any(parent[parent] != parent):  # chains of copies end at the original
            parent = parent[parent]
        joined = _join_copies(sol, parent, group, t, data, noise, settings, factors)
        if joined is None:
            break
        sol.merged += int(np.sum(parent != np.arange(len(parent))))  # copies joined earlier have no detections
        sol.poses, sol.landmarks, sol.cost, sol.converged = joined
        sol.owner = parent[sol.owner]
        # The path has moved: associate every detection again, to the landmarks that remain.
        live = np.nonzero(sol.owner == np.arange(len(sol.owner)))[0]
        seg, det, lid = _associate(sol.poses, sol.landmarks[live], data.z, data.z_mask, noise)
        sol.seg, sol.lid, sol.zz = seg, live[lid], np.asarray(data.z)[seg, det].reshape(-1, 2)
        sol.poses, sol.landmarks, it, _, sol.cost, sol.converged = _solve_from(
            sol.poses, sol, sol.seg, sol.zz, sol.lid, factors
        )
        sol.iterations += it


def smooth_path(
    path: Float[np.ndarray, "segments 3"],
    landmarks: Float[np.ndarray, "landmarks 2"],
    data: SegmentData,
    noise: DetectionNoise,
    settings: SmootherSettings = SmootherSettings(),
    held: Float[np.ndarray, "held 2"] | None = None,
) -> Smoothed:
    """Smooth a path and its map by Levenberg-Marquardt over odometry and detection factors.

    Args:
        path: the initial pose at each segment (the final best particle's ancestral path).
        landmarks: the initial landmark positions (its map's confirmed landmarks).
        data: the log's detections, motion priors and times per segment (:class:`SegmentData`).
        noise: the measurement noise and the association's gate (:class:`DetectionNoise`).
        settings: the smoother's settings.
        held: landmarks the run held earlier but not at its end (:func:`held_landmarks`). When
            ``landmarks`` explain less than ``settings.map_history_below`` of the detections along
            ``path``, each that explains at least ``settings.map_history_min`` of the others joins
            them.

    Returns:
        The smoothed poses and landmarks and the solver's account.
    """
    t0 = time.perf_counter()
    path = np.asarray(path, float)
    lm_all = np.asarray(landmarks, float).reshape(-1, 2)
    lm_all, (seg, det, lid) = _map_with_held(path, lm_all, data, noise, settings, held)
    zz = np.asarray(data.z)[seg, det].reshape(-1, 2)
    factors = _factors(data, noise, settings)
    poses, lm_out, iterations, initial_cost, cost, converged = _solve(
        path, lm_all.copy(), Observations(seg, zz, lid), factors
    )
    sol = _Solution(poses, lm_out, seg, lid, zz, iterations, cost, converged, np.arange(len(lm_out)))
    if settings.loop_closure is not None and data.time_s is not None and len(lid):
        _close_loops(sol, data, noise, settings, factors)
    return Smoothed(
        poses=sol.poses,
        landmarks=sol.landmarks[sol.owner],
        associated=int(len(sol.seg)),
        detections=int(np.sum(data.z_mask)),
        iterations=sol.iterations,
        initial_cost=float(initial_cost),
        cost=float(sol.cost),
        converged=sol.converged,
        seconds=time.perf_counter() - t0,
        merged=sol.merged,
        rejected=sol.rejected,
    )


def final_map(state, index: int | None = None) -> Float[np.ndarray, "landmarks 2"]:
    """The positions of the confirmed landmarks of a run's final best particle (``index``: the
    member of a batch run)."""
    lm = state.particles.landmarks
    best = np.asarray(state.best)
    take = (lambda a: np.asarray(a)[best]) if index is None else (lambda a: np.asarray(a)[index, best[index]])
    keep = take(lm.active) & take(lm.confirmed)
    return take(lm.mean)[keep]


def held_landmarks(
    history, final: Float[np.ndarray, "landmarks 2"], index: int | None = None, radius: float = 1.0
) -> Float[np.ndarray, "held 2"]:
    """Landmarks the best particle held at the end of a chunk of the run but not at its end.

    A particle that comes back with its pose drifted to trees it mapped earlier misses them where
    it expects them, and landmark management removes them; its final map holds only the drifted
    copies it made instead, and the detections of its first visit are left without a landmark.
    The run's :class:`~nanoslam_jax.methods.MapHistory` still has them. Every confirmed landmark
    of the history farther than ``radius`` from the final map's and from each other is returned,
    the later chunk's position first (a tree the particles mapped in different slots is one).

    Args:
        history: ``FilterRun.history``.
        final: the final map's landmarks (:func:`final_map`).
        index: the member of a batch run.
        radius: distance (m) below which a held landmark is the same tree as one kept.
    """
    mean, held = np.asarray(history.mean), np.asarray(history.held)
    if index is not None:
        mean, held = mean[:, index], held[:, index]
    cand = np.concatenate([mean[c][held[c]] for c in range(len(mean) - 1, -1, -1)]).reshape(-1, 2)
    kept = np.asarray(final, float).reshape(-1, 2)
    out = []
    for x in cand:
        if len(kept) and np.min(np.hypot(*(kept - x).T)) < radius:
            continue
        out.append(x)
        kept = np.vstack([kept, x])
    return np.asarray(out, float).reshape(-1, 2)


def smoother_map(
    run, settings: SmootherSettings, index: int | None = None
) -> tuple[Float[np.ndarray, "landmarks 2"], Float[np.ndarray, "held 2"] | None]:
    """The landmarks a run's smoothing starts from: the final best particle's confirmed ones
    (:func:`final_map`) and, with ``settings.map_history``, those it held earlier but no longer
    (:func:`held_landmarks`; else ``None``): the ``landmarks`` and ``held`` of :func:`smooth_run`.

    Args:
        run: the run (:class:`~nanoslam_jax.methods.FilterRun`).
        settings: the smoother's settings.
        index: the member of a batch run.
    """
    final = final_map(run.state, index)
    if not settings.map_history or run.history is None:
        return final, None
    return final, held_landmarks(run.history, final, index, settings.map_history_radius)


def smooth_run(
    path,
    landmarks,
    segments,
    params: Params,
    settings: SmootherSettings,
    prior: AbstractPrior = UnscentedPrior(),
    held=None,
) -> Smoothed:
    """:func:`smooth_path` for a run: the log's detections and motion priors from ``segments`` and
    ``params`` (one run's hyperparameters), the association gate ``params.gate``.

    Args:
        path: the run's ancestral path (``AncestralPath().trajectory(...)``).
        landmarks: the positions of its final best particle's confirmed landmarks.
        segments: the log's segments.
        params: the run's hyperparameters.
        settings: the smoother's settings.
        prior: ``filter.prior``, how the motion prior is propagated.
        held: landmarks the run held earlier but not at its end (:func:`smoother_map`).
    """
    mean, cov = segment_motion(segments, params, prior)
    return smooth_path(
        path,
        landmarks,
        SegmentData(
            np.asarray(segments.z),
            np.asarray(segments.z_mask),
            np.asarray(mean),
            np.asarray(cov),
            np.asarray(segments.time),
        ),
        DetectionNoise(float(params.sigma_r), float(params.sigma_beta), float(params.gate)),
        settings,
        held,
    )


def smooth_filter_run(
    run, path, segments, params: Params, config, prior: AbstractPrior = UnscentedPrior(), index: int | None = None
) -> Smoothed:
    """Smooth one run of :func:`~nanoslam_jax.methods.run_filter` (or member ``index`` of a
    :func:`~nanoslam_jax.methods.run_batch`): its final best particle's map (:func:`smoother_map`)
    and ``path``, with the settings of the config's ``smoother`` section ``config``.

    Args:
        run: the run (:class:`~nanoslam_jax.methods.FilterRun`).
        path: ``(segments, 3)`` its ancestral path (``AncestralPath().trajectory(...)``, that member's).
        segments: the log's segments.
        params: the run's hyperparameters (one member's).
        config: the ``smoother`` section (:class:`nanoslam_jax.app.config.SmootherConfig`).
        prior: ``filter.prior``.
        index: the member of a batch run (None: a single run).
    """
    settings = SmootherSettings.from_config(config)
    final, held = smoother_map(run, settings, index)
    return smooth_run(path, final, segments, params, settings, prior, held)


def smoother_metrics(sm: Smoothed, config) -> tuple[dict, list[str]]:
    """What a smoothed run reports: ``smoother_*`` figures, and a warning when it did not converge.

    Args:
        sm: the smoothed run.
        config: the ``smoother`` section it ran with (named in the warning).

    Returns:
        ``(metrics, warnings)``.
    """
    m = dict(
        smoother_iterations=sm.iterations,
        smoother_converged=sm.converged,
        smoother_associated=sm.associated,
        smoother_detections=sm.detections,
        smoother_cost_initial=sm.initial_cost,
        smoother_cost=sm.cost,
        smoother_s=sm.seconds,
        smoother_merged=sm.merged,
        smoother_rejected=sm.rejected,
    )
    warn = (
        []
        if sm.converged
        else [
            f"smoother: stopped after {sm.iterations} iterations without converging (smoother.max_iter "
            f"{config.max_iter}, smoother.tol {config.tol:g}); the smoothed path is reported as it stands"
        ]
    )
    return m, warn
