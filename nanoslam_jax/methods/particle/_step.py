"""One segment of the Rao-Blackwellised particle filter: per-particle work (vmapped) and the
particle-set work (weights, estimate, resampling)."""

from __future__ import annotations

import functools
from typing import NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, PartitionSpec
from jaxtyping import Array, Bool, Float, Int

from nanoslam_jax.lib._batching import batch_max, map_prefix, prefix_max, take_if, take_prefix_if
from nanoslam_jax.lib._trig import computed_once
from nanoslam_jax.data import Segments
from nanoslam_jax.models import circular_mean, is_composite
from nanoslam_jax.methods.proposals import AbstractProposal, Detections
from nanoslam_jax.methods.maps._association import (
    Gating,
    ScanDetections,
    associate,
    associate_window_prefix,
    predicted_measurements,
)
from nanoslam_jax.methods.maps._landmarks import (
    gather_window,
)
from nanoslam_jax.methods._params import Params, Static
from nanoslam_jax.methods.particle._prior import compose_prior, predict, relative_prior
from nanoslam_jax.lib._resampling import effective_sample_size, normalise
from nanoslam_jax.methods.particle._rows import RowInputs, RowResults, rows_over_buckets
from nanoslam_jax.methods.gaussian._srukf import adaptive_noise_rows
from nanoslam_jax.methods.particle._resample import mark_written, take_changed_blocks
from nanoslam_jax.methods.particle._map_update import Matches, SegmentIn, landmark_counts, over_slot_bucket, update_map
from nanoslam_jax.methods._state import (
    SEARCH_FROM,
    BlockIndex,
    FilterState,
    LandmarkMap,
    Particles,
)


class StepOutput(NamedTuple):
    """What the scan records per segment (small arrays only).

    Attributes:
        best_pose: pose of the highest-weight particle.
        mean_pose: weighted mean pose (circular mean heading).
        ess: effective sample size after weighting.
        resampled: whether the particles were resampled.
        n_landmarks: landmarks (tentative and confirmed) in the best particle's map.
        n_confirmed: confirmed landmarks in the best particle's map.
        iterations: mean proposal iterations over particles that had associations.
        n_capped: particles whose iterative proposal hit the iteration cap.
        n_nonfinite: particles whose proposal failed (fell back to the prior).
        n_associated: mean associated detections per particle.
        n_new: mean new landmarks per particle.
        window_overflow: most landmarks near a particle that did not fit its window.
        overflow: new landmarks dropped for lack of capacity (all particles).
        weight_reset: all weights were non-finite and were reset to uniform.
        poses: every particle's pose after the proposal (before resampling); recorded only with
            ``filter.estimate: path``, else None.
        ancestors: which of these particles each particle after the step descends from (the
            resampling's ancestor indices; ``arange`` when it did not resample); only with
            ``filter.estimate: path``. With ``poses`` the genealogy :func:`ancestral_path` follows.
    """

    best_pose: Float[Array, "3"]
    mean_pose: Float[Array, "3"]
    ess: Float[Array, ""]
    resampled: Bool[Array, ""]
    n_landmarks: Int[Array, ""]
    n_confirmed: Int[Array, ""]
    iterations: Float[Array, ""]
    n_capped: Int[Array, ""]
    n_nonfinite: Int[Array, ""]
    n_associated: Float[Array, ""]
    n_new: Float[Array, ""]
    window_overflow: Int[Array, ""]
    overflow: Int[Array, ""]
    weight_reset: Bool[Array, ""]
    poses: Optional[Float[Array, "particles 3"]] = None
    ancestors: Optional[Int[Array, " particles"]] = None


class _ParticleOut(NamedTuple):
    pose: Float[Array, "3"]
    pose_cov: Float[Array, "3 3"]
    landmarks: LandmarkMap
    dlogw: Float[Array, ""]
    iterations: Int[Array, ""]
    result: Int[Array, ""]
    has_assoc: Bool[Array, ""]
    n_associated: Int[Array, ""]
    n_new: Int[Array, ""]
    window_overflow: Int[Array, ""]
    overflow: Int[Array, ""]
    n_landmarks: Int[Array, ""] | None
    n_confirmed: Int[Array, ""] | None
    noise: Float[Array, " d"]
    noise_count: Int[Array, ""]
    map_index: BlockIndex | None
    slots: Int[Array, ""] | None
    written: Int[Array, " m"]


