"""NASRUKF FastSLAM (docs/method/nasrukf.md).

The paper replaces the particle filter over the pose and the per-particle landmark EKFs by ``N``
joint states, one per map feature, each holding the vehicle pose and that feature and each
estimated by a nonlinear adaptive square-root unscented Kalman filter (:mod:`._srukf`); the global
pose is the information-weighted fusion of the per-feature pose estimates (eq. 3-5). On this log
a feature is a tree: its centre (``nasrukf.feature: point``, a 5-D joint state) or the paper's arc
(``arc``: centre and radius, 6-D, the detection's diameter as a third measurement).

**Representation.** After each scan every feature's joint state is fed back to the global pose
(below), so all joint states share the pose marginal ``N(x, S S')`` and differ in the feature's
conditional given the pose: ``m | x ~ N(mean + gain (x - x_mean), sqrt sqrt')``. A feature is
stored as ``(mean, gain, sqrt)`` and its joint state's lower square root is, with no
factorisation, ``[[S, 0], [gain S, sqrt]]`` (:func:`joint_sqrt`); masked fixed-capacity arrays,
vmapped over features.

Per segment (:func:`nasrukf_step`):

1. **Time update.** The features do not move (the paper's ``x_j(k) = x_j(k-1) + w_j`` with
   ``w_j = 0`` for trees), so a joint state's time update moves its pose part only, and its
   cross-covariance follows the pose's regression on the scan's start pose. That regression is
   computed once per scan by the square-root unscented transform of (pose, start pose) through the
   DR pieces with the control noise augmented (:func:`pose_time_update`: QR and ``cholupdate`` per
   piece, eq. 8-9), giving ``T = Cov(x_start, x) Cov(x)^-1`` and the square root ``D`` of
   ``Cov(x_start | x)``; every feature then gets ``gain <- gain T`` and ``sqrt <- cholupdate(sqrt,
   gain D)`` (three rank-one updates of its 2x2 factor; :func:`propagate_features`). A static
   feature's cross-covariance with the moved pose is then ``gain Cov(x_start, x)`` and its marginal
   is unchanged, as in a joint unscented time update of (pose, feature); only the sigma-point
   spread differs (one transform of dimension 3 + 3 + 2 per scan instead of one of 3 + 2 + 2 per
   feature, each a QR), and the cost is O(1) per feature.
   **Features out of view** are propagated in the same way every scan (the cost is a few
   element-wise operations per slot): their correlation with the pose decays by ``T`` as the
   vehicle moves on while their marginal stays as it was, so a feature that is seen again later
   enters with what remains of it.
2. **Association** against the features within ``max_range + window_margin`` of the prior
   position (at most ``filter.window``) with the other methods' rule and gates
   (:func:`~._association.nearest_neighbours`): innovation covariance ``J P J' + Gm C Gm' + R``
   with ``J = Gx + Gm gain`` (the joint state's, pose-feature correlation included; autodiff
   Jacobians), a new feature above ``filter.new_landmark``, detections in order.
3. **Measurement updates** (eq. 10-12), one per associated detection, all in parallel (a feature is
   claimed once per scan): sigma points of the joint state, ``Sz`` by QR and ``cholupdate``, the
   state's square root downdated by ``U = K Sz``. With ``noise.adaptive`` the measurement noise is
   first re-estimated from each residual in detection order (eq. 11,
   :func:`~._srukf.adaptive_noise_rows`), and each update uses the estimate that includes its own
   residual, as in the paper. There is one estimate for the sensor, fed by every feature's
   residuals: a tree is detected a few dozen times at most, and eq. 11's first weight ``d_0 = 1``
   would make each feature's own estimate start from a single residual.
4. **Fusion** (eq. 4-5, :func:`fuse_poses`) of the updated joint states' pose marginals
   ``N(x_i, P_i)``. Eq. 4 assumes independent estimates (``P_ij = 0``); these all continue from the
   scan's common prior, so it is applied to each one's information gain over that prior:
   ``Lambda = Lambda_0 + sum_i (P_i^-1 - Lambda_0)``, ``x = x_0 + Lambda^-1 sum_i P_i^-1 (x_i - x_0)``,
   the exact posterior when the detections are independent given the pose. With
   ``nasrukf.adaptive_process`` the fused joint states' pose corrections ``x_i - x_0 = K_i nu_i``
   and covariance changes ``P_i - P_0``, averaged, update the estimated process noise ``Q`` of
   eq. 9 (a Sage-Husa estimate with eq. 11's weights ``d_k``,
   :func:`~._srukf.adaptive_process_update`), which scales the time update's noise from the next
   segment on. Eq. 5 as printed
   (``sum_i P_i^-1 x_i / sum_i P_i^-1`` over all ``N`` features, those not detected sitting at the
   prior) counts the prior once per feature, shrinking the pose covariance by the feature count at every
   scan. Features with fewer than
   ``nasrukf.new_feature_hits`` earlier detections (the paper's "enough new feature data") are
   updated but not fused.
5. **Feedback** (eq. 3: each joint state continues from the common past pose): every joint state's
   pose marginal is replaced by the fused one and its feature's conditional given the pose kept,
   ``p(x, m_i) <- p_fused(x) p_i(m_i | x)``. In the square-root form this is ``gain = L_mx
   L_xx^-1``, ``sqrt = L_mm``, ``mean = m_i + gain (x - x_i)`` (:func:`to_conditional`): features
   not updated move with the pose correction through their correlation with it; no
   factorisation. The fused pose's 3x3 covariance, combined in information form, is the one
   matrix factorised per scan.
6. **New features** from detections above ``filter.new_landmark``: the square-root unscented
   transform of (prior pose, detection) through the inverse model (:func:`init_feature`), in the
   free slots (overflow counted).

**Landmark management** (``static.manage``, the ``map`` section; :mod:`._management`): features
carry the same bookkeeping as the particle filters' landmarks (existence log-odds, hits, misses,
tentative or confirmed, birth scan, tree diameter) and follow the same rules, tested at the fused
pose after the feedback: a tentative feature is updated but moves the pose only with
``map.use_tentative`` (and, as the paper's rule, only once it has ``nasrukf.new_feature_hits``
earlier detections), a feature whose existence falls below the removal threshold or that stays
tentative too long is removed and its slot reused. Without management every feature is confirmed
and permanent.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from nanoslam_jax.lib._linalg import mmt, mv
from nanoslam_jax.data import Segments
from nanoslam_jax.models import (
    is_range_bearing,
    wrap_angle,
)
from nanoslam_jax.methods.maps._association import Association, Gating, ScanDetections, SlotTerms, nearest_neighbours
from nanoslam_jax.methods.maps._landmarks import first_true
from nanoslam_jax.methods.maps._management import (
    Candidates,
    Management,
    diameter_update,
    drop_stale,
    manage_window,
    new_landmarks,
)
from nanoslam_jax.methods._params import Params, Static
from nanoslam_jax.methods.gaussian._srukf import (
    SigmaMeasurement,
    adaptive_noise_rows,
    measurement_update,
    predict_measurement,
    process_noise_basis,
)
from nanoslam_jax.methods._method_settings import nasrukf_params, nasrukf_static
from nanoslam_jax.methods.gaussian._nasrukf_state import NasrukfFeatures, NasrukfState, configured_noise, feature_dim
from nanoslam_jax.methods.gaussian._gaussian import GaussianStepOutput
from nanoslam_jax.methods.gaussian._nasrukf_joint import fused_process_update
from nanoslam_jax.methods.gaussian._nasrukf_joint import (
    _minus,
    _rule,
    association_information,
    fuse_poses,
    init_feature,
    joint_sqrt,
    measure,
    pose_time_update,
    propagate_features,
    to_conditional,
)


class _Rows(NamedTuple):
    """Per detection row: the joint state it updates (before), and after."""

    x: Float[Array, "k n"]
    L: Float[Array, "k n n"]


class _Scan(NamedTuple):
    """A segment's detections as the step reads them.

    Attributes:
        seg: the segment (a :class:`Segments` without the leading axis).
        valid: False for a padding segment.
        z_mask: the real detections (none in padding).
        z: the measurements: range and bearing, and the diameter for arc features.
    """

    seg: Segments
    valid: Bool[Array, ""]
    z_mask: Bool[Array, " k"]
    z: Float[Array, "k mz"]


class _Prior(NamedTuple):
    """The time update's result: the prior pose (mean ``x``, lower square root ``S``, covariance
    ``P``), every feature propagated with it, and the process-noise basis accumulated so far."""

    x: Float[Array, "3"]
    S: Float[Array, "3 3"]
    P: Float[Array, "3 3"]
    features: NasrukfFeatures
    basis: Array


class _Window(NamedTuple):
    """The features a scan is associated with.

    Attributes:
        idx: the local window's slots among all features (``capacity`` where unused).
        n_near: features within range of the prior pose (beyond ``W`` they are left out).
        in_window: which window slots hold a feature.
        local: the window's features.
        new_y, new_L: one provisional feature's joint state per detection (at the prior pose).
        mean, gain, sqrt: the window's features (a finite dummy in unused slots), then the
            provisional features, in conditional form (``W + K`` rows).
    """

    idx: Int[Array, " W"]
    n_near: Int[Array, ""]
    in_window: Bool[Array, " W"]
    local: NasrukfFeatures
    new_y: Float[Array, "k n"]
    new_L: Float[Array, "k n n"]
    mean: Float[Array, "slots f"]
    gain: Float[Array, "slots f 3"]
    sqrt: Float[Array, "slots f f"]


class _Match(NamedTuple):
    """The association of a scan's detections.

    Attributes:
        assoc: the association rule's result (slot among ``W + K`` or -1, new features).
        matched: detections associated with a window or a provisional feature.
        existing: those associated with a window feature.
        provisional: those associated with an earlier detection's provisional feature.
        slot: each detection's row among the ``W + K`` (an unmatched one: its own provisional).
        ws, ps: the matched window slot and provisional row (clipped into range).
    """

    assoc: Association
    matched: Bool[Array, " k"]
    existing: Bool[Array, " k"]
    provisional: Bool[Array, " k"]
    slot: Int[Array, " k"]
    ws: Int[Array, " k"]
    ps: Int[Array, " k"]


class _Fused(NamedTuple):
    """The global pose after fusion (mean ``x``, lower square root ``S``) and the process-noise
    estimate (``Lambda``, its count and the basis) after it."""

    x: Float[Array, "3"]
    S: Float[Array, "3 3"]
    process_scale: Array
    process_count: Array
    basis: Array


class _Updated(NamedTuple):
    """Per detection row, after the fusion: the updated joint state and the provisional feature,
    each as ``(mean, gain, sqrt)`` given the fused pose, and the updated diameter and its variance."""

    upd: tuple[Array, Array, Array]
    ini: tuple[Array, Array, Array]
    diam: Float[Array, " k"]
    diam_var: Float[Array, " k"]


def _time_update(static: Static, params: Params, state: NasrukfState, scan: _Scan) -> _Prior:
    """The pose's time update (with the estimated process noise under ``nasrukf.adaptive_process``),
    then every feature's part of its joint state (:func:`pose_time_update`,
    :func:`propagate_features`); a padding segment's pieces are all masked."""
    seg, valid = scan.seg, scan.valid
    dr_mask = seg.dr_mask & valid
    if nasrukf_static(static).adaptive_process:
        scale_sqrt = jnp.linalg.cholesky(state.process_scale)
        basis = process_noise_basis(state.process_basis, state.pose, seg.dt, seg.u, dr_mask, params.motion)
    else:
        scale_sqrt, basis = None, state.process_basis
    x0, S0, T, D = pose_time_update(state.pose, state.pose_sqrt, seg.dt, seg.u, dr_mask, params, scale_sqrt)
    P0 = mmt(S0, S0)
    feats = propagate_features(state.features, T, D)
    return _Prior(x0, S0, P0, feats, basis)


