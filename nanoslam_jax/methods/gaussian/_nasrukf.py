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
from jaxtyping import Array, Bool, Float

from nanoslam_jax.lib._linalg import chol3, inv2, inv3, mm, mmt, mt, mv, sandwich, sym
from nanoslam_jax.data import Segments
from nanoslam_jax.models import (
    inverse_range_bearing,
    is_range_bearing,
    range_bearing,
    range_bearing_jacobians,
    wrap_angle,
)
from nanoslam_jax.lib.quadrature import Unscented
from nanoslam_jax.methods.maps._association import nearest_neighbours
from nanoslam_jax.methods.maps._landmarks import first_true
from nanoslam_jax.methods.maps._management import diameter_update, drop_stale, manage_window, new_landmarks
from nanoslam_jax.methods._params import Params, Static
from nanoslam_jax.methods.gaussian._srukf import (
    SigmaMeasurement,
    adaptive_noise_rows,
    adaptive_process_update,
    chol_rank_update,
    measurement_update,
    predict_measurement,
    process_noise_basis,
    srukf_transform,
)
from nanoslam_jax.methods._method_settings import nasrukf_params, nasrukf_static
from nanoslam_jax.methods.gaussian._nasrukf_state import NasrukfFeatures, NasrukfState, configured_noise, feature_dim
from nanoslam_jax.methods.gaussian._gaussian import GaussianStepOutput


def _rule(params: Params) -> Unscented:
    return Unscented(params.ut_alpha, params.ut_beta, params.ut_kappa)


def _minus(a: Float[Array, "3"], b: Float[Array, "3"]) -> Float[Array, "3"]:
    """Pose difference ``a - b`` with the heading wrapped."""
    d = a - b
    return d.at[2].set(wrap_angle(d[2]))


def pose_time_update(
    x: Float[Array, "3"],
    S: Float[Array, "3 3"],
    dt: Float[Array, " dr"],
    u: Float[Array, "dr c"],
    dr_mask: Bool[Array, " dr"],
    params: Params,
    noise_scale_sqrt: Float[Array, "w w"] | None = None,
) -> tuple[Float[Array, "3"], Float[Array, "3 3"], Float[Array, "3 3"], Float[Array, "3 3"]]:
    """The pose's SR-UKF time update through a segment's DR pieces, with its start pose carried.

    The state ``(x, x_start)`` starts as ``(x, x)`` with square root ``[[S, 0], [S, 0]]``; each
    real piece is a :func:`~._srukf.srukf_transform` with the control noise augmented
    (``x <- f(x, u + w)``, ``x_start`` unchanged). From the final square root
    ``[[S_x, 0], [S_sx, D]]``: ``T = S_sx S_x^-1`` (the start pose's regression on the predicted
    one) and ``D`` (the square root of ``Cov(x_start | x)``).

    Args:
        x, S: the pose mean and lower square root at the start of the segment.
        dt, u, dr_mask: the segment's DR pieces (masked pieces change nothing).
        params: vehicle constants, control noise, unscented parameters.
        noise_scale_sqrt: a lower square root ``Lambda^(1/2)`` scaling the motion model's noise,
            ``S(dt) Lambda^(1/2)`` (the estimated ``Q`` of eq. 9); None: the configured noise.

    Returns:
        The predicted mean and square root, ``T`` and ``D``.
    """
    rule = _rule(params)
    zero = jnp.zeros((3, 3), S.dtype)
    L = jnp.concatenate([jnp.concatenate([S, zero], 1), jnp.concatenate([S, zero], 1)], 0)
    motion = params.motion

    def body(i, carry):
        y, L = carry

        def move(p, w):
            return jnp.concatenate([motion.noisy_step(p[:3], u[i], w, dt[i]), p[3:]])

        Sw = motion.noise_sqrt(dt[i])
        Sw = Sw if noise_scale_sqrt is None else Sw @ noise_scale_sqrt
        yn, Ln = srukf_transform(y, L, move, Sw, rule, angles=(2, 5))
        return jnp.where(dr_mask[i], yn, y), jnp.where(dr_mask[i], Ln, L)

    n_pieces = jnp.max(jnp.where(dr_mask, jnp.arange(1, dr_mask.shape[0] + 1), 0))
    y, L = jax.lax.fori_loop(0, n_pieces, body, (jnp.concatenate([x, x]), L))
    Sx = L[:3, :3]
    return y[:3], Sx, mm(L[3:, :3], inv3(Sx)), L[3:, 3:]