class ParticleIn(NamedTuple):
    """One particle as it enters a segment (vmapped over the particles).

    Attributes:
        pose, pose_cov: the particle's pose and its covariance (the prior's start with
            ``static.prior.reset`` off).
        landmarks: the particle's map.
        eps: the particle's standard normal draw: the sampled pose is ``mean + chol(cov) eps``.
        noise, noise_count: the particle's adaptive measurement-noise variances and how many
            residuals they have seen (``static.adaptive_noise``; None: the configured noise).
        map_index: the spatial index of the particle's map (None: the map keeps none).
    """

    pose: Float[Array, "3"]
    pose_cov: Float[Array, "3 3"]
    landmarks: LandmarkMap
    eps: Float[Array, "3"]
    noise: Float[Array, " d"] | None = None
    noise_count: Int[Array, ""] | None = None
    map_index: BlockIndex | None = None


def particle_update(
    static: Static, params: Params, proposal: AbstractProposal, particle: ParticleIn, seg: SegmentIn
) -> _ParticleOut:
    """Prior, association, proposal, sampling, landmark updates and weight of one particle.

    With ``static.manage`` (landmark management, :mod:`._management`) only the rows matched to
    confirmed landmarks (all matched rows with ``map.use_tentative``) shape the proposal and the
    weight; a row that matched a tentative landmark then weighs as a new landmark does (``p0``).

    With ``static.adaptive_noise`` the scan is associated with the particle's adaptive noise;
    then each associated detection's residual at the prior updates it in order (eq. 11 of the
    NASRUKF paper with ``Gx P Gx' + Gm Sigma Gm'`` as the predicted covariance,
    :func:`~._srukf.adaptive_noise_rows`) and the proposal, landmark updates and weight use the result.
    """
    configured = jnp.diagonal(params.R)
    noise = configured if particle.noise is None else particle.noise
    noise_count = jnp.zeros((), jnp.int32) if particle.noise_count is None else particle.noise_count
    R = jnp.diag(noise) if static.adaptive_noise else params.R
    K = static.k_max
    dets = seg.dets
    dets = dets._replace(diam=jnp.zeros(K, dets.z.dtype) if dets.diam is None else dets.diam)
    x0, P0 = _prior(static, params, particle, seg)
    radius = params.max_range + params.window_margin
    W = static.window_size - K
    local, idx, window_overflow = over_slot_bucket(
        static,
        seg.slot_bucket,
        lambda b, lm, ix, x: gather_window(lm, x, W, radius, b, params.measurement, ix),
        particle.landmarks,
        particle.map_index,
        x0[:2],
    )
    m = _match(static, params, local, x0, P0, dets, R)
    det = Detections(dets.z, local.mean[m.ws], local.cov[m.ws], m.used, dets.kind)
    if static.adaptive_noise:
        noise, noise_count = _adapt_noise(params, x0, P0, det, m.existing, noise, noise_count)
        R = jnp.diag(noise)
    # The proposal, the sampled pose, the weight's likelihoods and the landmarks' updates and
    # starts: over the scan's bucket of rows.
    rows = rows_over_buckets(
        static, params, proposal, x0, P0, R, RowInputs(det, m.existing, m.ps, dets.mask), particle.eps
    )
    lm, index, overflow, (n_landmarks, n_confirmed, slots), written = update_map(
        static, params, (particle.landmarks, particle.map_index), (local, idx), m, rows, seg._replace(dets=dets)
    )
    has_assoc = jnp.any(m.used)
    return _ParticleOut(
        pose=rows.pose,
        pose_cov=rows.proposal.cov,
        landmarks=lm,
        dlogw=_log_weight(static, params, m, rows),
        iterations=rows.proposal.iterations,
        result=jnp.where(has_assoc, rows.proposal.result, 0),
        has_assoc=has_assoc,
        n_associated=jnp.sum(m.matched),
        n_new=jnp.sum(m.assoc.is_new),
        window_overflow=window_overflow,
        overflow=overflow,
        n_landmarks=n_landmarks,
        n_confirmed=n_confirmed,
        noise=noise,
        noise_count=noise_count,
        map_index=index,
        slots=slots,
        written=written,
    )