def _window(static: Static, params: Params, prior: _Prior, scan: _Scan, noise: Float[Array, " mz"]) -> _Window:
    """The local window (at most ``filter.window`` features within ``max_range + window_margin`` of
    the prior position) and one provisional feature per detection (:func:`init_feature` at the
    prior pose with the measurement noise ``noise``)."""
    capacity = static.capacity
    W = min(static.window, capacity)
    x0, S0 = prior.x, prior.S
    f = prior.features
    radius = params.max_range + params.window_margin
    d2 = jnp.square(f.mean[:, 0] - x0[0]) + jnp.square(f.mean[:, 1] - x0[1])
    idx, n_near = first_true(f.landmarks.active & (d2 < jnp.square(radius)), W)
    local = jax.tree.map(lambda a: a.at[idx].get(mode="fill", fill_value=0), f)
    in_window = idx < capacity
    new_y, new_L = jax.vmap(init_feature, (None, None, 0, None, None))(x0, S0, scan.z, noise, params)
    prov = jax.vmap(to_conditional, (0, 0, 0, None))(new_y[:, :3], new_y[:, 3:], new_L, x0)
    # Unused window slots hold a finite dummy feature 1 m ahead of the pose (never matched).
    dummy = jnp.concatenate([x0[:2] + jnp.array([1.0, 0.0]), jnp.ones(feature_dim(static) - 2)])
    mean = jnp.concatenate([jnp.where(in_window[:, None], local.mean, dummy), prov[0]])
    gain = jnp.concatenate([local.gain, prov[1]])
    sqrt = jnp.concatenate([local.sqrt, prov[2]])
    return _Window(idx, n_near, in_window, local, new_y, new_L, mean, gain, sqrt)


