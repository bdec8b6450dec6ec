"""EKF-SLAM: one joint Gaussian over the pose and all landmarks (algorithms.md section 3).

The state is a fixed-capacity joint Gaussian ``N(mean, cov)`` over
``(px, py, phi, m_0x, m_0y, ..., m_{C-1}x, m_{C-1}y)``, ``n = 3 + 2 C``, with an ``active`` mask.
Landmarks only ever get added (no pruning), so the active slots are a prefix of the map and a
new landmark takes slot ``count``. An inactive slot has mean 0, an identity 2x2 diagonal block
and zero cross-covariance with everything: it enters no innovation covariance and no gain, so
it affects nothing (the results do not depend on the capacity).

Per segment (:func:`ekf_slam_step`):

1. **Prediction** (:func:`ekf_slam_predict`): the pose is propagated through the segment's DR
   pieces by first-order linearisation with autodiff Jacobians (``F_i``, ``G_i`` of
   :func:`~nanoslam_jax.models.vehicle_step` per piece): ``P_xx <- F_i P_xx F_i' + G_i Q G_i'``
   composed over the pieces, and the pose-landmark cross-covariance ``P_xm <- F P_xm`` with
   ``F = prod F_i``. This is exactly the dense linearised joint prediction, touching only the
   three pose rows and columns: O(C), not O(C^2). EKF-SLAM always uses this linearised prior
   (``static.prior`` is not used): mixing an unscented ``P_xx`` with Jacobian cross-covariances
   would not be a joint linearisation and need not stay positive semi-definite.
2. **Sequential detections** (a ``while_loop`` over the scan's real detections, in order): the
   innovation covariance of every slot, ``S_j = H_j P H_j' + R`` with ``H_j`` over the pose and
   landmark ``j`` (pose-landmark cross-covariance included), is assembled from gathered 3x3,
   3x2 and 2x2 blocks (O(C)); the nearest available landmark by Mahalanobis distance is matched
   if ``d2 < gate`` and gets an EKF update of the whole joint state (:func:`ekf_slam_update`);
   a detection whose best ``d2 > new_landmark`` augments the state (:func:`ekf_slam_augment`);
   detections in between are dropped. With ``static.sequential`` a landmark is claimed at most
   once per scan and one created by detection k can be matched by a later detection; without
   it, all detections are associated with the landmarks existing after the prediction (the
   closest claimant keeps a contested landmark) and then applied in order.
3. The covariance update is the symmetric rank-2 form ``P <- P - V'V`` with ``V = L^-1 H P``
   and ``S = L L'`` (no n x n product). It keeps ``P`` exactly symmetric (each element is
   computed from commuting products), so no symmetrisation pass is needed; the Joseph form
   would be O(n^3) on the joint state and is not used. Positive semi-definiteness is not
   enforced beyond that: ``S`` is symmetrised and its Cholesky factor has floored pivots, and a
   non-finite state is reported (``n_nonfinite``), never hidden. ``V`` vanishes outside the
   active prefix ``3 + 2 count``, so the update runs over the tiles of that prefix only
   (:func:`rank2_downdate`): the cost per detection is O(map^2), not O(capacity^2).
4. No ``cond``/``switch`` around the big buffers (XLA would copy ``P``): an unmatched
   detection's update runs over zero tiles, an augmentation that does not happen scatters to
   out-of-range indices (dropped), and the pose rows are written in place.

Jacobians come from autodiff of the models (range-bearing, its inverse, the vehicle), never
hand-written formulas.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int, Key

from .._linalg import chol2, inv2, mm, mmt, mt, quad_form, sandwich, sym
from ..data import Segments
from ..models import (
    innovation,
    inverse_range_bearing,
    inverse_range_bearing_jacobians,
    range_bearing,
    range_bearing_jacobians,
    vehicle_jacobians,
    vehicle_step,
    wrap_angle,
)
from ._params import Params, Static
from ._state import LandmarkMap
from ._step import StepOutput


class EkfSlamState(NamedTuple):
    """The EKF-SLAM state carried from one segment to the next.

    Attributes:
        mean: joint mean ``(px, py, phi, m_0, ..., m_{C-1})``, ``n = 3 + 2 C``.
        cov: joint covariance (exactly symmetric).
        active: which landmark slots hold a landmark (a prefix of the slots).
        hits: detections associated with each landmark (1 at creation).
        count: number of active landmarks (the next free slot).
        key: PRNG key (unused by the filter; carried for the driver).
        resample_count: always 0 (no particles).
        overflow: new landmarks dropped so far because the state was full.
    """

    mean: Float[Array, "n"]
    cov: Float[Array, "n n"]
    active: Bool[Array, "capacity"]
    hits: Int[Array, "capacity"]
    count: Int[Array, ""]
    key: Key[Array, ""]
    resample_count: Int[Array, ""]
    overflow: Int[Array, ""]

    def landmark_map(self) -> LandmarkMap:
        """The landmark marginals as a :class:`LandmarkMap` (means, 2x2 blocks, no misses)."""
        capacity = self.active.shape[0]
        return LandmarkMap(
            mean=landmark_means(self.mean),
            cov=landmark_blocks(self.cov, capacity),
            active=self.active,
            hits=self.hits,
            misses=jnp.zeros(capacity, jnp.int32),
        )


def landmark_means(mean: Float[Array, "n"]) -> Float[Array, "capacity 2"]:
    """The landmark part of the joint mean as ``(capacity, 2)`` positions."""
    return mean[3:].reshape(-1, 2)


def landmark_blocks(cov: Float[Array, "n n"], capacity: int) -> Float[Array, "capacity 2 2"]:
    """The 2x2 diagonal blocks (landmark marginal covariances) of the joint covariance.

    Args:
        cov: joint covariance.
        capacity: number of landmark slots.
    """
    i = 3 + 2 * jnp.arange(capacity)
    a, b, c = cov[i, i], cov[i, i + 1], cov[i + 1, i + 1]
    return jnp.stack([jnp.stack([a, b], -1), jnp.stack([b, c], -1)], -2)


def init_ekf_state(static: Static, params: Params, key: Key[Array, ""]) -> EkfSlamState:
    """The pose at the origin with covariance ``init_cov * I``, no landmarks.

    Args:
        static: static settings (``capacity``).
        params: hyperparameters (``init_cov``).
        key: PRNG key (carried, unused).
    """
    c = static.capacity
    n = 3 + 2 * c
    diag = jnp.concatenate([jnp.full((3,), params.init_cov, dtype=float), jnp.ones(2 * c)])
    zero = jnp.zeros((), jnp.int32)
    return EkfSlamState(
        mean=jnp.zeros(n), cov=jnp.diag(diag), active=jnp.zeros(c, bool), hits=jnp.zeros(c, jnp.int32),
        count=zero, key=key, resample_count=zero, overflow=zero,
    )


def ekf_slam_predict(
    mean: Float[Array, "n"],
    cov: Float[Array, "n n"],
    dt: Float[Array, "dr"],
    u: Float[Array, "dr 2"],
    dr_mask: Bool[Array, "dr"],
    params: Params,
) -> tuple[Float[Array, "n"], Float[Array, "n n"]]:
    """Linearised joint prediction through a segment's DR pieces; only the pose rows change.

    Args:
        mean, cov: joint Gaussian at the start of the segment.
        dt: piece durations (padding: 0).
        u: piece controls ``(ve, alpha)``.
        dr_mask: which pieces are real (masked pieces change nothing).
        params: vehicle constants and control noise ``Q``.

    Returns:
        The joint mean and covariance at the scan time: pose mean ``f(x, u)``,
        ``P_xx = F_i P_xx F_i' + G_i Q G_i'`` composed over the pieces, ``P_xm = F P_xm`` with
        ``F`` the product of the pieces' pose Jacobians, ``P_mm`` unchanged.
    """
    Q = params.Q

    def body(carry, inp):
        x, Pxx, F = carry
        dti, ui, mi = inp
        Fi, Gi = vehicle_jacobians(x, ui, dti, params.vehicle)
        xn = vehicle_step(x, ui, dti, params.vehicle)
        Pn = sym(sandwich(Fi, Pxx) + sandwich(Gi, Q))
        Fn = mm(Fi, F)
        return (jnp.where(mi, xn, x), jnp.where(mi, Pn, Pxx), jnp.where(mi, Fn, F)), None

    x0, Pxx0 = mean[:3], cov[:3, :3]
    (x, Pxx, F), _ = jax.lax.scan(body, (x0, Pxx0, jnp.eye(3, dtype=mean.dtype)), (dt, u, dr_mask))
    # Without a real piece F = I exactly, so the rows are rewritten with their own values (no
    # masked select here: a select against the old rows would make XLA copy the matrix).
    rows = jnp.concatenate([Pxx, F @ cov[:3, 3:]], axis=1)
    cov = cov.at[:3, :].set(rows).at[:, :3].set(rows.T)
    return mean.at[:3].set(x), cov


def slot_innovations(
    mean: Float[Array, "n"], cov: Float[Array, "n n"], z: Float[Array, "2"], R: Float[Array, "2 2"],
    usable: Bool[Array, "capacity"],
) -> tuple[Float[Array, "capacity 2"], Float[Array, "capacity 2 2"]]:
    """Innovation and innovation covariance of detection ``z`` against every landmark slot.

    ``S_j = H_j P H_j' + R`` with ``H_j = [Gx, 0.., Gm, 0..]`` (autodiff Jacobians at the
    current mean), assembled from the pose block, the pose-landmark cross block and the
    landmark block of slot ``j``: O(capacity). Slots not ``usable`` are evaluated at a dummy
    landmark 1 m from the pose (finite values; the caller masks them).

    Args:
        mean, cov: joint Gaussian.
        z: the detection ``(r, beta)``.
        R: measurement noise covariance.
        usable: slots to evaluate at their mean.
    """
    capacity = usable.shape[0]
    x = mean[:3]
    lm = jnp.where(usable[:, None], landmark_means(mean), x[:2] + jnp.array([1.0, 0.0]))
    z_hat = jax.vmap(range_bearing, (None, 0))(x, lm)
    Gx, Gm = jax.vmap(range_bearing_jacobians, (None, 0))(x, lm)
    Pxx = cov[:3, :3]
    Pxl = jnp.transpose(cov[:3, 3:].reshape(3, capacity, 2), (1, 0, 2))  # (C, 3, 2)
    Pll = landmark_blocks(cov, capacity)
    C = mmt(mm(Gx, Pxl), Gm)
    S = sandwich(Gx, Pxx[None]) + C + mt(C) + sandwich(Gm, Pll) + R
    nu = jax.vmap(innovation, (None, 0))(z, z_hat)
    return nu, S


def association_distances(
    mean: Float[Array, "n"], cov: Float[Array, "n n"], z: Float[Array, "2"], R: Float[Array, "2 2"],
    available: Bool[Array, "capacity"],
) -> Float[Array, "capacity"]:
    """Squared Mahalanobis distance of ``z`` to every available landmark (inf elsewhere)."""
    nu, S = slot_innovations(mean, cov, z, R, available)
    return jnp.where(available, quad_form(nu, inv2(S)), jnp.inf)


#: Side of the square blocks in which the covariance update touches only the active part of P.
BLOCK = 128


def rank2_downdate(
    cov: Float[Array, "n n"], v0: Float[Array, "n"], v1: Float[Array, "n"], size: Int[Array, ""] | int | None = None,
    block: int = BLOCK,
) -> Float[Array, "n n"]:
    """``cov - (v0 v0' + v1 v1')`` on the leading ``size x size`` part of ``cov``.

    The update is applied in ``block x block`` tiles by a loop over the tiles that meet the
    leading part (cost O(size^2), not O(n^2)); each element is ``P_ab - (v0_a v0_b + v1_a v1_b)``,
    so a symmetric ``cov`` stays exactly symmetric. Entries outside the leading part are left
    as they are (the caller guarantees ``v0``, ``v1`` vanish there, so this is the full update).

    Args:
        cov: the matrix to update.
        v0, v1: the two update vectors.
        size: leading rows/columns to update (default: all); may be traced. 0 updates nothing.
        block: tile side.
    """
    n = cov.shape[0]
    B = min(block, n)
    size = n if size is None else jnp.minimum(jnp.asarray(size, jnp.int32), n)
    nb = (size + B - 1) // B
    idx = jnp.arange(B, dtype=jnp.int32)

    def body(t, P):
        bi, bj = t // nb, t % nb
        r_nom, c_nom = bi * B, bj * B
        # The last tile is clamped inside the matrix; rows/columns of earlier tiles are masked.
        r0, c0 = jnp.minimum(r_nom, n - B), jnp.minimum(c_nom, n - B)
        a0, a1 = jax.lax.dynamic_slice(v0, (r0,), (B,)), jax.lax.dynamic_slice(v1, (r0,), (B,))
        b0, b1 = jax.lax.dynamic_slice(v0, (c0,), (B,)), jax.lax.dynamic_slice(v1, (c0,), (B,))
        keep = ((r0 + idx) >= r_nom)[:, None] & ((c0 + idx) >= c_nom)[None, :]
        d = a0[:, None] * b0[None, :] + a1[:, None] * b1[None, :]
        tile = jax.lax.dynamic_slice(P, (r0, c0), (B, B))
        return jax.lax.dynamic_update_slice(P, tile - jnp.where(keep, d, 0.0), (r0, c0))

    return jax.lax.fori_loop(0, nb * nb, body, cov)


def ekf_slam_update(
    mean: Float[Array, "n"], cov: Float[Array, "n n"], z: Float[Array, "2"], slot: Int[Array, ""] | int,
    R: Float[Array, "2 2"], size: Int[Array, ""] | int | None = None, apply: Bool[Array, ""] | bool = True,
) -> tuple[Float[Array, "n"], Float[Array, "n n"]]:
    """EKF update of the joint state with detection ``z`` of landmark ``slot``.

    ``W = H P`` (2 x n) is formed from the pose rows and the landmark's two rows of ``P``;
    ``S = W H' + R = L L'``; ``V = L^-1 W``; then ``mean += V' L^-1 nu`` and ``P -= V'V``
    (the symmetric rank-2 form of ``P - K S K'``, exactly symmetric, O(n^2); see
    :func:`rank2_downdate`).

    Args:
        mean, cov: joint Gaussian.
        z: the detection ``(r, beta)`` (bearing residual wrapped).
        slot: the landmark slot it is associated with.
        R: measurement noise covariance.
        size: leading rows/columns of ``P`` that can be non-zero in ``W`` (``3 + 2 count``
            with the active slots a prefix; default: all). Only that part of ``P`` is touched.
        apply: when False the state is returned unchanged (no covariance work is done).

    Returns:
        The updated joint mean (heading wrapped) and covariance.
    """
    n = mean.shape[0]
    apply = jnp.asarray(apply)
    row = (3 + 2 * jnp.asarray(slot)).astype(jnp.int32)
    z0 = jnp.zeros((), jnp.int32)
    x = mean[:3]
    m = jax.lax.dynamic_slice(mean, (row,), (2,))
    Gx, Gm = range_bearing_jacobians(x, m)
    nu = innovation(z, range_bearing(x, m))
    W = Gx @ cov[:3, :] + Gm @ jax.lax.dynamic_slice(cov, (row, z0), (2, n))
    S = sym(mmt(W[:, :3], Gx) + mmt(jax.lax.dynamic_slice(W, (z0, row), (2, 2)), Gm) + R)
    L = chol2(S)
    l11, l21, l22 = L[0, 0], L[1, 0], L[1, 1]
    v0 = W[0] / l11
    v1 = (W[1] - l21 * v0) / l22
    w0 = nu[0] / l11
    w1 = (nu[1] - l21 * w0) / l22
    updated = mean + v0 * w0 + v1 * w1
    mean = jnp.where(apply, updated.at[2].set(wrap_angle(updated[2])), mean)
    size = n if size is None else size
    cov = rank2_downdate(cov, v0, v1, jnp.where(apply, size, 0))
    return mean, cov


def ekf_slam_augment(
    mean: Float[Array, "n"], cov: Float[Array, "n n"], z: Float[Array, "2"], slot: Int[Array, ""] | int,
    R: Float[Array, "2 2"], apply: Bool[Array, ""] | bool = True,
) -> tuple[Float[Array, "n"], Float[Array, "n n"]]:
    """Add a landmark from detection ``z`` in (free) slot ``slot``, with full cross-covariances.

    With ``m = h^-1(x, z)`` and its Jacobians ``Gx`` (pose) and ``Gz`` (detection) by autodiff:
    ``P_mm = Gx P_xx Gx' + Gz R Gz'`` and ``P_m,rest = Gx P_x,rest`` (the slot's old values are
    those of an inactive slot: zero cross-covariance, so ``P_m,rest`` is zero there too).
    O(n): two rows, two columns and a 2x2 block are written.

    Args:
        mean, cov: joint Gaussian; ``slot`` must be inactive.
        z: the detection ``(r, beta)``.
        slot: the slot that receives the landmark (``< capacity``).
        R: measurement noise covariance.
        apply: when False nothing is written.
    """
    n = mean.shape[0]
    apply = jnp.asarray(apply)
    row = (3 + 2 * jnp.asarray(slot)).astype(jnp.int32)
    x = mean[:3]
    m = inverse_range_bearing(x, z)
    Gx, Gz = inverse_range_bearing_jacobians(x, z)
    cross = Gx @ cov[:3, :]  # (2, n)
    Pmm = sym(mmt(cross[:, :3], Gx) + sandwich(Gz, R))
    # Scatters with out-of-range indices when not applying: no write, and no read of the old
    # values (reading them back into a masked write would make XLA copy the whole matrix).
    idx = jnp.where(apply, row + jnp.arange(2, dtype=jnp.int32), n)
    cov = cov.at[idx, :].set(cross, mode="drop")
    cov = cov.at[:, idx].set(cross.T, mode="drop")
    cov = cov.at[idx[:, None], idx[None, :]].set(Pmm, mode="drop")
    mean = mean.at[idx].set(m, mode="drop")
    return mean, cov


class _Carry(NamedTuple):
    mean: Float[Array, "n"]
    cov: Float[Array, "n n"]
    available: Bool[Array, "capacity"]
    hits: Int[Array, "capacity"]
    count: Int[Array, ""]
    n_associated: Int[Array, ""]
    n_new: Int[Array, ""]
    overflow: Int[Array, ""]


def _batch_association(
    mean: Float[Array, "n"], cov: Float[Array, "n n"], z: Float[Array, "k 2"], z_mask: Bool[Array, "k"],
    active: Bool[Array, "capacity"], R: Float[Array, "2 2"], gate: Float[Array, ""], new_landmark: Float[Array, ""],
) -> tuple[Int[Array, "k"], Bool[Array, "k"], Bool[Array, "k"]]:
    """Non-sequential association with the existing landmarks (the closest claimant wins)."""
    k_max = z.shape[0]
    d2 = jax.vmap(association_distances, (None, None, 0, None, None))(mean, cov, z, R, active)
    j = jnp.argmin(d2, axis=1)
    best = jnp.min(d2, axis=1)
    matched = z_mask & (best < gate)
    claim = jnp.where(matched[:, None] & (j[:, None] == jnp.arange(d2.shape[1])), best[:, None], jnp.inf)
    winner = jnp.argmin(claim, axis=0)
    matched = matched & (winner[j] == jnp.arange(k_max))
    return j, matched, z_mask & (best > new_landmark)


def ekf_slam_step(
    static: Static, params: Params, state: EkfSlamState, seg: Segments, valid: Bool[Array, ""] = True,
) -> tuple[EkfSlamState, StepOutput]:
    """Advance EKF-SLAM through one segment: prediction, then the scan's detections in order.

    Args:
        static: static settings (``capacity``, ``sequential``).
        params: hyperparameters (noise, ``gate``, ``new_landmark``).
        state: the state at the previous segment.
        seg: one segment (a :class:`Segments` without the leading axis).
        valid: False for a padding segment (no detections, ``dt = 0``): the state is then
            returned unchanged.

    Returns:
        The new state and the segment's :class:`StepOutput` (``best_pose = mean_pose`` = the
        pose mean, ``ess = 1``).
    """
    capacity = static.capacity
    R = params.R
    valid = jnp.asarray(valid)
    # A padding segment has no real DR piece (dr_mask False): the prediction is then exact identity.
    mean, cov = ekf_slam_predict(state.mean, state.cov, seg.dt, seg.u, seg.dr_mask & valid, params)

    z_mask = seg.z_mask & valid
    k_max = z_mask.shape[0]
    n_real = jnp.sum(z_mask).astype(jnp.int32)
    (order,) = jnp.nonzero(z_mask, size=k_max, fill_value=0)
    slots = jnp.arange(capacity)
    if not static.sequential:
        pre_slot, pre_matched, pre_new = _batch_association(
            mean, cov, seg.z, z_mask, state.active, R, params.gate, params.new_landmark)

    def body(i, c: _Carry) -> _Carry:
        k = order[i]
        zk = seg.z[k]
        if static.sequential:
            d2 = association_distances(c.mean, c.cov, zk, R, c.available)
            j = jnp.argmin(d2).astype(jnp.int32)
            best = jnp.min(d2)
            matched = best < params.gate
            new = best > params.new_landmark
        else:
            j, matched, new = pre_slot[k].astype(jnp.int32), pre_matched[k], pre_new[k]
        room = c.count < capacity
        add = new & room
        # No conditionals around the big buffers (they would copy P): masked operations whose
        # covariance work is skipped (update: zero tiles; augment: dropped scatters).
        mean, cov = ekf_slam_update(c.mean, c.cov, zk, j, R, size=3 + 2 * c.count, apply=matched)
        s = jnp.minimum(c.count, capacity - 1)
        mean, cov = ekf_slam_augment(mean, cov, zk, s, R, apply=add)
        claimed = matched & (slots == j)
        created = add & (slots == c.count)
        # Sequential: a landmark is claimed once per scan; a new one can be matched next.
        available = (c.available & ~claimed) | created if static.sequential else c.available
        return _Carry(
            mean=mean, cov=cov, available=available,
            hits=c.hits + claimed.astype(jnp.int32) + created.astype(jnp.int32),
            count=c.count + add.astype(jnp.int32),
            n_associated=c.n_associated + matched.astype(jnp.int32),
            n_new=c.n_new + add.astype(jnp.int32),
            overflow=c.overflow + (new & ~room).astype(jnp.int32),
        )

    zero = jnp.zeros((), jnp.int32)
    c = jax.lax.fori_loop(0, n_real, body, _Carry(mean, cov, state.active, state.hits, state.count, zero, zero, zero))
    active = slots < c.count
    x = c.mean[:3]
    diag = jnp.diagonal(c.cov)
    finite = jnp.all(jnp.isfinite(c.mean)) & jnp.all(jnp.isfinite(diag))
    new_state = EkfSlamState(
        mean=c.mean, cov=c.cov, active=active, hits=c.hits, count=c.count, key=state.key,
        resample_count=state.resample_count, overflow=state.overflow + c.overflow,
    )
    record = StepOutput(
        best_pose=x, mean_pose=x, ess=jnp.ones((), dtype=x.dtype), resampled=jnp.zeros((), bool),
        n_landmarks=c.count.astype(jnp.int32), iterations=jnp.zeros((), dtype=x.dtype),
        n_capped=zero, n_nonfinite=(~finite).astype(jnp.int32),
        n_associated=c.n_associated.astype(x.dtype), n_new=c.n_new.astype(x.dtype),
        window_overflow=zero, overflow=c.overflow, weight_reset=jnp.zeros((), bool),
    )
    return new_state, record