def _prior(
    static: Static, params: Params, particle: ParticleIn, seg: SegmentIn
) -> tuple[Float[Array, "3"], Float[Array, "3 3"]]:
    """The particle's prior over its pose after the segment's odometry: the shared relative prior
    placed at its pose, or its own prediction."""
    if seg.rel_prior is not None:
        x0, P0 = compose_prior(particle.pose, *seg.rel_prior)
    else:
        P_start = params.init_cov * jnp.eye(3) if static.prior.reset else particle.pose_cov
        x0, P0 = predict(particle.pose, P_start, seg.dt, seg.u, seg.dr_mask, params, static.prior)
    return computed_once((x0, P0))


def _match(
    static: Static,
    params: Params,
    local: LandmarkMap,
    x0: Float[Array, "3"],
    P0: Float[Array, "3 3"],
    dets: ScanDetections,
    R: Float[Array, "d d"],
) -> Matches:
    """The scan's association with the particle's local window, and which rows it makes used."""
    mp = params.map
    gating = Gating(params.gate, params.new_landmark, static.sequential, mp.use_diameter, mp.sigma_diameter)
    # With the row buckets (many particles per call), also the association over the window's
    # prefix: the same association, compiled three times, which pays off only where the particles'
    # arithmetic outweighs the longer compilation.
    assoc_fn = associate_window_prefix if static.row_buckets else associate
    assoc = assoc_fn(local, x0, P0, dets, R, gating, params.measurement)
    W, K = local.active.shape[0], dets.mask.shape[0]
    matched = assoc.slot >= 0
    existing = matched & (assoc.slot < W)
    ws = jnp.clip(assoc.slot, 0, W - 1)
    # Rows that shape the proposal and the weight: with management, those of confirmed landmarks.
    trusted = (local.confirmed[ws] | mp.use_tentative) if static.manage else jnp.ones(K, bool)
    return Matches(
        assoc=assoc,
        matched=matched,
        existing=existing,
        provisional=matched & ~existing,
        ws=ws,
        ps=jnp.clip(assoc.slot - W, 0, K - 1),
        trusted=trusted,
        used=existing & trusted,
    )


def _adapt_noise(
    params: Params,
    x0: Float[Array, "3"],
    P0: Float[Array, "3 3"],
    det: Detections,
    existing: Bool[Array, " k"],
    noise: Float[Array, " d"],
    noise_count: Int[Array, ""],
) -> tuple[Float[Array, " d"], Int[Array, ""]]:
    """The particle's adaptive noise after each associated detection's residual at the prior."""
    model = params.measurement
    z_prior, S_prior = predicted_measurements(x0, P0, det.mean, det.cov, jnp.diag(noise), model)
    _, noise, noise_count = adaptive_noise_rows(
        noise,
        noise_count,
        jax.vmap(model.innovation)(det.z, z_prior),
        jnp.diagonal(S_prior, axis1=1, axis2=2) - noise,
        existing,
        params.forgetting,
        params.noise_floor * jnp.diagonal(params.R),
    )
    return noise, noise_count


def _log_weight(static: Static, params: Params, m: Matches, rows: RowResults) -> Float[Array, ""]:
    """The particle's log-weight increment: the used rows' likelihoods, ``p0`` for each row that
    weighs as a new landmark, and the likelihood at the sampled pose of rows matching a landmark
    started earlier in the scan."""
    if static.manage:
        # A provisional landmark is tentative: its row weighs with its likelihood only with
        # use_tentative; unused rows that start or match a tentative landmark weigh as new (p0).
        use_tentative = params.map.use_tentative
        as_new = m.assoc.is_new | (m.existing & ~m.trusted) | (m.provisional & ~use_tentative)
        return (
            jnp.sum(jnp.where(m.used, rows.ll, 0.0))
            + jnp.sum(as_new) * params.log_p0
            + jnp.sum(jnp.where(m.provisional & use_tentative, rows.llp, 0.0))
        )
    return (
        jnp.sum(jnp.where(m.existing, rows.ll, 0.0))
        + jnp.sum(m.assoc.is_new) * params.log_p0
        + jnp.sum(jnp.where(m.provisional, rows.llp, 0.0))
    )