def _associate(
    static: Static, params: Params, prior: _Prior, win: _Window, scan: _Scan, noise: Float[Array, " mz"]
) -> _Match:
    """The scan's detections associated with the window's and the provisional features by the other
    methods' rule and gates (:func:`~._association.nearest_neighbours`), innovation covariances from
    the joint states at the prior pose (:func:`association_information`)."""
    W = win.idx.shape[0]
    seg, z_mask, in_window, local = scan.seg, scan.z_mask, win.in_window, win.local
    K = seg.z.shape[0]
    z_hat, s_inv = association_information(prior.x, prior.P, win.mean, win.gain, win.sqrt, jnp.diag(noise[:2]))
    mp = params.map
    var_d = jnp.square(mp.sigma_diameter)
    diam_term = (
        seg.diam,
        jnp.concatenate([local.landmarks.diam, seg.diam]),
        1.0 / (jnp.concatenate([local.landmarks.diam_var, jnp.full(K, var_d)]) + var_d),
        mp.use_diameter,
    )
    known = static.association.known
    id_term = None
    if known:
        ident = local.landmarks.ident
        assert ident is not None, "known association keeps each feature's landmark id"
        id_term = (seg.z_id, jnp.concatenate([ident, seg.z_id]))
    gating = Gating(params.gate, params.new_landmark, static.sequential)
    assoc = nearest_neighbours(z_hat, s_inv, in_window, seg.z, z_mask, gating, SlotTerms(diam_term, id_term))
    matched = assoc.slot >= 0
    existing = matched & (assoc.slot < W)
    provisional = matched & ~existing
    slot = jnp.where(matched, assoc.slot, W + jnp.arange(K))  # unmatched rows: their own provisional feature
    ws = jnp.clip(assoc.slot, 0, W - 1)
    ps = jnp.clip(assoc.slot - W, 0, K - 1)
    return _Match(assoc, matched, existing, provisional, slot, ws, ps)