def propagate_features(features: NasrukfFeatures, T: Float[Array, "3 3"], D: Float[Array, "3 3"]) -> NasrukfFeatures:
    """The features' part of the joint time update: ``gain <- gain T``, ``sqrt sqrt' += gain D D' gain'``
    (rank-one ``cholupdate`` with each column of ``gain D``)."""
    cols = mm(features.gain, D)
    sqrt = jax.vmap(chol_rank_update, (0, 0, None))(features.sqrt, cols, 1.0)
    return features._replace(gain=mm(features.gain, T), sqrt=sqrt)


def joint_sqrt(S: Float[Array, "3 3"], gain: Float[Array, "f 3"], sqrt: Float[Array, "f f"]) -> Float[Array, "n n"]:
    """Lower square root ``[[S, 0], [gain S, sqrt]]`` of a feature's joint state (pose first)."""
    f = gain.shape[0]
    top = jnp.concatenate([S, jnp.zeros((3, f), S.dtype)], 1)
    return jnp.concatenate([top, jnp.concatenate([gain @ S, sqrt], 1)], 0)


def to_conditional(
    x: Float[Array, "3"], m: Float[Array, " f"], L: Float[Array, "n n"], x_global: Float[Array, "3"]
) -> tuple[Float[Array, " f"], Float[Array, "f 3"], Float[Array, "f f"]]:
    """A joint state ``N((x, m), L L')`` fed back to the global pose (the feature's conditional kept).

    Returns:
        The feature's ``(mean, gain, sqrt)`` given the shared pose: ``gain = L_mx L_xx^-1``,
        ``sqrt = L_mm``, ``mean = m + gain (x_global - x)``.
    """
    gain = mm(L[3:, :3], inv3(L[:3, :3]))
    return m + gain @ _minus(x_global, x), gain, L[3:, 3:]


def measure(y: Float[Array, " n"]) -> Float[Array, " mz"]:
    """A joint state's predicted detection: range and bearing of the centre (and the diameter,
    twice the radius, for arcs)."""
    zb = range_bearing(y[:3], y[3:5])
    return jnp.concatenate([zb, 2.0 * y[5:6]]) if y.shape[0] == 6 else zb


def init_feature(
    x: Float[Array, "3"], S: Float[Array, "3 3"], z: Float[Array, " mz"], noise: Float[Array, " mz"], params: Params
) -> tuple[Float[Array, " n"], Float[Array, "n n"]]:
    """A new feature's joint state: the SR unscented transform of (pose, detection) through
    ``(x, m) = (x, g^-1(x, z))`` (and the radius as half the diameter for arcs).

    Args:
        x, S: the pose mean and lower square root.
        z: the detection (range, bearing[, diameter]).
        noise: measurement-noise variances.
        params: unscented parameters.
    """

    def place(p, w):
        zw = z + w
        parts = [p, inverse_range_bearing(p, zw[:2])] + ([0.5 * zw[2:3]] if z.shape[0] == 3 else [])
        return jnp.concatenate(parts)

    return srukf_transform(x, S, place, jnp.diag(jnp.sqrt(noise)), _rule(params), angles=(2,))