def _gather_small(fields: dict, skip: tuple[str, ...], axis_name: str) -> dict:
    """All-gather (tiled, inside ``shard_map``) every field but those in ``skip`` in one collective: the
    fields are packed as floating-point columns of one ``(particles, columns)`` array (the
    integer and boolean fields are small counts, exact as floats) and unpacked after."""
    names = [f for f in fields if f not in skip and fields[f] is not None]
    cols = [fields[f].reshape(fields[f].shape[0], -1).astype(float) for f in names]
    packed = jax.lax.all_gather(jnp.concatenate(cols, axis=1), axis_name, tiled=True)
    out, i = {}, 0
    for f, c in zip(names, cols):
        a = fields[f]
        out[f] = packed[:, i : i + c.shape[1]].reshape((-1,) + a.shape[1:]).astype(a.dtype)
        i += c.shape[1]
    return out


def weighted_mean_pose(pose: Float[Array, "n 3"], log_w: Float[Array, " n"]) -> Float[Array, "3"]:
    """Weighted mean pose with a circular mean for the heading."""
    w = jnp.exp(normalise(log_w))
    return jnp.concatenate([w @ pose[:, :2], circular_mean(pose[:, 2], w)[None]])


def filter_step(
    static: Static,
    params: Params,
    proposal: AbstractProposal,
    state: FilterState,
    seg: Segments,
    valid: Bool[Array, ""] | bool = True,
    rel_prior: tuple[Float[Array, "3"], Float[Array, "3 3"]] | None = None,
) -> tuple[FilterState, StepOutput]:
    """Advance the particle set through one segment.

    ``rel_prior``: the segment's :func:`relative_prior`, used with ``static.prior.reset``
    (computed here when None; :func:`filter_scan` computes every segment's before its scan).

    A padding segment (``valid`` False; it has no detections and ``dt = 0``) leaves the state
    unchanged: its maps are untouched already, and the poses, weights and resampling decision
    are masked here (small arrays), which is cheaper than a conditional around the whole step.

    With ``static.devices > 1`` the whole step runs under ``shard_map``: each device keeps and
    updates its share of the particles' maps, while the poses, weights and key are replicated;
    the particles' small outputs are gathered in one collective per step, and the maps cross
    devices only when the particles are resampled.
    """
    if not static.prior.reset or not params.motion.rigid:
        rel_prior = None  # a model that is not rigid: every particle's prior is predicted from its own pose
    elif rel_prior is None:
        rel_prior = relative_prior(seg.dt, seg.u, seg.dr_mask, params, static.prior)
    if static.devices == 1:
        return _step(static, None, params, proposal, state, seg, valid, rel_prior)
    mesh = Mesh(np.array(jax.devices()[: static.devices]), ("particles",))
    part, rep = PartitionSpec("particles"), PartitionSpec()
    spec = jax.tree.map(lambda _: rep, state)
    spec = spec._replace(
        particles=spec.particles._replace(
            landmarks=jax.tree.map(lambda _: part, state.particles.landmarks),
            map_index=jax.tree.map(lambda _: part, state.particles.map_index),
        )
    )
    step = functools.partial(_step, static, "particles")
    return jax.shard_map(
        step, mesh=mesh, in_specs=(rep, rep, spec, rep, rep, rep), out_specs=(spec, rep), check_vma=False
    )(params, proposal, state, seg, jnp.asarray(valid), rel_prior)


def _shared(
    static: Static,
    params: Params,
    seg: Segments,
    scan: Int[Array, ""],
    valid: Bool[Array, ""],
    rel_prior: tuple[Float[Array, "3"], Float[Array, "3 3"]] | None,
    in_use: Int[Array, ""],
) -> SegmentIn:
    """What the segment gives every particle: its odometry and detections, and the smallest map
    prefix holding every active landmark of this device's particles (``in_use`` slots; under a
    sweep's vmap: of the batch), where the local windows are searched."""
    slot_bucket = batch_max(jnp.sum(in_use > jnp.asarray(static.slot_buckets[:-1], jnp.int32)).astype(jnp.int32))
    dets = ScanDetections(
        seg.z,
        seg.z_mask,
        seg.diam,
        static.association.detection_ids(seg.z_id),
        seg.z_kind if is_composite(params.measurement) else None,
    )
    return SegmentIn(seg.dt, seg.u, seg.dr_mask, dets, valid & seg.is_scan, scan, rel_prior, slot_bucket, in_use)