def _measurement_updates(
    static: Static,
    params: Params,
    state: NasrukfState,
    prior: _Prior,
    win: _Window,
    match: _Match,
    scan: _Scan,
    noise: Float[Array, " mz"],
) -> tuple[_Rows, Float[Array, " mz"], Array]:
    """Every detection row's joint state (:class:`_Rows`, before and after) updated by its detection
    (eq. 10-12, all in parallel), with the adaptive noise estimate first under ``noise.adaptive``
    (eq. 11, :func:`~._srukf.adaptive_noise_rows`, each row's update with the estimate that
    includes its own residual).

    Returns:
        The rows after their updates, and the noise estimate and its count after the scan.
    """
    z, x0, S0 = scan.z, prior.x, prior.S
    K = z.shape[0]
    rows = _Rows(
        jax.vmap(lambda m: jnp.concatenate([x0, m]))(win.mean[match.slot]),
        jax.vmap(joint_sqrt, (None, 0, 0))(S0, win.gain[match.slot], win.sqrt[match.slot]),
    )
    pred: SigmaMeasurement = jax.vmap(predict_measurement, (0, 0, None, None, None))(
        rows.x, rows.L, measure, _rule(params), (1,)
    )
    if static.adaptive_noise:
        nu0 = z - pred.z_hat
        nu0 = nu0.at[:, 1].set(wrap_angle(nu0[:, 1]))
        row_noise, noise, noise_count = adaptive_noise_rows(
            noise,
            state.noise_count,
            nu0,
            jax.vmap(SigmaMeasurement.variance)(pred),
            match.matched,
            params.forgetting,
            params.noise_floor * configured_noise(static, params),
        )
    else:
        row_noise, noise_count = jnp.broadcast_to(noise, (K,) + noise.shape), state.noise_count
    post = _Rows(
        *jax.vmap(measurement_update, (0, 0, 0, 0, 0, None, None))(
            rows.x, rows.L, pred, z, jax.vmap(jnp.diag)(jnp.sqrt(row_noise)), (2,), (1,)
        )[:2]
    )
    return post, noise, noise_count


