"""NASRUKF FastSLAM with the paper's per-beam measurements on line and arc features
(``nasrukf.measurement: beams``; docs/method/nasrukf-beams.md).

The NASRUKF paper measures a feature one laser range at a time: ``rho(k)`` along the known beam
angle ``phi(k)`` against a line (eq. 14-15) or an arc (eq. 16-17). Its joint states are pose +
line and pose + arc. This module runs that filter on the segments of ``data.detections:
laser_beams`` (:mod:`nanoslam_jax.frontend._beams`: one detection per beam, ``z = (range, phi)``, the
beams of a front-end segment or arc sharing ``z_id``; ``diam > 0`` on an arc), with the
representation, time update, fusion and feedback of :mod:`._nasrukf`. Per segment
(:func:`beam_step`):

1. **Time update** of the pose through the odometry (or the random walk), with the adaptive
   process noise, and of every feature's gain (:func:`~._nasrukf.pose_time_update`,
   :func:`~._nasrukf.propagate_features`). During **static initialisation** (the first
   ``nasrukf.static_scans`` scans while the odometry reports no motion) the pose is held.
2. **Association by predicted range**: each beam's range is predicted against every feature at the
   prior pose (eq. 14-16 in the line's form, eq. 16's nearest root); the beam goes to the feature
   whose prediction is nearest its range, if within ``nasrukf.beam_gate``.
3. **Measurement update** of every feature with beams (vmapped): its joint state's beams stacked
   as one vector measurement (at most ``nasrukf.beams_per_feature``, evenly spread), the
   square-root UKF update of eq. 10-12 (:func:`~._nasrukf_beams_update.stacked_update`). With ``noise.adaptive`` the beam
   noise is re-estimated with eq. 11's weights from each feature's residuals in turn: after the
   updates from the residuals ``z - h(x+)`` plus their predicted variance (``nasrukf.noise_residual:
   posterior``), or as eq. 11 before each update from the innovations less their predicted
   variance (``innovation``).
4. **Fusion** of the updated joint states' poses (eq. 4-5, :func:`~._nasrukf.fuse_poses`, features
   with at least ``nasrukf.new_feature_hits`` earlier scans) and **feedback** to every feature; the
   adaptive process noise from the fused corrections (as :mod:`._nasrukf`).
5. **New features** from the front-end segments and arcs whose beams no feature explains (fewer
   than half associated): stored as the paper's new-feature data, a feature created once
   ``nasrukf.n_new`` data of the same line or arc are stored (:func:`candidate_update`), from the
   group's own fit (:func:`fit_group`) through the square-root unscented transform of (pose, fit).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from nanoslam_jax.lib._linalg import mv
from nanoslam_jax.models import wrap_angle
from nanoslam_jax.models._lines import beam_range_circle, line_to_world
from nanoslam_jax.lib.quadrature import Unscented
from nanoslam_jax.methods.gaussian._nasrukf_joint import fused_process_update
from nanoslam_jax.methods.gaussian._nasrukf_joint import (
    _minus,
    fuse_poses,
    joint_sqrt,
    pose_time_update,
    propagate_features,
    to_conditional,
)
from nanoslam_jax.methods.gaussian._nasrukf_beams_state import (
    ARC,
    LINE,
    BeamFeatures,
    Candidates,
    GroupFit,
    NasrukfBeamState,
    candidate_update,
    fit_group,
    line_param,
)
from nanoslam_jax.methods.gaussian._nasrukf_beams_update import (
    FeatureBeams,
    innovation_rows,
    line_ranges,
    posterior_rows,
    projected_rows,
    run_updates,
    select_beams,
)
from nanoslam_jax.methods._method_settings import nasrukf_params, nasrukf_static
from nanoslam_jax.methods._params import Params, Static
from nanoslam_jax.methods.gaussian._srukf import (
    adaptive_noise_rows,
    predict_measurement,
    process_noise_basis,
    srukf_transform,
)
from nanoslam_jax.methods.gaussian._gaussian import GaussianStepOutput

#: Odometry below this (m/s, rad/s) is no motion (static initialisation).
AT_REST = 1e-9
#: New lines (and arcs) created in one scan at most; a further one is stored and starts in a later scan.
NEW_PER_SCAN = 4


def _rule(params: Params) -> Unscented:
    return Unscented(params.ut_alpha, params.ut_beta, params.ut_kappa)


def _zeros_like(shapes):
    """Zeros of the shapes and dtypes of a pytree of :class:`jax.ShapeDtypeStruct`."""
    return jax.tree.map(lambda a: jnp.zeros(a.shape, a.dtype), shapes)


def _busiest(counts: Array, active: Bool[Array, " c"], size: int) -> tuple[Array, Bool[Array, " size"]]:
    """The ``size`` active slots with the most associated beams (indices) and which of them have any."""
    top, idx = jax.lax.top_k(jnp.where(active, counts, -1), size)
    return idx, top > 0


def _line_angles(form: str) -> tuple[int, ...]:
    """The angle components of a line's joint state (pose heading, and the normal form's angle)."""
    return (2, 4) if form == "normal" else (2,)


def _h_line(form: str):
    """A line's joint state's predicted range along beam ``p`` (0 where the beam misses it), as
    ``h(y, p, vertical)``."""

    def h(yy, p, v):
        rr, hit = line_ranges(yy[:3], p, yy[3:], v, form)
        return jnp.where(hit, rr, 0.0)

    return h


def _h_arc(yy, p, v):
    """An arc's joint state's predicted range along beam ``p`` (0 where the beam misses it)."""
    rr, hit = beam_range_circle(yy[:3], p, yy[3:])
    return jnp.where(hit, rr, 0.0)


class _Prior(NamedTuple):
    """The time update's result.

    Attributes:
        x, S: the prior pose (mean, lower square root).
        lines, arcs: the features propagated with it.
        basis: the process-noise basis accumulated so far.
        static_now: the pose is held in this segment (static initialisation).
        moving: static initialisation is over.
    """

    x: Float[Array, "3"]
    S: Float[Array, "3 3"]
    lines: BeamFeatures
    arcs: BeamFeatures
    basis: Array
    static_now: Bool[Array, ""]
    moving: Bool[Array, ""]


class _Beams(NamedTuple):
    """A scan's beams and their association by predicted range.

    Attributes:
        r, phi, diam: each beam's range, angle and its front-end feature's diameter (> 0 on an arc).
        ok: the real beams.
        best: each beam's nearest feature by predicted range (lines, then arcs).
        assoc: the beams associated with it (within ``nasrukf.beam_gate``).
        group: each beam's front-end feature within the scan (clipped into the ``G`` groups).
        n_group, n_assoc: per group, its real beams and those associated.
    """

    r: Float[Array, " k"]
    phi: Float[Array, " k"]
    diam: Float[Array, " k"]
    ok: Bool[Array, " k"]
    best: Array
    assoc: Bool[Array, " k"]
    group: Array
    n_group: Array
    n_assoc: Array


class _Side(NamedTuple):
    """The features of one kind (lines or arcs) the scan updates.

    Attributes:
        feats: the window of features (those with the most associated beams).
        slots: their slots among that kind's.
        seen: which of them have beams.
        dat: their stacked measurements.
    """

    feats: BeamFeatures
    slots: Array
    seen: Bool[Array, " w"]
    dat: FeatureBeams


class _Posterior(NamedTuple):
    """A window's joint states after their updates (means ``y``, lower square roots ``L``) and
    which of them were updated (``upd``: with beams, in the window)."""

    y: Float[Array, "w n"]
    L: Float[Array, "w n n"]
    upd: Bool[Array, " w"]


class _Fused(NamedTuple):
    """The global pose after fusion (mean ``x``, lower square root ``S``; the prior while the pose is
    held) and the process-noise estimate (``Lambda``, its count, the basis) after it."""

    x: Float[Array, "3"]
    S: Float[Array, "3 3"]
    process_scale: Array
    process_count: Array
    basis: Array


class _NewData(NamedTuple):
    """The scan's new-feature data: each group's fits (:class:`GroupFit`), whether it is an arc, and
    whether it starts a feature now (the paper's N_new rule)."""

    fits: GroupFit
    is_arc: Bool[Array, " g"]
    starts: Bool[Array, " g"]


def _time_update(static: Static, params: Params, state: NasrukfBeamState, seg) -> _Prior:
    """The pose's time update through the segment's DR pieces (with the adaptive process noise) and
    every feature's gain; during static initialisation the pose and the features are held."""
    ns, bp = nasrukf_static(static), nasrukf_params(params).beams
    assert bp is not None, "nasrukf.measurement beams needs params.method.beams"
    at_rest = jnp.all(~seg.dr_mask | jnp.all(jnp.abs(seg.u) < AT_REST, axis=-1))
    static_now = ~state.moving & at_rest & (state.scan < bp.static_scans)
    moving = state.moving | ~static_now
    scale_sqrt = jnp.linalg.cholesky(state.process_scale) if ns.adaptive_process else None
    xp, Sp, T, D = pose_time_update(state.pose, state.pose_sqrt, seg.dt, seg.u, seg.dr_mask, params, scale_sqrt)
    x0 = jnp.where(static_now, state.pose, xp)
    S0 = jnp.where(static_now, state.pose_sqrt, Sp)
    lines0 = propagate_features(state.lines, T, D)  # type: ignore[arg-type]
    arcs0 = propagate_features(state.arcs, T, D)  # type: ignore[arg-type]
    lines0 = jax.tree.map(lambda a, b: jnp.where(static_now, a, b), state.lines, lines0)
    arcs0 = jax.tree.map(lambda a, b: jnp.where(static_now, a, b), state.arcs, arcs0)
    basis = state.process_basis
    if ns.adaptive_process:
        moved = process_noise_basis(basis, state.pose, seg.dt, seg.u, seg.dr_mask, params.motion)
        basis = jnp.where(static_now, basis, moved)
    return _Prior(x0, S0, lines0, arcs0, basis, static_now, moving)


def _associate(static: Static, params: Params, prior: _Prior, seg, valid: Bool[Array, ""]) -> _Beams:
    """Each beam's range predicted against every feature at the prior pose (eq. 14-16); a beam goes
    to the feature whose prediction is nearest its range, if within ``nasrukf.beam_gate``."""
    ns, bp = nasrukf_static(static), nasrukf_params(params).beams
    assert bp is not None, "nasrukf.measurement beams needs params.method.beams"
    form, G, x0 = ns.line_form, ns.groups, prior.x
    lines0, arcs0 = prior.lines, prior.arcs
    r, phi = seg.z[:, 0], seg.z[:, 1]
    ok = seg.z_mask & valid
    rl, hl = jax.vmap(lambda m, v: line_ranges(x0, phi, m, v, form))(lines0.mean, lines0.vertical)
    ra, ha = jax.vmap(lambda m: beam_range_circle(x0, phi, m))(arcs0.mean)
    res = jnp.concatenate(
        [
            jnp.where(hl & lines0.active[:, None], jnp.abs(r[None] - rl), jnp.inf),
            jnp.where(ha & arcs0.active[:, None], jnp.abs(r[None] - ra), jnp.inf),
        ]
    )
    best = jnp.argmin(res, axis=0)
    assoc = ok & (jnp.min(res, axis=0) < bp.beam_gate)
    group = jnp.clip(seg.z_id, 0, G - 1)
    n_group = jax.ops.segment_sum(ok.astype(jnp.int32), group, G)
    n_assoc = jax.ops.segment_sum(assoc.astype(jnp.int32), group, G)
    return _Beams(r, phi, seg.diam, ok, best, assoc, group, n_group, n_assoc)


def _feature_update(feats: BeamFeatures, gid, prior: _Prior, beams: _Beams, size: int, h_of, rule) -> FeatureBeams:
    """Predictions and the data of the stacked updates of the features ``feats`` (a window of the
    slots; ``gid``: their indices among all features, lines then arcs), vmapped over them: at most
    ``size`` of each one's associated beams (:func:`select_beams`), its joint state at the prior
    pose and the sigma-point prediction of ``h_of(y, phi, vertical)``."""
    idx, use = jax.vmap(lambda j: select_beams(beams.assoc & (beams.best == j), size))(gid)
    zs, ps = beams.r[idx], beams.phi[idx]
    ys = jax.vmap(lambda m: jnp.concatenate([prior.x, m]))(feats.mean)
    Ls = jax.vmap(joint_sqrt, (None, 0, 0))(prior.S, feats.gain, feats.sqrt)

    def pred_one(y, L, p, v, u):
        return predict_measurement(y, L, lambda yy: jnp.where(u, h_of(yy, p, v), 0.0), rule)

    preds = jax.vmap(pred_one)(ys, Ls, ps, feats.vertical, use)
    return FeatureBeams(ys, Ls, zs, ps, use, preds)


def _windows(static: Static, params: Params, prior: _Prior, beams: _Beams) -> tuple[_Side, _Side]:
    """The lines and the arcs the scan updates (at most ``filter.window`` of each, those with the
    most associated beams) with their stacked measurements."""
    ns = nasrukf_static(static)
    form, rule, M = ns.line_form, _rule(params), ns.beams_per_feature
    lines0, arcs0 = prior.lines, prior.arcs
    n_lines = lines0.mean.shape[0]
    counts = jax.ops.segment_sum(beams.assoc.astype(jnp.int32), beams.best, n_lines + arcs0.mean.shape[0])
    wL, seenL = _busiest(counts[:n_lines], lines0.active, min(static.window, n_lines))
    wA, seenA = _busiest(counts[n_lines:], arcs0.active, min(static.window, arcs0.mean.shape[0]))
    subL = jax.tree.map(lambda a: a[wL], lines0)
    subA = jax.tree.map(lambda a: a[wA], arcs0)
    Ldat = _feature_update(subL, wL, prior, beams, M, _h_line(form), rule)
    Adat = _feature_update(subA, n_lines + wA, prior, beams, M, _h_arc, rule)
    return _Side(subL, wL, seenL, Ldat), _Side(subA, wA, seenA, Adat)


def _stacked_updates(
    static: Static, params: Params, state: NasrukfBeamState, lines: _Side, arcs: _Side
) -> tuple[_Posterior, _Posterior, Float[Array, "1"], Int[Array, ""]]:
    """Every windowed feature's stacked update, with the beam noise estimated under
    ``noise.adaptive`` (eq. 11's weights, a row per feature): before the updates from the
    innovations (``nasrukf.noise_residual: innovation``, less their predicted variance, or
    ``projected``), or after them from the residuals (``posterior``).

    Returns:
        The lines' and the arcs' updated joint states, and the noise estimate and its count.
    """
    ns, bp = nasrukf_static(static), nasrukf_params(params).beams
    assert bp is not None, "nasrukf.measurement beams needs params.method.beams"
    form, rule = ns.line_form, _rule(params)
    Ldat, Adat = lines.dat, arcs.dat
    noise, noise_count = state.noise, state.noise_count
    updL, updA = jnp.any(Ldat.use, axis=1), jnp.any(Adat.use, axis=1)
    rows_use = jnp.concatenate([updL, updA])
    floor = params.noise_floor * jnp.square(bp.sigma_beam)[None]
    before_update = static.adaptive_noise and ns.noise_residual != "posterior"
    if before_update:  # eq. 11 before each update: the innovations less their predicted variance, or projected
        if ns.noise_residual == "projected":
            (nuL, pvL, okL), (nuA, pvA, okA) = (projected_rows(d, noise[0]) for d in (Ldat, Adat))
        else:
            (nuL, pvL, okL), (nuA, pvA, okA) = innovation_rows(Ldat), innovation_rows(Adat)
        rows, noise, noise_count = adaptive_noise_rows(
            noise,
            noise_count,
            jnp.concatenate([nuL, nuA]),
            jnp.concatenate([pvL, pvA]),
            rows_use & jnp.concatenate([okL, okA]),
            params.forgetting,
            floor,
        )
        varL, varA = rows[: lines.slots.shape[0], 0], rows[lines.slots.shape[0] :, 0]
    else:
        varL = jnp.broadcast_to(noise[0], updL.shape)
        varA = jnp.broadcast_to(noise[0], updA.shape)
    yL, LL = run_updates(Ldat, varL, _line_angles(form))
    yA, LA = run_updates(Adat, varA, (2,))
    if static.adaptive_noise and not before_update:  # eq. 11's weights on the residuals after the update
        eL = posterior_rows(yL, LL, Ldat, _h_line(form), lines.feats.vertical, rule)
        eA = posterior_rows(yA, LA, Adat, _h_arc, arcs.feats.vertical, rule)
        _, noise, noise_count = adaptive_noise_rows(
            noise,
            noise_count,
            jnp.concatenate([eL[0], eA[0]]),
            -jnp.concatenate([eL[1], eA[1]]),
            rows_use,
            params.forgetting,
            floor,
        )
    return _Posterior(yL, LL, updL & lines.seen), _Posterior(yA, LA, updA & arcs.seen), noise, noise_count


def _fuse(
    static: Static,
    params: Params,
    state: NasrukfBeamState,
    prior: _Prior,
    lines: _Side,
    arcs: _Side,
    post_lines: _Posterior,
    post_arcs: _Posterior,
) -> _Fused:
    """The global pose fused from the updated joint states of the features with at least
    ``nasrukf.new_feature_hits`` earlier scans (eq. 4-5, :func:`~._nasrukf.fuse_poses`; the prior
    while the pose is held), and under ``nasrukf.adaptive_process`` the estimated ``Q`` from their
    corrections (as :mod:`._nasrukf`)."""
    ns, nk = nasrukf_static(static), nasrukf_params(params)
    x0, S0, basis, static_now = prior.x, prior.S, prior.basis, prior.static_now
    fuseL = post_lines.upd & (lines.feats.hits >= nk.new_feature_hits)
    fuseA = post_arcs.upd & (arcs.feats.hits >= nk.new_feature_hits)
    xs = jnp.concatenate([post_lines.y[:, :3], post_arcs.y[:, :3]])
    Lp = jnp.concatenate([post_lines.L[:, :3, :3], post_arcs.L[:, :3, :3]])
    use = jnp.concatenate([fuseL, fuseA])
    x_f, S_f = fuse_poses(x0, S0, xs, Lp, use)
    x_g = jnp.where(static_now, x0, x_f)
    S_g = jnp.where(static_now, S0, S_f)
    process = (state.process_scale, state.process_count, basis)
    if ns.adaptive_process:  # no estimate while the pose is held
        use = use & ~static_now
        process = fused_process_update(process, xs, Lp, use, x0, S0, nk.process_forgetting, nk.process_floor)
    process_scale, process_count, basis = process
    return _Fused(x_g, S_g, process_scale, process_count, basis)


def _feedback(
    feats: BeamFeatures,
    win: Array,
    post: _Posterior,
    angle_idx: Sequence[int],
    x_g: Float[Array, "3"],
    x0: Float[Array, "3"],
) -> BeamFeatures:
    """Every feature of one kind fed back to the fused pose ``x_g`` from the prior ``x0`` (moved
    through its gain); the updated ones (slots ``win`` where ``post.upd``) take their updated
    conditionals and one more hit; ``angle_idx``: parameters wrapped as angles."""
    mean, gain, sqrt = jax.vmap(to_conditional, (0, 0, 0, None))(post.y[:, :3], post.y[:, 3:], post.L, x_g)
    cap = feats.mean.shape[0]
    tgt = jnp.where(post.upd, win, cap)
    feats = feats._replace(mean=feats.mean + mv(feats.gain, _minus(x_g, x0)))
    feats = feats._replace(
        mean=feats.mean.at[tgt].set(mean, mode="drop"),
        gain=feats.gain.at[tgt].set(gain, mode="drop"),
        sqrt=feats.sqrt.at[tgt].set(sqrt, mode="drop"),
        hits=feats.hits.at[tgt].add(1, mode="drop"),
    )
    for i in angle_idx:
        feats = feats._replace(mean=feats.mean.at[:, i].set(wrap_angle(feats.mean[:, i])))
    return feats


def _new_data(
    static: Static,
    params: Params,
    state: NasrukfBeamState,
    beams: _Beams,
    valid: Bool[Array, ""],
    x_g: Float[Array, "3"],
    noise: Float[Array, "1"],
) -> tuple[Candidates, _NewData]:
    """The front-end segments and arcs no feature explains (at least 3 beams, fewer than half of
    them associated), fitted (:func:`fit_group`, only in a scan that has any) with the beam noise
    ``noise``, in the world at the fused pose ``x_g``, stored as new-feature data
    (:func:`candidate_update`).

    Returns:
        The stored data after the scan and the scan's :class:`_NewData`.
    """
    ns, bp = nasrukf_static(static), nasrukf_params(params).beams
    assert bp is not None, "nasrukf.measurement beams needs params.method.beams"
    G, ok, group, r, phi = ns.groups, beams.ok, beams.group, beams.r, beams.phi
    members = ok[None, :] & (group[None, :] == jnp.arange(G)[:, None])
    is_arc = jax.ops.segment_max(jnp.where(ok, beams.diam, 0.0), group, G) > 0
    unexplained = (beams.n_group >= 3) & (2 * beams.n_assoc < beams.n_group)
    # the fits are read only for the unexplained groups: a scan with none skips them
    fit_all = lambda: jax.vmap(fit_group, (None, None, 0, None))(r, phi, members, noise[0])  # noqa: E731
    fits = jax.lax.cond(jnp.any(unexplained & valid), fit_all, lambda: _zeros_like(jax.eval_shape(fit_all)))
    world_line = jax.vmap(line_to_world, (0, None))(fits.line, x_g)
    c, s = jnp.cos(x_g[2]), jnp.sin(x_g[2])
    world_arc = jnp.stack(
        [
            x_g[0] + c * fits.arc[:, 0] - s * fits.arc[:, 1],
            x_g[1] + s * fits.arc[:, 0] + c * fits.arc[:, 1],
            fits.arc[:, 2],
        ],
        axis=1,
    )
    kind = jnp.where(is_arc, ARC, LINE)
    param = jnp.where(is_arc[:, None], world_arc, jnp.pad(world_line, ((0, 0), (0, 1))))
    cands, starts = candidate_update(
        state.candidates, unexplained & valid, kind, param, state.scan, bp.n_new, bp.merge_gate
    )
    return cands, _NewData(fits, is_arc, starts)


def _init_line(fused: _Fused, z, cov, form: str, rule: Unscented):
    """A new line's joint state from its fit ``z`` (robot frame) of covariance ``cov``: the
    square-root unscented transform of (fused pose, fit) into the state's form, and whether it is
    vertical (the paper's form)."""

    def place_line(p, w):
        line = line_to_world(z + w, p[:3])
        m, _ = line_param(line, form)
        return jnp.concatenate([p[:3], m])

    _, vertical = line_param(line_to_world(z, fused.x), form)
    nsq = jnp.linalg.cholesky(cov + 1e-18 * jnp.eye(2))
    y, L = srukf_transform(fused.x, fused.S, place_line, nsq, rule, angles=_line_angles(form))
    return y, L, vertical


def _init_arc(fused: _Fused, z, cov, rule: Unscented):
    """A new arc's joint state from its fit ``z = (xc, yc, R)`` (robot frame) of covariance ``cov``:
    the square-root unscented transform of (fused pose, fit) into the world."""

    def place_arc(p, w):
        zz = z + w
        cc, ss = jnp.cos(p[2]), jnp.sin(p[2])
        return jnp.concatenate(
            [p[:3], jnp.stack([p[0] + cc * zz[0] - ss * zz[1], p[1] + ss * zz[0] + cc * zz[1], zz[2]])]
        )

    nsq = jnp.linalg.cholesky(cov + 1e-12 * jnp.eye(3))
    return srukf_transform(fused.x, fused.S, place_arc, nsq, rule, angles=(2,))


def _insert(feats: BeamFeatures, create, y, L, vertical, x_g: Float[Array, "3"], scan: Int[Array, ""]):
    """The joint states ``(y, L)`` where ``create`` made features of one kind in the free slots (fed
    back to the fused pose ``x_g``, born at ``scan``); the features, and those added and those
    dropped for want of a slot."""
    cap, k = feats.mean.shape[0], create.shape[0]
    free = jnp.nonzero(~feats.active, size=k, fill_value=cap)[0]
    rank = jnp.cumsum(create) - 1
    dest = jnp.where(create, free[jnp.clip(rank, 0, k - 1)], cap)
    mean, gain, sqrt = jax.vmap(to_conditional, (0, 0, 0, None))(y[:, :3], y[:, 3:], L, x_g)
    new = BeamFeatures(
        mean, gain, sqrt, vertical, jnp.ones(k, bool), jnp.ones(k, jnp.int32), jnp.full(k, scan, jnp.int32)
    )
    feats = jax.tree.map(lambda a, b: a.at[dest].set(b, mode="drop"), feats, new)
    return feats, jnp.sum(create & (dest < cap)), jnp.sum(create & (dest >= cap))


def _create(
    static: Static,
    params: Params,
    state: NasrukfBeamState,
    fused: _Fused,
    new: _NewData,
    lines: BeamFeatures,
    arcs: BeamFeatures,
) -> tuple[BeamFeatures, BeamFeatures, Int[Array, ""], Int[Array, ""]]:
    """The first :data:`NEW_PER_SCAN` starters of each kind made features (a later one is stored
    again in the next scan), only in a scan that has any.

    Returns:
        The lines, the arcs, the features added and those dropped for want of a slot.
    """
    ns = nasrukf_static(static)
    form, rule, G = ns.line_form, _rule(params), ns.groups
    starts, is_arc, fits, x_g = new.starts, new.is_arc, new.fits, fused.x

    def create(lines, arcs):
        gL = jnp.nonzero(starts & ~is_arc, size=NEW_PER_SCAN, fill_value=G)[0]
        gA = jnp.nonzero(starts & is_arc, size=NEW_PER_SCAN, fill_value=G)[0]
        gLc, gAc = jnp.clip(gL, 0, G - 1), jnp.clip(gA, 0, G - 1)
        ny, nL, nv = jax.vmap(lambda z, cov: _init_line(fused, z, cov, form, rule))(fits.line[gLc], fits.line_cov[gLc])
        ay, aL = jax.vmap(lambda z, cov: _init_arc(fused, z, cov, rule))(fits.arc[gAc], fits.arc_cov[gAc])
        lines, addL, overL = _insert(lines, gL < G, ny, nL, nv, x_g, state.scan)
        arcs, addA, overA = _insert(arcs, gA < G, ay, aL, jnp.zeros(NEW_PER_SCAN, bool), x_g, state.scan)
        return lines, arcs, (addL + addA).astype(jnp.int32), (overL + overA).astype(jnp.int32)

    none = jnp.zeros((), jnp.int32)
    return jax.lax.cond(jnp.any(starts), create, lambda lines, arcs: (lines, arcs, none, none), lines, arcs)


def _output(
    state: NasrukfBeamState,
    seg,
    valid: Bool[Array, ""],
    fused: _Fused,
    maps: tuple[BeamFeatures, BeamFeatures, Candidates],
    noise: tuple[Float[Array, "1"], Int[Array, ""]],
    moving: Bool[Array, ""],
    tallies: tuple[Int[Array, ""], Int[Array, ""], Int[Array, ""]],
) -> tuple[NasrukfBeamState, GaussianStepOutput]:
    """The new state (exactly the old one for padding) and the segment's record.

    Args:
        state: the state before the segment.
        seg: the segment; ``valid``: False for padding.
        fused: the fused pose and the process-noise estimate.
        maps: the lines, the arcs and the stored new-feature data after the scan.
        noise: the beam-noise estimate and its count.
        moving: static initialisation is over.
        tallies: the beams associated, the features added and those dropped for want of a slot.
    """
    lines, arcs, cands = maps
    noise_v, noise_count = noise
    n_associated, added, over = tallies
    keep = lambda new_value, old: jax.tree.map(lambda a, b: jnp.where(valid, a, b), new_value, old)  # noqa: E731
    count = jnp.sum(lines.active) + jnp.sum(arcs.active)
    new_state = NasrukfBeamState(
        pose=keep(fused.x, state.pose),
        pose_sqrt=keep(fused.S, state.pose_sqrt),
        lines=keep(lines, state.lines),
        arcs=keep(arcs, state.arcs),
        candidates=keep(cands, state.candidates),
        noise=keep(noise_v, state.noise),
        noise_count=keep(noise_count, state.noise_count),
        process_scale=keep(fused.process_scale, state.process_scale),
        process_count=keep(fused.process_count, state.process_count),
        process_basis=keep(fused.basis, state.process_basis),
        moving=keep(moving, state.moving),
        count=jnp.where(valid, count, state.count).astype(jnp.int32),
        overflow=state.overflow + jnp.where(valid, over, 0).astype(jnp.int32),
        scan=state.scan + (valid & seg.is_scan).astype(jnp.int32),
        slope_form=state.slope_form,
    )
    x = new_state.pose
    finite = jnp.all(jnp.isfinite(x)) & jnp.all(jnp.isfinite(new_state.pose_sqrt))
    record = GaussianStepOutput(
        pose=x,
        pose_cov=new_state.pose_cov,
        n_landmarks=new_state.count,
        n_confirmed=new_state.count,
        n_associated=n_associated,
        n_new=added,
        overflow=over.astype(jnp.int32),
        n_nonfinite=(~finite).astype(jnp.int32),
    )
    return new_state, record


def beam_step(
    static: Static, params: Params, state: NasrukfBeamState, seg, valid: Bool[Array, ""]
) -> tuple[NasrukfBeamState, GaussianStepOutput]:
    """One segment of NASRUKF with per-beam measurements (module docstring).

    Args:
        static: static settings (NASRUKF's ``line_form``, ``beams_per_feature``, ...).
        params: hyperparameters (NASRUKF's ``beams``, unscented parameters, noise estimates' settings).
        state: the state before the segment.
        seg: one segment of ``data.detections: laser_beams`` (``z = (range, phi)``, ``z_id`` the
            front-end feature within the scan, ``diam > 0`` on an arc).
        valid: False for padding (the state is returned unchanged).

    Returns:
        The new state and the segment's :class:`~._gaussian.GaussianStepOutput`.
    """
    assert nasrukf_params(params).beams is not None, "nasrukf.measurement beams needs params.method.beams"
    form = nasrukf_static(static).line_form
    prior = _time_update(static, params, state, seg)
    beams = _associate(static, params, prior, seg, valid)
    lines_w, arcs_w = _windows(static, params, prior, beams)
    post_lines, post_arcs, noise, noise_count = _stacked_updates(static, params, state, lines_w, arcs_w)
    fused = _fuse(static, params, state, prior, lines_w, arcs_w, post_lines, post_arcs)
    lines = _feedback(prior.lines, lines_w.slots, post_lines, (1,) if form == "normal" else (), fused.x, prior.x)
    arcs = _feedback(prior.arcs, arcs_w.slots, post_arcs, (), fused.x, prior.x)
    cands, new = _new_data(static, params, state, beams, valid, fused.x, noise)
    lines, arcs, added, over = _create(static, params, state, fused, new, lines, arcs)
    n_associated = jnp.sum(beams.assoc).astype(jnp.int32)
    maps, noises = (lines, arcs, cands), (noise, noise_count)
    return _output(state, seg, valid, fused, maps, noises, prior.moving, (n_associated, added, over))