def association_information(
    x: Float[Array, "3"],
    P: Float[Array, "3 3"],
    mean: Float[Array, "slots f"],
    gain: Float[Array, "slots f 3"],
    sqrt: Float[Array, "slots f f"],
    R: Float[Array, "2 2"],
) -> tuple[
    tuple[Float[Array, " slots"], Float[Array, " slots"]],
    tuple[Float[Array, " slots"], Float[Array, " slots"], Float[Array, " slots"]],
]:
    """Predicted range and bearing of each slot's centre and the entries of its inverse innovation
    covariance ``J P J' + Gm C Gm' + R``, ``J = Gx + Gm gain`` (joint state linearised, autodiff)."""
    c = mean[:, :2]
    z_hat = jax.vmap(range_bearing, (None, 0))(x, c)
    Gx, Gm = jax.vmap(range_bearing_jacobians, (None, 0))(x, c)
    J = Gx + mm(Gm, gain[:, :2])
    s = sqrt[:, :2, :2]
    Si = inv2(sym(sandwich(J, P) + sandwich(Gm, mmt(s, s)) + R))
    return (z_hat[:, 0], z_hat[:, 1]), (Si[:, 0, 0], Si[:, 0, 1], Si[:, 1, 1])


def _information(L: Float[Array, "3 3"]) -> Float[Array, "3 3"]:
    """``(L L')^-1`` from a lower square root."""
    Li = inv3(L)
    return mm(mt(Li), Li)


def fuse_poses(
    x0: Float[Array, "3"],
    S0: Float[Array, "3 3"],
    xs: Float[Array, "k 3"],
    Ls: Float[Array, "k 3 3"],
    use: Bool[Array, " k"],
    shared_prior: bool = True,
) -> tuple[Float[Array, "3"], Float[Array, "3 3"]]:
    """The global pose from per-feature pose estimates, information-weighted (eq. 4-5).

    Args:
        x0, S0: the scan's prior pose (mean, lower square root).
        xs, Ls: the per-feature pose estimates (means, lower square roots).
        use: which estimates take part (none: the prior is returned).
        shared_prior: the estimates all started from ``N(x0, S0 S0')`` (the filter's case): eq. 4
            is applied to their information gains over it, ``Lambda = Lambda_0 + sum_i (Lambda_i -
            Lambda_0)``, the exact posterior when the detections are independent given the pose.
            False: eq. 4 as printed for independent estimates, ``Lambda = sum_i Lambda_i``. Both
            ``x = x0 + Lambda^-1 sum_i Lambda_i (x_i - x0)`` (headings relative to ``x0``).

    Returns:
        The fused mean (heading wrapped) and the lower square root of ``Lambda^-1``.
    """
    I0 = _information(S0)
    Ii = jax.vmap(_information)(Ls)
    w = use.astype(x0.dtype)
    eta = jnp.sum(w[:, None] * mv(Ii, jax.vmap(_minus, (0, None))(xs, x0)), axis=0)
    if shared_prior:
        Lam = I0 + jnp.sum(w[:, None, None] * (Ii - I0), axis=0)
    else:
        Lam = jnp.where(jnp.any(use), jnp.sum(w[:, None, None] * Ii, axis=0), I0)
    P = sym(inv3(sym(Lam)))
    x = x0 + P @ eta
    return x.at[2].set(wrap_angle(x[2])), chol3(P)