def _fuse(
    static: Static, params: Params, state: NasrukfState, prior: _Prior, win: _Window, match: _Match, post: _Rows
) -> _Fused:
    """The global pose fused from the updated joint states of the features with enough data (eq.
    4-5, :func:`fuse_poses`; tentative ones only with ``map.use_tentative``), and under
    ``nasrukf.adaptive_process`` the estimated ``Q`` from their pose corrections and covariance
    changes (:func:`~._srukf.adaptive_process_update`)."""
    ns, nk = nasrukf_static(static), nasrukf_params(params)
    x0, S0, basis = prior.x, prior.S, prior.basis
    local, existing, ws = win.local, match.existing, match.ws
    hits_before = jnp.where(existing, local.landmarks.hits[ws], 1)
    fuse = match.matched & (hits_before >= nk.new_feature_hits)
    if static.manage:  # tentative features (and those started in this scan) move the pose only if asked
        fuse = fuse & ((existing & local.landmarks.confirmed[ws]) | params.map.use_tentative)
    x_g, S_g = fuse_poses(x0, S0, post.x[:, :3], post.L[:, :3, :3], fuse)
    process = (state.process_scale, state.process_count, basis)
    if ns.adaptive_process:  # the estimated Q from the fused joint states' corrections and covariance changes
        Ls = post.L[:, :3, :3]
        process = fused_process_update(
            process, post.x[:, :3], Ls, fuse, x0, S0, nk.process_forgetting, nk.process_floor
        )
    process_scale, process_count, basis = process
    return _Fused(x_g, S_g, process_scale, process_count, basis)


def _feedback(
    static: Static,
    params: Params,
    prior: _Prior,
    win: _Window,
    match: _Match,
    post: _Rows,
    x_g: Float[Array, "3"],
    scan: _Scan,
) -> tuple[NasrukfFeatures, _Updated]:
    """Every joint state fed back to the fused pose ``x_g`` (eq. 3, :func:`to_conditional`): the
    features move with the pose correction through their gains, and the updated window features
    take their updated conditionals, one more hit and their updated diameters.

    Returns:
        The features, and the rows' updated and provisional conditionals and diameters (for the
        new features).
    """
    capacity = static.capacity
    mp = params.map
    var_d = jnp.square(mp.sigma_diameter)
    seg, x0, local, new_y, new_L = scan.seg, prior.x, win.local, win.new_y, win.new_L
    existing, ws, ps = match.existing, match.ws, match.ps
    upd = jax.vmap(to_conditional, (0, 0, 0, None))(post.x[:, :3], post.x[:, 3:], post.L, x_g)
    ini = jax.vmap(to_conditional, (0, 0, 0, None))(new_y[:, :3], new_y[:, 3:], new_L, x_g)
    feats = prior.features
    feats = feats._replace(mean=feats.mean + mv(feats.gain, _minus(x_g, x0)))
    target = jnp.where(existing, win.idx[ws], capacity)
    d_old = jnp.where(existing, local.landmarks.diam[ws], seg.diam[ps])
    dv_old = jnp.where(existing, local.landmarks.diam_var[ws], var_d)
    upd_d, upd_dv = diameter_update(d_old, dv_old, seg.diam, mp.sigma_diameter)
    lms = feats.landmarks
    feats = feats._replace(
        mean=feats.mean.at[target].set(upd[0], mode="drop"),
        gain=feats.gain.at[target].set(upd[1], mode="drop"),
        sqrt=feats.sqrt.at[target].set(upd[2], mode="drop"),
        landmarks=lms._replace(
            hits=lms.hits.at[target].add(1, mode="drop"),
            diam=lms.diam.at[target].set(upd_d, mode="drop"),
            diam_var=lms.diam_var.at[target].set(upd_dv, mode="drop"),
        ),
    )
    return feats, _Updated(upd, ini, upd_d, upd_dv)


