"""A particle's map after its scan: the matched landmarks written back, management over the
local window, the scan's new landmarks placed (and the map's spatial index widened), over the
slot bucket that holds every active landmark."""

from __future__ import annotations

import functools
from typing import NamedTuple, Optional

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from nanoslam_jax.lib._batching import prefix_max
from nanoslam_jax.methods._params import Params, Static
from nanoslam_jax.methods._state import BlockIndex, LandmarkMap, count_confirmed, count_landmarks
from nanoslam_jax.methods.maps._association import Association, ScanDetections
from nanoslam_jax.methods.maps._landmarks import (
    MANAGED_FIELDS,
    free_slots,
    place_landmarks,
    scatter_window,
    update_slots,
)
from nanoslam_jax.methods.maps._management import (
    Candidates,
    Management,
    diameter_update,
    drop_stale,
    manage_window,
    manage_window_prefix,
    new_landmarks,
)
from nanoslam_jax.methods.particle._rows import RowResults


class SegmentIn(NamedTuple):
    """What one segment gives every particle (shared, not vmapped).

    Attributes:
        dt, u, dr_mask: the segment's odometry steps, controls and which steps are real.
        dets: the scan's detections; ``dets.ident`` is given only with known association, and
            ``dets.kind`` only for a composite measurement model.
        observed: the segment is a laser scan. False marks padding, or a segment splitting a long
            gap between scans: landmark management then counts no misses (for padding the caller
            masks the pose and weight; with no detections the map is unchanged).
        scan: the count of laser scans before this one (the clock of the landmarks' ``born``).
        rel_prior: the segment's :func:`relative_prior`, shared by all particles, with
            ``static.prior.reset``; the prior is then placed at the particle's pose
            instead of propagated per particle (the same Gaussian up to rounding). None:
            propagated per particle.
        slot_bucket: index into ``static.slot_buckets`` of a map prefix that holds every active
            landmark (the local window, and with management the free slots, are searched there;
            None: the whole map). The same for all particles, so under ``vmap`` it stays a branch.
        slots_used: one past the highest active slot of any particle (the stale tentative
            landmarks are dropped below it; None: over the whole map).
    """

    dt: Float[Array, " dr"]
    u: Float[Array, "dr c"]
    dr_mask: Bool[Array, " dr"]
    dets: ScanDetections
    observed: Bool[Array, ""] | bool = True
    scan: Int[Array, ""] | int = 0
    rel_prior: tuple[Float[Array, "3"], Float[Array, "3 3"]] | None = None
    slot_bucket: Int[Array, ""] | None = None
    slots_used: Int[Array, ""] | None = None


class Matches(NamedTuple):
    """How a scan's rows relate to one particle's local window (from the association).

    Attributes:
        assoc: the association.
        matched: the row matched a landmark (of the window or started earlier in the scan).
        existing: the row matched a landmark of the window.
        provisional: the row matched the landmark an earlier row of this scan started.
        ws: the local slot of a row that matched an existing landmark (clipped for the others).
        ps: the row that started the landmark a row matched (clipped for the others).
        trusted: the matched landmark may shape the proposal and the weight (with management:
            a confirmed one, or any with ``map.use_tentative``).
        used: the rows that shape the proposal and the weight.
    """

    assoc: Association
    matched: Bool[Array, " k"]
    existing: Bool[Array, " k"]
    provisional: Bool[Array, " k"]
    ws: Int[Array, " k"]
    ps: Int[Array, " k"]
    trusted: Bool[Array, " k"]
    used: Bool[Array, " k"]


