"""Landmark management: tentative and confirmed landmarks, existence by negative evidence, tree
diameters (the ``map`` config section; docs/method/landmarks.md).

Each landmark carries an existence log-odds ``l``. The sensor model is the binary one of
occupancy mapping: a landmark inside the sensor's footprint is detected with probability
``p_detect`` if it exists and "detected" (a clutter detection falls in its gate) with probability
``p_false`` if it does not, so by Bayes' rule

* an associated detection adds ``log(p_detect / p_false)`` (:attr:`MapParams.log_odds_hit`),
* a scan in which the landmark lay inside the footprint, shrunk by the view margins, was not
  hidden behind a nearer object and was not detected adds
  ``log((1 - p_detect) / (1 - p_false))`` (:attr:`MapParams.log_odds_miss`),

and ``l`` is clamped at ``log_odds_max`` so that a tree that has gone can be removed after a few
misses. A landmark starts *tentative* at ``log_odds_birth``; it is *confirmed* once ``l`` reaches
``log_odds_confirm`` with at least ``confirm_hits`` detections; a tentative landmark older than
``tentative_scans`` scans is dropped, and any landmark whose ``l`` falls below ``log_odds_remove``
is removed (its slot is reused by :func:`~nanoslam_jax.methods.add_landmarks`).

Tree diameters: each landmark keeps a scalar Kalman filter of the diameter reported with its
detections (a constant state observed with noise ``sigma_diameter``: its estimate is the running
mean of the detections and its variance ``sigma_diameter^2 / n``), used optionally as a third
term of the association distance (:func:`~nanoslam_jax.methods.associate`).

All functions here are pure and per particle (vmapped by the caller); every value they use is a
traced :class:`~nanoslam_jax.methods.MapParams` field, so one compilation serves a sweep.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from nanoslam_jax.lib._batching import map_prefix
from nanoslam_jax.lib._trig import atan2, computed_once
from nanoslam_jax.models import AbstractMeasurementModel, RangeBearing, is_range_bearing, range_bearing, row_models
from nanoslam_jax.methods.maps._association import ScanDetections
from nanoslam_jax.methods.maps._landmarks import window_prefixes
from nanoslam_jax.methods._params import MapParams
from nanoslam_jax.methods._state import LandmarkMap


def diameter_update(
    diam: Float[Array, "*n"], var: Float[Array, "*n"], measured: Float[Array, "*n"], sigma: Float[Array, ""]
) -> tuple[Float[Array, "*n"], Float[Array, "*n"]]:
    """Scalar Kalman update of a constant diameter with a measurement of noise ``sigma``.

    Args:
        diam, var: the estimate and its variance.
        measured: the measured diameter.
        sigma: measurement noise standard deviation.

    Returns:
        The updated estimate and variance: ``diam + K (measured - diam)``, ``(1 - K) var`` with
        ``K = var / (var + sigma^2)``.
    """
    gain = var / (var + jnp.square(sigma))
    return diam + gain * (measured - diam), (1.0 - gain) * var


def in_view(z_pred: Float[Array, "n 2"], model: RangeBearing) -> Bool[Array, " n"]:
    """Which predicted detections ``(r, beta)`` lie inside a range-bearing sensor's footprint
    shrunk by the margins (:meth:`~nanoslam_jax.models.RangeBearing.visible` of the landmarks).

    Args:
        z_pred: predicted range and bearing of each landmark from the particle's pose.
        model: the range-bearing model (its footprint and margins).
    """
    return model.in_view(z_pred[:, 0], z_pred[:, 1])


def occluded(
    z_pred: Float[Array, "n 2"],
    occluder_z: Float[Array, "o 2"],
    occluder_radius: Float[Array, " o"],
    occluder_mask: Bool[Array, " o"],
    width: Float[Array, ""],
) -> Bool[Array, " n"]:
    """Which landmarks are hidden behind a nearer object at a similar bearing.

    Landmark ``j`` (predicted at ``(r_j, beta_j)``) is hidden when some occluder ``i`` (at
    ``(r_i, beta_i)``, radius ``rho_i``) is nearer, ``r_i < r_j``, and covers its bearing,
    ``|beta_i - beta_j| < atan2(rho_i + width, r_i)`` (bearing difference wrapped).

    Args:
        z_pred: predicted ``(r, beta)`` of the landmarks tested (bearings in ``(-pi, pi]``).
        occluder_z: ``(r, beta)`` of the possible occluders (the scan's detections, landmarks;
            bearings in ``(-pi, pi]``).
        occluder_radius: their radii (half the diameter, m).
        occluder_mask: which occluders are real.
        width: half-width added to every occluder's radius (m).
    """
    r_o, b_o = occluder_z[:, 0], occluder_z[:, 1]
    # The vectorised arctangent (jnp.arctan2 runs one element at a time on XLA:CPU, ~15 ns each).
    half = computed_once(atan2(occluder_radius + width, jnp.maximum(r_o, 1e-9)))
    # Occluders on the leading axis: the reduction then combines whole rows (vectorised on
    # XLA:CPU; over the trailing axis it was most of the management's cost).
    nearer = r_o[:, None] < z_pred[None, :, 0]
    # |wrap(d)| for bearings in (-pi, pi] (|d| < 2 pi), as min(|d|, 2 pi - |d|): the same values
    # bit for bit as wrap_angle's, at a third of the cost.
    d = jnp.abs(b_o[:, None] - z_pred[None, :, 1])
    covers = jnp.minimum(d, 2.0 * jnp.pi - d) < half[:, None]
    return jnp.any(occluder_mask[:, None] & nearer & covers, axis=0)


class Management(eqx.Module):
    """A landmark management policy: its traced hyperparameters and whether occlusion counts.

    Attributes:
        mp: the management hyperparameters (``map`` config section).
        occlusion: (static) landmarks hidden behind a nearer detection or confirmed landmark
            count no miss (range-bearing models only).
    """

    mp: MapParams
    occlusion: bool = eqx.field(static=True, default=False)


def manage_window(
    local: LandmarkMap,
    pose: Float[Array, "3"],
    seen: Bool[Array, " window"],
    dets: ScanDetections,
    observed: Bool[Array, ""] | bool,
    scan: Int[Array, ""] | int,
    model: AbstractMeasurementModel,
    policy: Management,
) -> LandmarkMap:
    """Existence, confirmation and removal of a particle's local landmarks after a scan.

    Args:
        local: the local map after the scan's updates (``hits`` already counts this scan's
            detections).
        pose: the particle's (sampled) pose.
        seen: which local landmarks a detection of this scan was associated with.
        dets: the scan's detections (occluders with ``policy.occlusion``; ``dets.diam`` their
            diameters).
        observed: the segment is a laser scan (False for padding and for the segments that split
            a long gap between scans: no misses are counted).
        scan: the current scan (the clock of ``born``).
        model: the measurement model: a landmark counts a miss where it is
            :meth:`~nanoslam_jax.models.AbstractMeasurementModel.visible`.
        policy: the management hyperparameters and whether occlusion counts.

    Returns:
        The local map with updated ``log_odds``, ``misses``, ``confirmed`` and ``active``.
    """
    if is_range_bearing(model):
        z_pred = jax.vmap(range_bearing, (None, 0))(pose, local.mean)
        visible = in_view(z_pred, model)
    else:
        rows, ax = row_models(model, local.kind)  # a composite's landmarks: each by its type
        visible = jax.vmap(lambda md, m: md.visible(pose, m), (ax, 0))(rows, local.mean)
    mp = policy.mp
    missed = observed & local.active & ~seen & visible
    if policy.occlusion and is_range_bearing(model):
        diam = jnp.zeros(dets.mask.shape, dets.z.dtype) if dets.diam is None else dets.diam
        occ_z = jnp.concatenate([dets.z, z_pred])
        occ_radius = jnp.concatenate([0.5 * diam, 0.5 * local.diam])
        occ_mask = jnp.concatenate([dets.mask, local.active & local.confirmed])
        missed = missed & ~occluded(z_pred, occ_z, occ_radius, occ_mask, mp.occlusion_width)
    log_odds = local.log_odds + jnp.where(seen, mp.log_odds_hit, 0.0) + jnp.where(missed, mp.log_odds_miss, 0.0)
    log_odds = jnp.minimum(log_odds, mp.log_odds_max)
    confirmed = local.confirmed | confirm_rule(log_odds, local.hits, mp)
    keep = (log_odds >= mp.log_odds_remove) & (confirmed | fresh(local.born, scan, mp))
    return local._replace(
        log_odds=log_odds,
        misses=local.misses + missed.astype(jnp.int32),
        confirmed=confirmed,
        active=local.active & keep,
    )


def manage_window_prefix(
    local: LandmarkMap,
    seen: Bool[Array, " window"],
    n_local: Int[Array, ""],
    manage: Callable[[LandmarkMap, Bool[Array, " b"]], LandmarkMap],
) -> LandmarkMap:
    """:func:`manage_window` (as ``manage(local, seen)``) over the smallest prefix of the window
    that holds its ``n_local`` landmarks: 16, 32 or all slots (``lax.switch``).

    The local window holds its landmarks in its leading slots (:func:`._landmarks.gather_window`)
    and management leaves inactive slots inactive and counts them neither as missed nor as
    occluders, so the prefix gives every landmark the same values as the whole window, at a
    fraction of the cost of the occlusion test (window x (detections + window) pairs). One branch
    for all particles (:func:`._landmarks.window_prefixes`).
    """
    sizes, index = window_prefixes(local.active.shape[0], n_local)
    if len(sizes) == 1:
        return manage(local, seen)

    def prefix(b):
        def branch(loc, sn):
            head = manage(jax.tree.map(lambda a: a[:b], loc), sn[:b])
            return jax.tree.map(lambda h, a: a.at[:b].set(h), head, loc)

        return branch

    return jax.lax.switch(index, [prefix(b) for b in sizes], local, seen)


def confirm_rule(log_odds: Float[Array, "*n"], hits: Int[Array, "*n"], mp: MapParams) -> Bool[Array, "*n"]:
    """Whether landmarks qualify for confirmation: log-odds and detection count both high enough."""
    return (log_odds >= mp.log_odds_confirm) & (hits >= mp.confirm_hits)


def fresh(born: Int[Array, "*n"], scan: Int[Array, ""] | int, mp: MapParams) -> Bool[Array, "*n"]:
    """Whether landmarks started at scan ``born`` are still within their tentative period."""
    return (scan - born) <= mp.tentative_scans


def drop_stale(
    lm: LandmarkMap, scan: Int[Array, ""] | int, mp: MapParams, used: Int[Array, ""] | None = None
) -> LandmarkMap:
    """Deactivate, over the whole map, the tentative landmarks past their tentative period
    (including those out of the local window, which no scan tests).

    ``used``: one past the highest active slot (the slots above are left as they are, since none
    is active); ``None``: every slot is visited.
    """

    def kept(active, other):
        confirmed, born = other
        return active & (confirmed | fresh(born, scan, mp))

    other = (lm.confirmed, lm.born)
    active = kept(lm.active, other) if used is None else map_prefix(kept, lm.active, used, read=other)
    return lm._replace(active=active)


class Candidates(NamedTuple):
    """The landmark each detection of a scan would start, as it leaves the scan.

    Attributes:
        mean, cov: each candidate's landmark (after any later detection of the same scan that
            matched it).
        diam, diam_var: each candidate's diameter estimate and variance.
        ident: each candidate's landmark id (known association), or None (the map keeps no ids).
        kind: each candidate's type (a composite measurement model), or None (the map keeps none).
    """

    mean: Float[Array, "k l"]
    cov: Float[Array, "k l l"]
    diam: Float[Array, " k"]
    diam_var: Float[Array, " k"]
    ident: Int[Array, " k"] | None = None
    kind: Int[Array, " k"] | None = None


def new_landmarks(
    cand: Candidates,
    is_new: Bool[Array, " k"],
    extra_hits: Int[Array, " k"],
    scan: Int[Array, ""] | int,
    mp: MapParams,
    manage: bool,
) -> LandmarkMap:
    """The landmarks a scan starts, as they leave the scan.

    Args:
        cand: each detection's candidate landmark.
        is_new: which candidates are started.
        extra_hits: further detections of the same scan that matched each started landmark.
        scan: the current scan (``born``).
        mp: management hyperparameters.
        manage: (static) with management a landmark starts tentative at ``log_odds_birth`` (plus
            a hit per further detection) and is confirmed if it already qualifies; without it,
            every new landmark is confirmed.
    """
    k = is_new.shape[0]
    hits = is_new.astype(jnp.int32) + extra_hits
    log_odds = jnp.minimum(mp.log_odds_birth + extra_hits * mp.log_odds_hit, mp.log_odds_max)
    confirmed = confirm_rule(log_odds, hits, mp) if manage else jnp.ones(k, bool)
    return LandmarkMap(
        mean=cand.mean,
        cov=cand.cov,
        active=is_new,
        hits=hits,
        misses=jnp.zeros(k, jnp.int32),
        log_odds=jnp.broadcast_to(log_odds, (k,)).astype(cand.mean.dtype),
        confirmed=confirmed & is_new,
        born=jnp.full(k, scan, jnp.int32),
        diam=cand.diam,
        diam_var=cand.diam_var,
        ident=None if cand.ident is None else cand.ident.astype(jnp.int32),
        kind=None if cand.kind is None else cand.kind.astype(jnp.int32),
    )