def _manage(
    static: Static,
    params: Params,
    state: NasrukfState,
    scan: _Scan,
    win: _Window,
    match: _Match,
    x_g: Float[Array, "3"],
    feats: NasrukfFeatures,
) -> NasrukfFeatures:
    """Existence of the window's features at the fused pose ``x_g`` (``static.manage``; a removed
    feature frees its slot; ``feats`` unchanged without management)."""
    if not static.manage:
        return feats
    seg, valid, z_mask, in_window, idx = scan.seg, scan.valid, scan.z_mask, win.in_window, win.idx
    mp = params.map
    W = idx.shape[0]
    existing, ws = match.existing, match.ws
    book = feats.book()
    win_book = jax.tree.map(lambda a: a.at[idx].get(mode="fill", fill_value=0), book)
    win_book = win_book._replace(active=in_window & win_book.active)
    seen = jnp.zeros(W, bool).at[jnp.where(existing, ws, W)].set(True, mode="drop")
    win_book = manage_window(
        win_book,
        x_g,
        seen,
        ScanDetections(seg.z, z_mask, seg.diam),
        valid & seg.is_scan,
        state.scan,
        params.measurement,
        Management(mp, static.occlusion),
    )
    book = drop_stale(jax.tree.map(lambda a, b: a.at[idx].set(b, mode="drop"), book, win_book), state.scan, mp)
    return feats._replace(landmarks=book)  # its mean and cov are not used


def _add_new(
    static: Static,
    params: Params,
    state: NasrukfState,
    scan: _Scan,
    match: _Match,
    updated: _Updated,
    feats: NasrukfFeatures,
) -> tuple[NasrukfFeatures, Int[Array, ""], Int[Array, ""]]:
    """New features as they leave the scan (updated if a later detection matched one), in the free
    slots.

    Returns:
        The features, the number added and the number dropped for want of a slot.
    """
    capacity = static.capacity
    mp = params.map
    var_d = jnp.square(mp.sigma_diameter)
    seg, upd, ini, upd_d, upd_dv = scan.seg, updated.upd, updated.ini, updated.diam, updated.diam_var
    K = seg.z.shape[0]
    known = static.association.known
    is_new = match.assoc.is_new
    pt = jnp.where(match.provisional, match.ps, K)
    extra = jnp.zeros(K, jnp.int32).at[pt].add(1, mode="drop")
    cand = Candidates(
        mean=ini[0][:, :2],
        cov=jnp.broadcast_to(jnp.eye(2), (K, 2, 2)),
        diam=seg.diam.at[pt].set(upd_d, mode="drop"),
        diam_var=jnp.full(K, var_d).at[pt].set(upd_dv, mode="drop"),
        ident=seg.z_id if known else None,
    )
    new_book = new_landmarks(cand, is_new, extra, state.scan, mp, static.manage)
    new = NasrukfFeatures(
        mean=ini[0].at[pt].set(upd[0], mode="drop"),
        gain=ini[1].at[pt].set(upd[1], mode="drop"),
        sqrt=ini[2].at[pt].set(upd[2], mode="drop"),
        landmarks=new_book,
    )
    free, _ = first_true(~feats.landmarks.active, K)
    free = free[jnp.clip(jnp.cumsum(is_new) - 1, 0, K - 1)]
    room = free < capacity
    dest = jnp.where(is_new & room, free, capacity)
    feats = jax.tree.map(lambda a, b: a.at[dest].set(b, mode="drop"), feats, new)
    added = jnp.sum(is_new & room).astype(jnp.int32)
    overflow = jnp.sum(is_new & ~room).astype(jnp.int32)
    return feats, added, overflow