def update_map(
    static: Static,
    params: Params,
    mapped: tuple[LandmarkMap, BlockIndex | None],
    window: tuple[LandmarkMap, Int[Array, " w"]],
    m: Matches,
    rows: RowResults,
    seg: SegmentIn,
) -> tuple[LandmarkMap, BlockIndex | None, Int[Array, ""], tuple[Optional[Int[Array, ""]], ...], Int[Array, " m"]]:
    """The particle's map (and its spatial index) after the scan: matched landmarks updated,
    management over the window, the scan's new landmarks added; with the overflow, when the
    particles are split over devices the landmark counts and one past the highest active slot
    (else None: the step finds them), and the slots written (the capacity for none; besides
    these, only the stale tentative landmarks' ``active`` changes, the same function of every
    particle's slots)."""
    lm, index = mapped
    local, idx = window
    dets, mp = seg.dets, params.map
    W, K = local.active.shape[0], static.k_max
    assert dets.diam is not None
    # Diameters: each matched row updates its landmark's estimate (scalar Kalman filter).
    var_d = jnp.square(mp.sigma_diameter)
    cur_d = jnp.where(m.existing, local.diam[m.ws], dets.diam[m.ps])
    cur_dv = jnp.where(m.existing, local.diam_var[m.ws], var_d)
    upd_d, upd_dv = diameter_update(cur_d, cur_dv, dets.diam, mp.sigma_diameter)
    new = _started(static, params, m, rows, dets, (upd_d, upd_dv), seg.scan)
    upd = (rows.upd_mean, rows.upd_cov, upd_d, upd_dv)
    if static.manage:
        wt = jnp.where(m.existing, m.ws, W)
        local = update_slots(local, wt, *upd)
        seen = jnp.zeros(W, bool).at[wt].set(True, mode="drop")
        policy = Management(mp, static.occlusion)

        def manage(loc, sn):
            return manage_window(loc, rows.pose, sn, dets, seg.observed, seg.scan, params.measurement, policy)

        local = manage_window_prefix(local, seen, jnp.sum(local.active), manage)
    # The matched rows' estimates go straight to their slots (k rows); of the window only the
    # fields management changes are written back.
    updated = jnp.where(m.existing, idx[m.ws], lm.active.shape[0])
    lm = update_slots(lm, updated, *upd)
    if static.manage:
        lm = drop_stale(scatter_window(lm, local, idx, fields=MANAGED_FIELDS), seg.scan, mp, seg.slots_used)
    # Every active landmark lies in the slot bucket before this scan (management only frees
    # slots), so the scan's new landmarks go to its first K free slots at most K past it: the
    # free slots are searched there and the map's landmarks counted there, not over the capacity.
    past = lambda b: None if b is None else b + K  # noqa: E731
    free = None
    if static.manage:
        free = over_slot_bucket(static, seg.slot_bucket, lambda b, a: free_slots(a, K, past(b)), lm.active)
    lm, placed = place_landmarks(lm, new, m.assoc.is_new, contiguous=not static.manage, free=free)
    overflow = jnp.sum(m.assoc.is_new & (placed == lm.active.shape[0]))
    if index is not None:
        index = index.widen(updated, rows.upd_mean).widen(placed, new.mean)
    written = jnp.concatenate([idx if static.manage else updated, placed])
    if static.devices == 1:  # the step counts the best particle's landmarks and the slots in use
        return lm, index, overflow, (None, None, None), written
    # Split over devices: counted where the maps are, with one past the particle's highest active slot.
    counts = over_slot_bucket(
        static, seg.slot_bucket, lambda b, lm_: landmark_counts(jax.tree.map(lambda a: a[: past(b)], lm_)), lm
    )
    used = jnp.asarray(lm.active.shape[0] if seg.slots_used is None else seg.slots_used + K)
    return lm, index, overflow, (*counts, prefix_max(lm.active, used)), written


def _started(
    static: Static,
    params: Params,
    m: Matches,
    rows: RowResults,
    dets: ScanDetections,
    diam_upd: tuple[Float[Array, " k"], Float[Array, " k"]],
    scan: Int[Array, ""] | int,
) -> LandmarkMap:
    """The landmarks the scan starts, as they leave it (a later detection of the scan may have
    updated one)."""
    assert dets.diam is not None
    K = static.k_max
    upd_d, upd_dv = diam_upd
    pt = jnp.where(m.provisional, m.ps, K)
    cand = Candidates(
        mean=rows.new_mean.at[pt].set(rows.upd_mean, mode="drop"),
        cov=rows.new_cov.at[pt].set(rows.upd_cov, mode="drop"),
        diam=dets.diam.at[pt].set(upd_d, mode="drop"),
        diam_var=jnp.full(K, jnp.square(params.map.sigma_diameter)).at[pt].set(upd_dv, mode="drop"),
        ident=dets.ident,
        kind=dets.kind,
    )
    extra_hits = jnp.zeros(K, jnp.int32).at[pt].add(1, mode="drop")
    return new_landmarks(cand, m.assoc.is_new, extra_hits, scan, params.map, static.manage)


def over_slot_bucket(static: Static, slot_bucket: Int[Array, ""] | None, fn, *operands):
    """``fn(slots, *operands)`` with ``slots`` the size of the map prefix ``slot_bucket`` names (a
    ``lax.switch`` over ``static.slot_buckets``; the index is the same for all particles, so under
    ``vmap`` it stays one branch), or ``fn(None, *operands)`` (the whole map) without buckets."""
    if slot_bucket is None or len(static.slot_buckets) == 1:
        return fn(None, *operands)
    return jax.lax.switch(slot_bucket, [functools.partial(fn, b) for b in static.slot_buckets], *operands)


def landmark_counts(lm: LandmarkMap) -> tuple[Int[Array, ""], Int[Array, ""]]:
    """:func:`count_landmarks` and :func:`count_confirmed` of one particle's map, as int32."""
    return count_landmarks(lm).astype(jnp.int32), count_confirmed(lm).astype(jnp.int32)