def _slots_in_use(lm: LandmarkMap, before: Int[Array, " n"] | None, bound: Int[Array, ""]) -> Int[Array, ""]:
    """One past the highest active slot of the particles' maps ``lm`` after the step (every active
    one lies below ``bound``); split over devices, the highest of the particles' before resampling
    (``before``), which bounds it too since resampling copies maps."""
    return prefix_max(lm.active, bound) if before is None else jnp.max(before)


def _take_maps(
    flag: Bool[Array, ""], anc: Int[Array, " n"], particles: Particles, used: Int[Array, ""]
) -> tuple[LandmarkMap, Int[Array, "n blocks"] | None]:
    """The maps (and their block versions) after a resampling to ancestors ``anc`` if ``flag``:
    with block versions, only the blocks that differ from the ancestor's are copied; without,
    the slots below ``used``."""
    if particles.map_version is None:
        return take_prefix_if(flag, anc, particles.landmarks, used), None
    return take_changed_blocks(flag, anc, particles.landmarks, particles.map_version, used)


def _reweight(
    log_w: Float[Array, " n"], dlogw: Float[Array, " n"], valid: Bool[Array, ""]
) -> tuple[Float[Array, " n"], Bool[Array, ""]]:
    """The particles' normalised log-weights after a segment's increments (unchanged for padding),
    and whether any was finite (else they are reset to uniform)."""
    n = log_w.shape[0]
    new = log_w + dlogw
    finite = jnp.any(jnp.isfinite(new))
    new = jnp.where(jnp.isnan(new), -jnp.inf, new)
    new = jnp.where(finite, normalise(new), jnp.full((n,), -jnp.log(n)))
    return jnp.where(valid, new, log_w), finite


def _record(
    out: _ParticleOut,
    log_w: Float[Array, " n"],
    best: Int[Array, ""],
    valid: Bool[Array, ""],
    finite: Bool[Array, ""],
    resample_threshold: Float[Array, ""],
) -> StepOutput:
    """The segment's record from every particle's outputs and the new weights."""
    n = log_w.shape[0]
    ess = effective_sample_size(log_w)
    if out.n_landmarks is None or out.n_confirmed is None:  # one device: the best particle's map
        n_landmarks, n_confirmed = landmark_counts(jax.tree.map(lambda a: a[best], out.landmarks))
    else:  # counted per particle where the maps are (the best one's would cross devices)
        n_landmarks, n_confirmed = out.n_landmarks[best], out.n_confirmed[best]
    return StepOutput(
        best_pose=out.pose[best],
        mean_pose=weighted_mean_pose(out.pose, log_w),
        ess=ess,
        resampled=valid & (ess < resample_threshold * n),
        n_landmarks=n_landmarks,
        n_confirmed=n_confirmed,
        iterations=jnp.sum(jnp.where(out.has_assoc, out.iterations, 0)) / jnp.maximum(jnp.sum(out.has_assoc), 1),
        n_capped=jnp.sum(out.result == 1).astype(jnp.int32),
        n_nonfinite=jnp.sum(out.result == 2).astype(jnp.int32),
        n_associated=jnp.mean(out.n_associated.astype(float)),
        n_new=jnp.mean(out.n_new.astype(float)),
        window_overflow=jnp.max(out.window_overflow).astype(jnp.int32),
        overflow=jnp.sum(out.overflow).astype(jnp.int32),
        weight_reset=~finite,
    )