def _output(
    state: NasrukfState,
    scan: _Scan,
    fused: _Fused,
    feats: NasrukfFeatures,
    noise: tuple[Float[Array, " mz"], Array],
    tallies: tuple[Int[Array, ""], Int[Array, ""], Int[Array, ""], Int[Array, ""]],
) -> tuple[NasrukfState, GaussianStepOutput]:
    """The new state (exactly the old one for a padding segment) and the segment's record.

    Args:
        state: the state before the segment.
        scan: the segment's detections (``valid``: False for padding).
        fused: the fused pose and the process-noise estimate.
        feats: the features after the scan.
        noise: the measurement-noise estimate and its count.
        tallies: the detections associated, the features added, those dropped for want of a slot,
            and the features in range left out of the window.
    """
    valid, seg = scan.valid, scan.seg
    noise_v, noise_count = noise
    n_associated, added, overflow, window_overflow = tallies
    # A padding segment leaves the state exactly as it was.
    keep = lambda new_value, old: jax.tree.map(lambda a, b: jnp.where(valid, a, b), new_value, old)  # noqa: E731
    new_state = NasrukfState(
        pose=keep(fused.x, state.pose),
        pose_sqrt=keep(fused.S, state.pose_sqrt),
        features=keep(feats, state.features),
        noise=keep(noise_v, state.noise),
        noise_count=keep(noise_count, state.noise_count),
        process_scale=keep(fused.process_scale, state.process_scale),
        process_count=keep(fused.process_count, state.process_count),
        process_basis=keep(fused.basis, state.process_basis),
        count=jnp.where(valid, jnp.sum(feats.landmarks.active), state.count).astype(jnp.int32),
        overflow=state.overflow + overflow,
        scan=state.scan + (valid & seg.is_scan).astype(jnp.int32),
    )
    x = new_state.pose
    finite = jnp.all(jnp.isfinite(x)) & jnp.all(jnp.isfinite(new_state.pose_sqrt))
    record = GaussianStepOutput(
        pose=x,
        pose_cov=new_state.pose_cov,
        n_landmarks=new_state.count,
        n_confirmed=jnp.sum(new_state.features.landmarks.active & new_state.features.landmarks.confirmed).astype(
            jnp.int32
        ),
        n_associated=n_associated,
        n_new=added,
        overflow=overflow,
        n_nonfinite=(~finite).astype(jnp.int32),
        window_overflow=window_overflow,
    )
    return new_state, record


def nasrukf_step(
    static: Static,
    params: Params,
    state: NasrukfState,
    seg: Segments,
    valid: Bool[Array, ""] | bool = True,
) -> tuple[NasrukfState, GaussianStepOutput]:
    """Advance NASRUKF FastSLAM through one segment (see the module docstring).

    Args:
        static: static settings (``capacity``, ``window``, ``sequential``, ``adaptive_noise``,
            NASRUKF's ``feature`` and ``adaptive_process``).
        params: hyperparameters (noise, gates, unscented parameters, ``forgetting``,
            ``noise_floor``, NASRUKF's ``new_feature_hits``).
        state: the state at the previous segment.
        seg: one segment (a :class:`Segments` without the leading axis).
        valid: False for a padding segment: the state is then returned unchanged (exactly).

    Returns:
        The new state and the segment's :class:`~._gaussian.GaussianStepOutput` (the fused pose
        and its covariance).
    """
    if not is_range_bearing(params.measurement):
        raise ValueError(
            f"model.measurement: NASRUKF runs range-bearing models only, not {type(params.measurement).__name__}"
        )
    valid = jnp.asarray(valid)
    W = min(static.window, static.capacity)
    arc = nasrukf_static(static).feature == "arc"
    noise = state.noise if static.adaptive_noise else configured_noise(static, params)
    z = jnp.concatenate([seg.z, seg.diam[:, None]], 1) if arc else seg.z
    scan = _Scan(seg, valid, seg.z_mask & valid, z)
    prior = _time_update(static, params, state, scan)
    win = _window(static, params, prior, scan, noise)
    match = _associate(static, params, prior, win, scan, noise)
    post, noise, noise_count = _measurement_updates(static, params, state, prior, win, match, scan, noise)
    fused = _fuse(static, params, state, prior, win, match, post)
    feats, updated = _feedback(static, params, prior, win, match, post, fused.x, scan)
    feats = _manage(static, params, state, scan, win, match, fused.x, feats)
    feats, added, overflow = _add_new(static, params, state, scan, match, updated, feats)
    n_associated = jnp.sum(match.matched).astype(jnp.int32)
    window_overflow = jnp.maximum(win.n_near - W, 0).astype(jnp.int32)
    return _output(state, scan, fused, feats, (noise, noise_count), (n_associated, added, overflow, window_overflow))
