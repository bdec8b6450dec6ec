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
   square-root UKF update of eq. 10-12 (:func:`stacked_update`). With ``noise.adaptive`` the beam
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

from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
from jax.scipy.linalg import cho_solve
from jaxtyping import Array, Bool, Float

from nanoslam_jax.lib._linalg import mmt, mv
from nanoslam_jax.models import wrap_angle
from nanoslam_jax.models._lines import (
    beam_range_circle,
    beam_range_line,
    beam_range_slope_intercept,
    beam_range_vertical,
    line_to_world,
)
from nanoslam_jax.lib.quadrature import Unscented
from nanoslam_jax.methods.gaussian._nasrukf import (
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
    NasrukfBeamState,
    candidate_update,
    fit_group,
    line_param,
)
from nanoslam_jax.methods._method_settings import nasrukf_params, nasrukf_static
from nanoslam_jax.methods._params import Params, Static
from nanoslam_jax.methods.gaussian._srukf import (
    SigmaMeasurement,
    _wrap_at,
    adaptive_noise_rows,
    adaptive_process_update,
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


def line_ranges(
    pose: Float[Array, "3"], phi: Float[Array, " k"], m: Float[Array, "2"], vertical: Bool[Array, ""], form: str
) -> tuple[Float[Array, " k"], Bool[Array, " k"]]:
    """Ranges along beams ``phi`` to a line in the state's form: the normal form, or the paper's
    eq. 14 (``y = a x + b``) and eq. 15 (``x = c`` where ``vertical``)."""
    if form == "normal":
        return beam_range_line(pose, phi, m)
    r1, h1 = beam_range_slope_intercept(pose, phi, m[0], m[1])
    r2, h2 = beam_range_vertical(pose, phi, m[0])
    return jnp.where(vertical, r2, r1), jnp.where(vertical, h2, h1)


def stacked_update(
    y: Float[Array, " n"],
    L: Float[Array, "n n"],
    h: Callable[[Float[Array, " n"]], Float[Array, " b"]],
    z: Float[Array, " b"],
    use: Bool[Array, " b"],
    noise_var: Float[Array, ""],
    rule: Unscented,
    x_angles: Sequence[int] = (),
    pred: SigmaMeasurement | None = None,
) -> tuple[Float[Array, " n"], Float[Array, "n n"], SigmaMeasurement]:
    """The square-root UKF update (eq. 10-12) with the beams ``use`` of ``z`` stacked as one vector
    measurement of independent noise ``noise_var``.

    ``Sz`` the lower Cholesky factor of ``sum_i wc_i dz_i dz_i' + R`` (the matrix whose square root
    eq. 12 forms by ``qr`` and ``cholupdate``); ``K = (Pxz / Sz') / Sz``; ``y + K (z - z_hat)``; the
    new square root the Cholesky factor of ``L L' - U U'``, ``U = K Sz`` (what eq. 12's rank-one
    downdates by the columns of ``U`` give). With ``b`` beams above the ``2n + 1`` sigma points and
    ``n <= 6``, one factorisation of each matrix is cheaper than the rotations, in time and in the
    size of the compiled program. Where rounding leaves ``L L' - U U'`` not positive definite (never
    with the algebra right) the state is left as it was. Unused entries predict and measure 0: their
    rows of ``Pxz`` are 0, so they change nothing.

    Args:
        y, L: the joint state's mean and lower square root.
        h: its predicted measurement (the unused entries are set to 0 here).
        z: the measurement.
        use: which entries are real.
        noise_var: the noise variance of one entry.
        rule: the unscented rule.
        x_angles: angle components of ``y``.
        pred: the sigma-point prediction of ``h`` with the unused entries 0, if computed already.

    Returns:
        The updated mean and square root, and the sigma-point prediction (for the noise estimate).
    """
    if pred is None:
        pred = predict_measurement(y, L, lambda yy: jnp.where(use, h(yy), 0.0), rule)
    b = z.shape[0]
    Pzz = (pred.wc[:, None] * pred.dz).T @ pred.dz + noise_var * jnp.eye(b)
    Sz = jnp.linalg.cholesky(0.5 * (Pzz + Pzz.T))
    Pxz = (pred.wc[:, None] * pred.dx).T @ pred.dz
    K = cho_solve((Sz, True), Pxz.T).T
    nu = jnp.where(use, z - pred.z_hat, 0.0)
    U = K @ Sz
    P = L @ L.T - U @ U.T
    Ln = jnp.linalg.cholesky(0.5 * (P + P.T))
    ok = jnp.all(jnp.isfinite(Ln))
    return jnp.where(ok, _wrap_at(y + K @ nu, x_angles), y), jnp.where(ok, Ln, L), pred


def _select(sel: Bool[Array, " k"], size: int) -> tuple[Array, Bool[Array, " size"]]:
    """At most ``size`` of the beams ``sel``, evenly spread (every ``ceil(n / size)``-th), as indices and a mask."""
    n = jnp.sum(sel)
    stride = jnp.maximum(-(-n // size), 1)
    rank = jnp.cumsum(sel) - 1
    take = sel & (rank % stride == 0)
    idx = jnp.nonzero(take, size=size, fill_value=0)[0]
    return idx, jnp.arange(size) < jnp.sum(take)


def _zeros_like(shapes):
    """Zeros of the shapes and dtypes of a pytree of :class:`jax.ShapeDtypeStruct`."""
    return jax.tree.map(lambda a: jnp.zeros(a.shape, a.dtype), shapes)


def _busiest(counts: Array, active: Bool[Array, " c"], size: int) -> tuple[Array, Bool[Array, " size"]]:
    """The ``size`` active slots with the most associated beams (indices) and which of them have any."""
    top, idx = jax.lax.top_k(jnp.where(active, counts, -1), size)
    return idx, top > 0


def _feature_update(feats: BeamFeatures, gid, x0, S0, r, phi, best, assoc, size, h_of, rule):
    """Predictions and the data of the stacked updates of the features ``feats`` (a window of the
    slots; ``gid``: their indices among all features, lines then arcs), vmapped over them."""
    idx, use = jax.vmap(lambda j: _select(assoc & (best == j), size))(gid)
    zs, ps = r[idx], phi[idx]
    ys = jax.vmap(lambda m: jnp.concatenate([x0, m]))(feats.mean)
    Ls = jax.vmap(joint_sqrt, (None, 0, 0))(S0, feats.gain, feats.sqrt)

    def pred_one(y, L, p, v, u):
        return predict_measurement(y, L, lambda yy: jnp.where(u, h_of(yy, p, v), 0.0), rule)

    preds = jax.vmap(pred_one)(ys, Ls, ps, feats.vertical, use)
    return ys, Ls, zs, ps, use, preds


def projected_rows(
    dat, variance: Float[Array, ""]
) -> tuple[Float[Array, "w 1"], Float[Array, "w 1"], Bool[Array, " w"]]:
    """Each feature's innovations with the part the state's uncertainty can explain removed, as
    rows of the noise estimate (``nasrukf.noise_residual: projected``).

    A feature's ``b`` innovations ``nu`` have covariance ``H P H' + r I``. Projected onto the
    orthogonal complement of the columns of ``H P^(1/2)`` (here the sigma points' odd
    deviations, ``sqrt(2 wc) (dz_i - dz_(i+n)) / 2``: the linear part), they keep ``r I`` alone:
    ``E |nu_perp|^2 = r (b - k)`` with ``k`` the directions projected out, whatever ``P`` is. So
    the estimate does not trade the beam noise against the process noise (the innovation form's
    ``nu^2 - H P H'`` does: an overestimated ``P`` drives it to the floor, and the process-noise
    estimate, fed by updates that trust the beams too much, grows without bound). Directions the
    state moves the predictions by less than ``1e-3 variance`` are left in (they add at most that).

    Args:
        dat: the window's predictions and data (:func:`_feature_update`).
        variance: the current noise estimate (the threshold's scale).

    Returns:
        ``sqrt(|nu_perp|^2 / (b - k))`` and 0 (no predicted variance to subtract) per feature,
        and whether it has at least one degree of freedom left.
    """
    _, _, zs, _, use, preds = dat
    n = preds.dx.shape[-1]
    nu = jnp.where(use, zs - preds.z_hat, 0.0)
    D = (preds.dz[:, 1 : n + 1] - preds.dz[:, n + 1 :]) * (0.5 * jnp.sqrt(2.0 * preds.wc[:, 1, None, None]))
    vals, vecs = jnp.linalg.eigh(D @ jnp.swapaxes(D, 1, 2))
    keep = vals > 1e-3 * variance
    c = jnp.einsum("wnk,wnb,wb->wk", vecs, D, nu)
    along = jnp.sum(jnp.where(keep, jnp.square(c) / jnp.where(keep, vals, 1.0), 0.0), axis=1)
    dof = jnp.sum(use, axis=1) - jnp.sum(keep, axis=1)
    e2 = jnp.maximum(jnp.sum(jnp.square(nu), axis=1) - along, 0.0) / jnp.maximum(dof, 1)
    return jnp.sqrt(e2)[:, None], jnp.zeros_like(e2)[:, None], dof >= 1


def _posterior_rows(ys, Ls, dat, h_of, vertical, rule):
    """Each updated feature's RMS residual ``z - h(x+)`` after its update and its mean predicted
    variance there (from the posterior's sigma points), as rows of the noise estimate."""
    _, _, zs, ps, use, _ = dat

    def one(y, L, z, p, u, v):
        pred = predict_measurement(y, L, lambda yy: jnp.where(u, h_of(yy, p, v), 0.0), rule)
        n = jnp.maximum(jnp.sum(u), 1)
        e2 = jnp.sum(jnp.where(u, jnp.square(z - pred.z_hat), 0.0)) / n
        return jnp.sqrt(e2)[None], (jnp.sum(jnp.where(u, pred.variance(), 0.0)) / n)[None]

    return jax.vmap(one)(ys, Ls, zs, ps, use, vertical)


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
    ns, nk = nasrukf_static(static), nasrukf_params(params)
    bp = nk.beams
    assert bp is not None, "nasrukf.measurement beams needs params.method.beams"
    form, rule, G, M = ns.line_form, _rule(params), ns.groups, ns.beams_per_feature
    line_angles = (2, 4) if form == "normal" else (2,)

    # 1. Time update (held during static initialisation).
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

    # 2. Association by predicted range.
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

    # 3. Stacked updates, the noise estimate first.
    n_lines = lines0.mean.shape[0]

    def h_line(yy, p, v):
        rr, hit = line_ranges(yy[:3], p, yy[3:], v, form)
        return jnp.where(hit, rr, 0.0)

    def h_arc(yy, p, v):
        rr, hit = beam_range_circle(yy[:3], p, yy[3:])
        return jnp.where(hit, rr, 0.0)

    counts = jax.ops.segment_sum(assoc.astype(jnp.int32), best, n_lines + arcs0.mean.shape[0])
    wL, seenL = _busiest(counts[:n_lines], lines0.active, min(static.window, n_lines))
    wA, seenA = _busiest(counts[n_lines:], arcs0.active, min(static.window, arcs0.mean.shape[0]))
    subL = jax.tree.map(lambda a: a[wL], lines0)
    subA = jax.tree.map(lambda a: a[wA], arcs0)
    Ldat = _feature_update(subL, wL, x0, S0, r, phi, best, assoc, M, h_line, rule)
    Adat = _feature_update(subA, n_lines + wA, x0, S0, r, phi, best, assoc, M, h_arc, rule)

    def residual_rows(dat):
        _, _, zs, _, use, preds = dat
        n = jnp.maximum(jnp.sum(use, axis=1), 1)
        nu2 = jnp.sum(jnp.where(use, jnp.square(zs - preds.z_hat), 0.0), axis=1) / n
        pv = jnp.sum(jnp.where(use, jax.vmap(SigmaMeasurement.variance)(preds), 0.0), axis=1) / n
        return jnp.sqrt(nu2)[:, None], pv[:, None], jnp.any(use, axis=1)

    noise, noise_count = state.noise, state.noise_count
    updL, updA = jnp.any(Ldat[4], axis=1), jnp.any(Adat[4], axis=1)
    rows_use = jnp.concatenate([updL, updA])
    floor = params.noise_floor * jnp.square(bp.sigma_beam)[None]
    before_update = static.adaptive_noise and ns.noise_residual != "posterior"
    if before_update:  # eq. 11 before each update: the innovations less their predicted variance, or projected
        if ns.noise_residual == "projected":
            (nuL, pvL, okL), (nuA, pvA, okA) = (projected_rows(d, noise[0]) for d in (Ldat, Adat))
        else:
            (nuL, pvL, okL), (nuA, pvA, okA) = residual_rows(Ldat), residual_rows(Adat)
        rows, noise, noise_count = adaptive_noise_rows(
            noise,
            noise_count,
            jnp.concatenate([nuL, nuA]),
            jnp.concatenate([pvL, pvA]),
            rows_use & jnp.concatenate([okL, okA]),
            params.forgetting,
            floor,
        )
        varL, varA = rows[: wL.shape[0], 0], rows[wL.shape[0] :, 0]
    else:
        varL = jnp.broadcast_to(noise[0], updL.shape)
        varA = jnp.broadcast_to(noise[0], updA.shape)

    def run_updates(dat, var, h_of, vertical, angles):
        ys, Ls, zs, ps, use, preds = dat

        def one(y, L, z, p, u, v, s2, pred):
            yn, Ln, _ = stacked_update(y, L, lambda yy: h_of(yy, p, v), z, u, s2, rule, angles, pred)
            return yn, Ln

        return jax.vmap(one)(ys, Ls, zs, ps, use, vertical, var, preds)

    yL, LL = run_updates(Ldat, varL, h_line, subL.vertical, line_angles)
    yA, LA = run_updates(Adat, varA, h_arc, subA.vertical, (2,))
    if static.adaptive_noise and not before_update:  # eq. 11's weights on the residuals after the update
        eL = _posterior_rows(yL, LL, Ldat, h_line, subL.vertical, rule)
        eA = _posterior_rows(yA, LA, Adat, h_arc, subA.vertical, rule)
        _, noise, noise_count = adaptive_noise_rows(
            noise,
            noise_count,
            jnp.concatenate([eL[0], eA[0]]),
            -jnp.concatenate([eL[1], eA[1]]),
            rows_use,
            params.forgetting,
            floor,
        )
    updL, updA = updL & seenL, updA & seenA

    # 4. Fusion and feedback.
    fuseL = updL & (subL.hits >= nk.new_feature_hits)
    fuseA = updA & (subA.hits >= nk.new_feature_hits)
    xs = jnp.concatenate([yL[:, :3], yA[:, :3]])
    Lp = jnp.concatenate([LL[:, :3, :3], LA[:, :3, :3]])
    use = jnp.concatenate([fuseL, fuseA])
    x_f, S_f = fuse_poses(x0, S0, xs, Lp, use)
    x_g = jnp.where(static_now, x0, x_f)
    S_g = jnp.where(static_now, S0, S_f)
    process_scale, process_count = state.process_scale, state.process_count
    if ns.adaptive_process:
        P0 = mmt(S0, S0)
        dx = jax.vmap(_minus, (0, None))(xs, x0)
        Pi = mmt(Lp, Lp)
        w = use.astype(x0.dtype)
        change = jnp.sum(w[:, None, None] * (dx[:, :, None] * dx[:, None, :] + Pi - P0), axis=0)
        change = change / jnp.maximum(jnp.sum(w), 1.0)
        updated = jnp.any(use) & ~static_now
        new_scale = adaptive_process_update(
            process_scale, process_count, change, S0, basis, nk.process_forgetting, nk.process_floor
        )
        process_scale = jnp.where(updated, new_scale, process_scale)
        process_count = process_count + updated.astype(process_count.dtype)
        basis = jnp.where(updated, jnp.zeros_like(basis), basis)

    def feedback(feats: BeamFeatures, win, y, L, upd, angle_idx):
        mean, gain, sqrt = jax.vmap(to_conditional, (0, 0, 0, None))(y[:, :3], y[:, 3:], L, x_g)
        cap = feats.mean.shape[0]
        tgt = jnp.where(upd, win, cap)
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

    lines = feedback(lines0, wL, yL, LL, updL, (1,) if form == "normal" else ())
    arcs = feedback(arcs0, wA, yA, LA, updA, ())

    # 5. New features from the front-end segments and arcs no feature explains.
    members = ok[None, :] & (group[None, :] == jnp.arange(G)[:, None])
    is_arc = jax.ops.segment_max(jnp.where(ok, seg.diam, 0.0), group, G) > 0
    unexplained = (n_group >= 3) & (2 * n_assoc < n_group)
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

    def place_line(p, w, z):
        line = line_to_world(z + w, p[:3])
        m, _ = line_param(line, form)
        return jnp.concatenate([p[:3], m])

    def init_line(z, cov):
        _, vertical = line_param(line_to_world(z, x_g), form)
        nsq = jnp.linalg.cholesky(cov + 1e-18 * jnp.eye(2))
        y, L = srukf_transform(x_g, S_g, lambda p, w: place_line(p, w, z), nsq, rule, angles=line_angles)
        return y, L, vertical

    def place_arc(p, w, z):
        zz = z + w
        cc, ss = jnp.cos(p[2]), jnp.sin(p[2])
        return jnp.concatenate(
            [p[:3], jnp.stack([p[0] + cc * zz[0] - ss * zz[1], p[1] + ss * zz[0] + cc * zz[1], zz[2]])]
        )

    def init_arc(z, cov):
        nsq = jnp.linalg.cholesky(cov + 1e-12 * jnp.eye(3))
        return srukf_transform(x_g, S_g, lambda p, w: place_arc(p, w, z), nsq, rule, angles=(2,))

    def create(lines, arcs):
        """The first NEW_PER_SCAN starters of each kind made features (a later one is stored
        again in the next scan); the features added and those dropped for want of a slot."""
        gL = jnp.nonzero(starts & ~is_arc, size=NEW_PER_SCAN, fill_value=G)[0]
        gA = jnp.nonzero(starts & is_arc, size=NEW_PER_SCAN, fill_value=G)[0]
        gLc, gAc = jnp.clip(gL, 0, G - 1), jnp.clip(gA, 0, G - 1)
        ny, nL, nv = jax.vmap(init_line)(fits.line[gLc], fits.line_cov[gLc])
        ay, aL = jax.vmap(init_arc)(fits.arc[gAc], fits.arc_cov[gAc])
        lines, addL, overL = insert(lines, gL < G, ny, nL, nv)
        arcs, addA, overA = insert(arcs, gA < G, ay, aL, jnp.zeros(NEW_PER_SCAN, bool))
        return lines, arcs, (addL + addA).astype(jnp.int32), (overL + overA).astype(jnp.int32)

    def insert(feats: BeamFeatures, create, y, L, vertical):
        cap, k = feats.mean.shape[0], create.shape[0]
        free = jnp.nonzero(~feats.active, size=k, fill_value=cap)[0]
        rank = jnp.cumsum(create) - 1
        dest = jnp.where(create, free[jnp.clip(rank, 0, k - 1)], cap)
        mean, gain, sqrt = jax.vmap(to_conditional, (0, 0, 0, None))(y[:, :3], y[:, 3:], L, x_g)
        new = BeamFeatures(
            mean, gain, sqrt, vertical, jnp.ones(k, bool), jnp.ones(k, jnp.int32), jnp.full(k, state.scan, jnp.int32)
        )
        feats = jax.tree.map(lambda a, b: a.at[dest].set(b, mode="drop"), feats, new)
        return feats, jnp.sum(create & (dest < cap)), jnp.sum(create & (dest >= cap))

    none = jnp.zeros((), jnp.int32)
    lines, arcs, added, over = jax.lax.cond(
        jnp.any(starts), create, lambda lines, arcs: (lines, arcs, none, none), lines, arcs
    )

    keep = lambda new_value, old: jax.tree.map(lambda a, b: jnp.where(valid, a, b), new_value, old)  # noqa: E731
    count = jnp.sum(lines.active) + jnp.sum(arcs.active)
    new_state = NasrukfBeamState(
        pose=keep(x_g, state.pose),
        pose_sqrt=keep(S_g, state.pose_sqrt),
        lines=keep(lines, state.lines),
        arcs=keep(arcs, state.arcs),
        candidates=keep(cands, state.candidates),
        noise=keep(noise, state.noise),
        noise_count=keep(noise_count, state.noise_count),
        process_scale=keep(process_scale, state.process_scale),
        process_count=keep(process_count, state.process_count),
        process_basis=keep(basis, state.process_basis),
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
        n_associated=jnp.sum(assoc).astype(jnp.int32),
        n_new=added,
        overflow=over.astype(jnp.int32),
        n_nonfinite=(~finite).astype(jnp.int32),
    )
    return new_state, record