def _step(
    static: Static,
    axis: str | None,
    params: Params,
    proposal: AbstractProposal,
    state: FilterState,
    seg: Segments,
    valid: Bool[Array, ""] | bool,
    rel_prior,
) -> tuple[FilterState, StepOutput]:
    """:func:`filter_step` on one device; ``axis`` names the device axis when the maps are split
    (``state.particles.landmarks`` then holds this device's share, everything else all particles)."""
    n = static.n_particles
    key, k_part, k_res = jax.random.split(state.key, 3)
    # All particles' standard normal draws in one call (cheaper than a key per particle).
    eps = jax.random.normal(k_part, (n, 3), dtype=state.particles.pose.dtype)
    p = state.particles
    valid = jnp.asarray(valid)
    if axis is None:
        mine = lambda a: a  # noqa: E731
    else:
        share = n // static.devices
        first = jax.lax.axis_index(axis) * share
        mine = lambda a: jax.lax.dynamic_slice_in_dim(a, first, share)  # noqa: E731

    in_use = batch_max(state.slots)
    shared = _shared(static, params, seg, state.scan, valid, rel_prior, in_use)
    particle = ParticleIn(
        mine(p.pose), mine(p.pose_cov), p.landmarks, mine(eps), mine(p.noise), mine(p.noise_count), p.map_index
    )
    out = jax.vmap(particle_update, (None, None, None, 0, None))(static, params, proposal, particle, shared)
    if axis is not None:
        out = out._replace(**_gather_small(out._asdict(), ("landmarks", "map_index", "written"), axis))
    out = out._replace(
        pose=jnp.where(valid, out.pose, p.pose),
        pose_cov=jnp.where(valid, out.pose_cov, p.pose_cov),
        dlogw=jnp.where(valid, out.dlogw, 0.0),
        noise=jnp.where(valid, out.noise, p.noise),
        noise_count=jnp.where(valid, out.noise_count, p.noise_count),
    )
    log_w, finite = _reweight(p.log_w, out.dlogw, valid)
    best = jnp.argmax(log_w).astype(jnp.int32)
    version = None if p.map_version is None else mark_written(p.map_version, out.written, state.resample_count)
    particles = Particles(
        out.pose, out.pose_cov, log_w, out.landmarks, out.noise, out.noise_count, out.map_index, version
    )
    record = _record(out, log_w, best, valid, finite, params.resample_threshold)

    def ancestors(parts):
        anc = static.resampler(k_res, parts.log_w)
        # A copy of the best particle if it survived (always, for systematic and residual
        # resampling, since its weight is >= 1/N), else the best survivor.
        return anc, jnp.argmax(parts.log_w[anc]).astype(jnp.int32)

    uniform = jnp.full((n,), -jnp.log(n), dtype=particles.log_w.dtype)
    # filter.estimate: path records the genealogy: the resampling's ancestors, identity without it.
    track = static.estimate.records_path
    if axis is None:
        # A conditional copy; under a sweep's vmap each run copies its maps only when it resamples.
        # The ancestors are drawn at every step (one uniform and a search over the weights, well
        # under a microsecond) so that only the copy is conditional. Uniform weights taken by
        # ancestor are uniform, so they can be set before the copy.
        anc, best_after = ancestors(particles)
        log_w = jnp.where(record.resampled, uniform, particles.log_w)
        # Of the maps, only the slots that can hold a landmark after this step are copied: those
        # below the step's start plus one new landmark per detection.
        lms, version = _take_maps(record.resampled, anc, particles, in_use + static.k_max)
        rest = take_if(
            record.resampled,
            anc,
            particles._replace(log_w=log_w)._asdict() | {"landmarks": None, "map_version": None},
        )
        particles = Particles(**rest | {"landmarks": lms, "map_version": version})
        best = jnp.where(record.resampled, best_after, best)
        parents = jnp.where(record.resampled, anc, jnp.arange(n, dtype=anc.dtype)) if track else None
    else:

        def do_resample(args):
            parts, _, _ = args
            anc, best_after = ancestors(parts)

            # This device's new particles may descend from any device's: gather all maps (of a
            # long map, block by block over the slots that can hold a landmark after this step;
            # a short one whole, in one collective per field).
            def take(block):
                return jax.tree.map(lambda a: jax.lax.all_gather(a, axis, tiled=True)[mine(anc)], block)

            short = static.capacity < SEARCH_FROM
            lms = take(parts.landmarks) if short else map_prefix(take, parts.landmarks, in_use + static.k_max, axis=1)
            parts = jax.tree.map(lambda a: a[anc], parts._replace(landmarks=None, map_index=None))._replace(
                landmarks=lms, map_index=take(parts.map_index)
            )
            return parts._replace(log_w=uniform), best_after, (anc if track else None)

        particles, best, parents = jax.lax.cond(
            record.resampled,
            do_resample,
            lambda a: a,
            (particles, best, jnp.arange(n, dtype=jnp.int32) if track else None),
        )
    if track:
        record = record._replace(poses=out.pose, ancestors=parents)
    slots = _slots_in_use(particles.landmarks, out.slots, in_use + static.k_max)
    new_state = FilterState(
        particles=particles,
        key=key,
        best=best,
        resample_count=state.resample_count + record.resampled.astype(jnp.int32),
        overflow=state.overflow + record.overflow,
        scan=state.scan + (valid & seg.is_scan).astype(jnp.int32),
        slots=slots,
    )
    return new_state, record