class _Rows(NamedTuple):
    """Per detection row: the joint state it updates (before), and after."""

    x: Float[Array, "k n"]
    L: Float[Array, "k n n"]


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
    capacity, K = static.capacity, seg.z.shape[0]
    W = min(static.window, capacity)
    ns, nk = nasrukf_static(static), nasrukf_params(params)
    arc = ns.feature == "arc"
    noise = state.noise if static.adaptive_noise else configured_noise(static, params)

    # 1. Time update: the pose (with the estimated process noise), then every feature's part of its joint state.
    dr_mask = seg.dr_mask & valid
    if ns.adaptive_process:
        scale_sqrt = jnp.linalg.cholesky(state.process_scale)
        basis = process_noise_basis(state.process_basis, state.pose, seg.dt, seg.u, dr_mask, params.motion)
    else:
        scale_sqrt, basis = None, state.process_basis
    x0, S0, T, D = pose_time_update(state.pose, state.pose_sqrt, seg.dt, seg.u, dr_mask, params, scale_sqrt)
    P0 = mmt(S0, S0)
    feats = propagate_features(state.features, T, D)

    # 2. The local window and one provisional feature per detection (at the prior pose).
    f = feats
    radius = params.max_range + params.window_margin
    d2 = jnp.square(f.mean[:, 0] - x0[0]) + jnp.square(f.mean[:, 1] - x0[1])
    idx, n_near = first_true(f.landmarks.active & (d2 < jnp.square(radius)), W)
    local = jax.tree.map(lambda a: a.at[idx].get(mode="fill", fill_value=0), f)
    in_window = idx < capacity
    z_mask = seg.z_mask & valid
    z = jnp.concatenate([seg.z, seg.diam[:, None]], 1) if arc else seg.z
    new_y, new_L = jax.vmap(init_feature, (None, None, 0, None, None))(x0, S0, z, noise, params)
    prov = jax.vmap(to_conditional, (0, 0, 0, None))(new_y[:, :3], new_y[:, 3:], new_L, x0)
    # Unused window slots hold a finite dummy feature 1 m ahead of the pose (never matched).
    dummy = jnp.concatenate([x0[:2] + jnp.array([1.0, 0.0]), jnp.ones(feature_dim(static) - 2)])
    mean = jnp.concatenate([jnp.where(in_window[:, None], local.mean, dummy), prov[0]])
    gain = jnp.concatenate([local.gain, prov[1]])
    sqrt = jnp.concatenate([local.sqrt, prov[2]])

    # 3. Association with the other methods' rule and gates.
    z_hat, s_inv = association_information(x0, P0, mean, gain, sqrt, jnp.diag(noise[:2]))
    mp = params.map
    var_d = jnp.square(mp.sigma_diameter)
    diam_term = (
        seg.diam,
        jnp.concatenate([local.landmarks.diam, seg.diam]),
        1.0 / (jnp.concatenate([local.landmarks.diam_var, jnp.full(K, var_d)]) + var_d),
        mp.use_diameter,
    )
    known = static.association == "known"
    id_term = (seg.z_id, jnp.concatenate([local.landmarks.ident, seg.z_id])) if known else None
    assoc = nearest_neighbours(
        z_hat, s_inv, in_window, seg.z, z_mask, params.gate, params.new_landmark, static.sequential, diam_term, id_term
    )
    matched = assoc.slot >= 0
    existing = matched & (assoc.slot < W)
    provisional = matched & ~existing
    slot = jnp.where(matched, assoc.slot, W + jnp.arange(K))  # unmatched rows: their own provisional feature
    ws = jnp.clip(assoc.slot, 0, W - 1)
    ps = jnp.clip(assoc.slot - W, 0, K - 1)

    # 4. The matched joint states' measurement updates, with the adaptive noise estimate first.
    rows = _Rows(
        jax.vmap(lambda m: jnp.concatenate([x0, m]))(mean[slot]),
        jax.vmap(joint_sqrt, (None, 0, 0))(S0, gain[slot], sqrt[slot]),
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
            matched,
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

    # 5. Fusion of the pose estimates of the features with enough data, 6. feedback.
    hits_before = jnp.where(existing, local.landmarks.hits[ws], 1)
    fuse = matched & (hits_before >= nk.new_feature_hits)
    if static.manage:  # tentative features (and those started in this scan) move the pose only if asked
        fuse = fuse & ((existing & local.landmarks.confirmed[ws]) | mp.use_tentative)
    x_g, S_g = fuse_poses(x0, S0, post.x[:, :3], post.L[:, :3, :3], fuse)
    process_scale, process_count = state.process_scale, state.process_count
    if ns.adaptive_process:  # the estimated Q from the fused joint states' corrections and covariance changes
        dx = jax.vmap(_minus, (0, None))(post.x[:, :3], x0)
        Pi = mmt(post.L[:, :3, :3], post.L[:, :3, :3])
        w = fuse.astype(x0.dtype)
        change = jnp.sum(w[:, None, None] * (dx[:, :, None] * dx[:, None, :] + Pi - P0), axis=0) / jnp.maximum(
            jnp.sum(w), 1.0
        )
        updated = jnp.any(fuse)
        new_scale = adaptive_process_update(
            process_scale, process_count, change, S0, basis, nk.process_forgetting, nk.process_floor
        )
        process_scale = jnp.where(updated, new_scale, process_scale)
        process_count = process_count + updated.astype(process_count.dtype)
        basis = jnp.where(updated, jnp.zeros_like(basis), basis)
    upd = jax.vmap(to_conditional, (0, 0, 0, None))(post.x[:, :3], post.x[:, 3:], post.L, x_g)
    ini = jax.vmap(to_conditional, (0, 0, 0, None))(new_y[:, :3], new_y[:, 3:], new_L, x_g)
    feats = feats._replace(mean=feats.mean + mv(feats.gain, _minus(x_g, x0)))
    target = jnp.where(existing, idx[ws], capacity)
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

    # Existence of the window's features at the fused pose (a removed feature frees its slot).
    if static.manage:
        book = feats.book()
        win = jax.tree.map(lambda a: a.at[idx].get(mode="fill", fill_value=0), book)
        win = win._replace(active=in_window & win.active)
        seen = jnp.zeros(W, bool).at[jnp.where(existing, ws, W)].set(True, mode="drop")
        win = manage_window(
            win,
            x_g,
            seen,
            seg.z,
            z_mask,
            seg.diam,
            valid & seg.is_scan,
            state.scan,
            params.measurement,
            mp,
            static.occlusion,
        )
        book = drop_stale(jax.tree.map(lambda a, b: a.at[idx].set(b, mode="drop"), book, win), state.scan, mp)
        feats = feats._replace(landmarks=book)  # its mean and cov are not used

    # New features as they leave the scan (updated if a later detection matched one), in free slots.
    is_new = assoc.is_new
    pt = jnp.where(provisional, ps, K)
    extra = jnp.zeros(K, jnp.int32).at[pt].add(1, mode="drop")
    new_book = new_landmarks(
        mean=ini[0][:, :2],
        cov=jnp.broadcast_to(jnp.eye(2), (K, 2, 2)),
        is_new=is_new,
        extra_hits=extra,
        diam=seg.diam.at[pt].set(upd_d, mode="drop"),
        diam_var=jnp.full(K, var_d).at[pt].set(upd_dv, mode="drop"),
        scan=state.scan,
        mp=mp,
        manage=static.manage,
        ident=seg.z_id if known else None,
    )
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

    # A padding segment leaves the state exactly as it was.
    keep = lambda new_value, old: jax.tree.map(lambda a, b: jnp.where(valid, a, b), new_value, old)  # noqa: E731
    new_state = NasrukfState(
        pose=keep(x_g, state.pose),
        pose_sqrt=keep(S_g, state.pose_sqrt),
        features=keep(feats, state.features),
        noise=keep(noise, state.noise),
        noise_count=keep(noise_count, state.noise_count),
        process_scale=keep(process_scale, state.process_scale),
        process_count=keep(process_count, state.process_count),
        process_basis=keep(basis, state.process_basis),
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
        n_associated=jnp.sum(matched).astype(jnp.int32),
        n_new=added,
        overflow=overflow,
        n_nonfinite=(~finite).astype(jnp.int32),
        window_overflow=jnp.maximum(n_near - W, 0).astype(jnp.int32),
    )
    return new_state, record
