"""Operations on EKF-SLAM's joint Gaussian over the pose and a fixed-capacity landmark vector.

The state is ``N(mean, cov)`` over ``(px, py, phi, m_0, ..., m_{C-1})``, ``n = 3 + l C`` with
``l`` the measurement model's ``landmark_dim`` (a point's ``(x, y)``: 2). An inactive slot has
mean 0, an identity ``l x l`` diagonal block and zero
cross-covariance with everything: it enters no innovation covariance and no gain, so it affects
nothing. Prediction (:func:`ekf_slam_predict`), innovations against every slot
(:func:`slot_innovations`), the joint update (:func:`ekf_slam_update`, a rank-2 downdate over the
leading part of the matrix that can hold landmarks, :func:`rank2_downdate`), augmentation with a
new landmark (:func:`ekf_slam_augment`) and removal of one (:func:`ekf_slam_marginalise`); see
:mod:`._ekf_slam` for how the step uses them. Jacobians come from autodiff of the models.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from nanoslam_jax.lib._linalg import chol_small, inv_small, mm, mmt, mt, quad_form, sandwich, sym
from nanoslam_jax.models import AbstractMeasurementModel, RangeBearing, row_models, row_noise, wrap_angle
from nanoslam_jax.methods._params import Params


def _model(model: AbstractMeasurementModel | None) -> AbstractMeasurementModel:
    """``model``, or the range-bearing model where none is given."""
    return RangeBearing() if model is None else model


def landmark_means(mean: Float[Array, " n"], dim: int = 2) -> Float[Array, "capacity l"]:
    """The landmark part of the joint mean as ``(capacity, dim)`` landmarks (``dim``: the
    measurement model's ``landmark_dim``)."""
    return mean[3:].reshape(-1, dim)


def landmark_blocks(cov: Float[Array, "n n"], capacity: int, dim: int = 2) -> Float[Array, "capacity l l"]:
    """The ``dim x dim`` diagonal blocks (landmark marginal covariances) of the joint covariance.

    Args:
        cov: joint covariance.
        capacity: number of landmark slots.
        dim: values per landmark (the measurement model's ``landmark_dim``).
    """
    i = 3 + dim * jnp.arange(capacity)
    if dim == 2:
        a, b, c = cov[i, i], cov[i, i + 1], cov[i + 1, i + 1]
        return jnp.stack([jnp.stack([a, b], -1), jnp.stack([b, c], -1)], -2)
    r = i[:, None] + jnp.arange(dim)
    return cov[r[:, :, None], r[:, None, :]]


def ekf_slam_predict(
    mean: Float[Array, " n"],
    cov: Float[Array, "n n"],
    dt: Float[Array, " dr"],
    u: Float[Array, "dr c"],
    dr_mask: Bool[Array, " dr"],
    params: Params,
) -> tuple[Float[Array, " n"], Float[Array, "n n"]]:
    """Linearised joint prediction through a segment's DR pieces; only the pose rows change.

    Args:
        mean, cov: joint Gaussian at the start of the segment.
        dt: piece durations (padding: 0).
        u: piece controls (the motion model's ``control_dim`` values).
        dr_mask: which pieces are real (masked pieces change nothing).
        params: the motion model (``params.motion``) with its process noise.

    Returns:
        The joint mean and covariance at the scan time: pose mean ``f(x, u)``,
        ``P_xx = F_i P_xx F_i' + G_i Q G_i'`` composed over the pieces, ``P_xm = F P_xm`` with
        ``F`` the product of the pieces' pose Jacobians, ``P_mm`` unchanged.
    """
    motion = params.motion

    def body(carry, inp):
        x, Pxx, F = carry
        dti, ui, mi = inp
        Fi, Gi = motion.jacobians(x, ui, dti)
        xn = motion.step(x, ui, dti)
        Pn = sym(sandwich(Fi, Pxx) + sandwich(Gi, motion.noise_cov(dti)))
        Fn = mm(Fi, F)
        return (jnp.where(mi, xn, x), jnp.where(mi, Pn, Pxx), jnp.where(mi, Fn, F)), None

    x0, Pxx0 = mean[:3], cov[:3, :3]
    (x, Pxx, F), _ = jax.lax.scan(body, (x0, Pxx0, jnp.eye(3, dtype=mean.dtype)), (dt, u, dr_mask))
    # Without a real piece F = I exactly, so the rows are rewritten with their own values (no
    # masked select here: a select against the old rows would make XLA copy the matrix).
    rows = jnp.concatenate([Pxx, F @ cov[:3, 3:]], axis=1)
    cov = cov.at[:3, :].set(rows).at[:, :3].set(rows.T)
    return mean.at[:3].set(x), cov


def _dummy_landmark(x: Float[Array, "3"], dim: int) -> Float[Array, " l"]:
    """A finite landmark to evaluate unused slots at: 1 m ahead of the pose in x, further values 1."""
    dummy = x[:2] + jnp.array([1.0, 0.0])
    return dummy if dim == 2 else jnp.concatenate([dummy, jnp.ones(dim - 2, dummy.dtype)])


def slot_innovations(
    mean: Float[Array, " n"],
    cov: Float[Array, "n n"],
    z: Float[Array, " d"],
    R: Float[Array, "d d"],
    usable: Bool[Array, " capacity"],
    model: AbstractMeasurementModel | None = None,
    slot_kind: Int[Array, " capacity"] | None = None,
    z_kind: Int[Array, ""] | None = None,
) -> tuple[Float[Array, "capacity d"], Float[Array, "capacity d d"]]:
    """Innovation and innovation covariance of detection ``z`` against every landmark slot.

    ``S_j = H_j P H_j' + R`` with ``H_j = [Gx, 0.., Gm, 0..]`` (autodiff Jacobians at the
    current mean), assembled from the pose block, the pose-landmark cross block and the
    landmark block of slot ``j``: O(capacity). Slots not ``usable`` are evaluated at a dummy
    landmark (for a point 1 m from the pose; for another model its first two components there and
    the rest 1: finite values, which the caller masks).

    Args:
        mean, cov: joint Gaussian.
        z: the detection (``(r, beta)`` for range-bearing).
        R: measurement noise covariance.
        usable: slots to evaluate at their mean.
        model: the measurement model (default range-bearing).
        slot_kind, z_kind: each slot's and the detection's type, for a composite ``model`` (each
            slot predicted by its type's model with its noise; the innovation by the detection's).
    """
    model = _model(model)
    capacity = usable.shape[0]
    dim = model.landmark_dim
    x = mean[:3]
    lm = jnp.where(usable[:, None], landmark_means(mean, dim), _dummy_landmark(x, dim))
    rows, ax = row_models(model, slot_kind)
    z_hat = jax.vmap(lambda md, m: md.h(x, m), (ax, 0))(rows, lm)
    Gx, Gm = jax.vmap(lambda md, m: md.jacobians(x, m), (ax, 0))(rows, lm)
    R = row_noise(rows, ax, R)[0]
    Pxx = cov[:3, :3]
    Pxl = jnp.transpose(cov[:3, 3:].reshape(3, capacity, dim), (1, 0, 2))  # (C, 3, dim)
    Pll = landmark_blocks(cov, capacity, dim)
    C = mmt(mm(Gx, Pxl), Gm)
    S = sandwich(Gx, Pxx[None]) + C + mt(C) + sandwich(Gm, Pll) + R
    detection = model if ax is None else model.of_kind(z_kind)  # type: ignore[attr-defined]  # a Composite
    nu = jax.vmap(detection.innovation, (None, 0))(z, z_hat)
    return nu, S


def association_distances(
    mean: Float[Array, " n"],
    cov: Float[Array, "n n"],
    z: Float[Array, " d"],
    R: Float[Array, "d d"],
    available: Bool[Array, " capacity"],
    diam_term: Float[Array, " capacity"] | float = 0.0,
    model: AbstractMeasurementModel | None = None,
    kinds: tuple[Int[Array, " capacity"] | None, Int[Array, ""] | None] | None = None,
) -> Float[Array, " capacity"]:
    """Squared Mahalanobis distance of ``z`` to every available landmark (inf elsewhere), plus
    ``diam_term`` (the tree-diameter term of each slot, or 0); ``model``: the measurement model
    (default range-bearing); ``kinds``: ``(slot_kind, z_kind)``, the slots' and the detection's
    types for a composite model (a slot of another type is not available; None: no types)."""
    slot_kind, z_kind = (None, None) if kinds is None else kinds
    if slot_kind is not None and z_kind is not None:
        available = available & (slot_kind == z_kind)
    nu, S = slot_innovations(mean, cov, z, R, available, model, slot_kind, z_kind)
    return jnp.where(available, quad_form(nu, inv_small(S)) + diam_term, jnp.inf)


#: Side of the square blocks in which the covariance update touches only the active part of P.
BLOCK = 128


def low_rank_downdate(
    cov: Float[Array, "n n"],
    vs: tuple[Float[Array, " n"], ...],
    size: Int[Array, ""] | int | None = None,
    block: int = BLOCK,
) -> Float[Array, "n n"]:
    """``cov - sum_i v_i v_i'`` on the leading ``size x size`` part of ``cov``.

    The update is applied in ``block x block`` tiles by a loop over the tiles that meet the
    leading part (cost O(size^2), not O(n^2)); each element is ``P_ab - sum_i v_ia v_ib``,
    so a symmetric ``cov`` stays exactly symmetric. Entries outside the leading part are left
    as they are (the caller guarantees the ``v_i`` vanish there, so this is the full update).

    Args:
        cov: the matrix to update.
        vs: the update vectors (one per dimension of the detection).
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
        a = [jax.lax.dynamic_slice(v, (r0,), (B,)) for v in vs]
        b = [jax.lax.dynamic_slice(v, (c0,), (B,)) for v in vs]
        keep = ((r0 + idx) >= r_nom)[:, None] & ((c0 + idx) >= c_nom)[None, :]
        d = a[0][:, None] * b[0][None, :]
        for ai, bi_ in zip(a[1:], b[1:]):
            d = d + ai[:, None] * bi_[None, :]
        tile = jax.lax.dynamic_slice(P, (r0, c0), (B, B))
        return jax.lax.dynamic_update_slice(P, tile - jnp.where(keep, d, 0.0), (r0, c0))

    return jax.lax.fori_loop(0, nb * nb, body, cov)


def rank2_downdate(
    cov: Float[Array, "n n"],
    v0: Float[Array, " n"],
    v1: Float[Array, " n"],
    size: Int[Array, ""] | int | None = None,
    block: int = BLOCK,
) -> Float[Array, "n n"]:
    """``cov - (v0 v0' + v1 v1')`` on the leading ``size x size`` part of ``cov``
    (:func:`low_rank_downdate` of two vectors)."""
    return low_rank_downdate(cov, (v0, v1), size, block)


def _forward_substitution(L: Float[Array, "d d"]):
    """``b -> L^-1 b`` for lower-triangular ``L`` (``d x d``), with ``b`` given by its rows
    (``row(i)``, arrays of any shape). The entries of ``L`` are read once, row by row."""
    d = L.shape[0]
    entries = {(i, j): L[i, j] for i in range(d) for j in range(i + 1)}

    def solve(row) -> list:
        out: list = []
        for i in range(d):
            acc = row(i)
            for j in range(i):
                acc = acc - entries[i, j] * out[j]
            out.append(acc / entries[i, i])
        return out

    return solve


def ekf_slam_update(
    mean: Float[Array, " n"],
    cov: Float[Array, "n n"],
    z: Float[Array, " d"],
    slot: Int[Array, ""] | int,
    R: Float[Array, "d d"],
    size: Int[Array, ""] | int | None = None,
    apply: Bool[Array, ""] | bool = True,
    model: AbstractMeasurementModel | None = None,
) -> tuple[Float[Array, " n"], Float[Array, "n n"]]:
    """EKF update of the joint state with detection ``z`` of landmark ``slot``.

    ``W = H P`` (d x n) is formed from the pose rows and the landmark's ``l`` rows of ``P``;
    ``S = W H' + R = L L'``; ``V = L^-1 W``; then ``mean += V' L^-1 nu`` and ``P -= V'V``
    (the symmetric rank-d form of ``P - K S K'``, exactly symmetric, O(n^2); see
    :func:`low_rank_downdate`).

    Args:
        mean, cov: joint Gaussian.
        z: the detection (``(r, beta)`` for range-bearing; angular residuals wrapped).
        slot: the landmark slot it is associated with.
        R: measurement noise covariance.
        size: leading rows/columns of ``P`` that can be non-zero in ``W`` (``3 + l count``
            with the active slots a prefix; default: all). Only that part of ``P`` is touched.
        apply: when False the state is returned unchanged (no covariance work is done).
        model: the measurement model (default range-bearing).

    Returns:
        The updated joint mean (heading wrapped) and covariance.
    """
    model = _model(model)
    n = mean.shape[0]
    dim, d = model.landmark_dim, z.shape[-1]
    apply = jnp.asarray(apply)
    row = (3 + dim * jnp.asarray(slot)).astype(jnp.int32)
    z0 = jnp.zeros((), jnp.int32)
    x = mean[:3]
    m = jax.lax.dynamic_slice(mean, (row,), (dim,))
    Gx, Gm = model.jacobians(x, m)
    nu = model.innovation(z, model.h(x, m))
    W = Gx @ cov[:3, :] + Gm @ jax.lax.dynamic_slice(cov, (row, z0), (dim, n))
    S = sym(mmt(W[:, :3], Gx) + mmt(jax.lax.dynamic_slice(W, (z0, row), (d, dim)), Gm) + R)
    L = chol_small(S)
    solve = _forward_substitution(L)
    v = solve(lambda i: W[i])
    w = solve(lambda i: nu[i])
    updated = mean
    for vi, wi in zip(v, w):
        updated = updated + vi * wi
    mean = jnp.where(apply, updated.at[2].set(wrap_angle(updated[2])), mean)
    size = n if size is None else size
    cov = low_rank_downdate(cov, tuple(v), jnp.where(apply, size, 0))
    return mean, cov


def ekf_slam_augment(
    mean: Float[Array, " n"],
    cov: Float[Array, "n n"],
    z: Float[Array, " d"],
    slot: Int[Array, ""] | int,
    R: Float[Array, "d d"],
    apply: Bool[Array, ""] | bool = True,
    model: AbstractMeasurementModel | None = None,
) -> tuple[Float[Array, " n"], Float[Array, "n n"]]:
    """Add a landmark from detection ``z`` in (free) slot ``slot``, with full cross-covariances.

    With ``m = h^-1(x, z)`` and its Jacobians ``Gx`` (pose) and ``Gz`` (detection) by autodiff:
    ``P_mm = Gx P_xx Gx' + Gz R Gz'`` and ``P_m,rest = Gx P_x,rest`` (the slot's old values are
    those of an inactive slot: zero cross-covariance, so ``P_m,rest`` is zero there too).
    O(n): ``l`` rows, ``l`` columns and an ``l x l`` block are written.

    Args:
        mean, cov: joint Gaussian; ``slot`` must be inactive.
        z: the detection.
        slot: the slot that receives the landmark (``< capacity``).
        R: measurement noise covariance.
        apply: when False nothing is written.
        model: the measurement model (default range-bearing): ``h^-1`` is its ``landmark_from``.
    """
    model = _model(model)
    n = mean.shape[0]
    dim = model.landmark_dim
    apply = jnp.asarray(apply)
    row = (3 + dim * jnp.asarray(slot)).astype(jnp.int32)
    x = mean[:3]
    m = model.landmark_from(x, z)
    Gx, Gz = model.inverse_jacobians(x, z)
    cross = Gx @ cov[:3, :]  # (l, n)
    Pmm = sym(mmt(cross[:, :3], Gx) + sandwich(Gz, R))
    # Scatters with out-of-range indices when not applying: no write, and no read of the old
    # values (reading them back into a masked write would make XLA copy the whole matrix).
    idx = jnp.where(apply, row + jnp.arange(dim, dtype=jnp.int32), n)
    cov = cov.at[idx, :].set(cross, mode="drop")
    cov = cov.at[:, idx].set(cross.T, mode="drop")
    cov = cov.at[idx[:, None], idx[None, :]].set(Pmm, mode="drop")
    mean = mean.at[idx].set(m, mode="drop")
    return mean, cov


def ekf_slam_marginalise(
    mean: Float[Array, " n"],
    cov: Float[Array, "n n"],
    slot: Int[Array, ""] | int,
    apply: Bool[Array, ""] | bool = True,
    dim: int = 2,
) -> tuple[Float[Array, " n"], Float[Array, "n n"]]:
    """Remove landmark ``slot`` from the joint Gaussian (marginalise it out) and free its slot.

    The marginal of a Gaussian over the other variables is the same Gaussian with the landmark's
    rows and columns deleted; here they are reset to those of an inactive slot (mean 0, identity
    block, zero cross-covariance), which affects nothing. O(n): ``dim`` rows and columns.

    Args:
        mean, cov: joint Gaussian.
        slot: the landmark slot to free.
        apply: when False nothing is written.
        dim: values per landmark (the measurement model's ``landmark_dim``).
    """
    n = mean.shape[0]
    row = (3 + dim * jnp.asarray(slot)).astype(jnp.int32)
    idx = jnp.where(jnp.asarray(apply), row + jnp.arange(dim, dtype=jnp.int32), n)
    cov = cov.at[idx, :].set(0.0, mode="drop").at[:, idx].set(0.0, mode="drop")
    cov = cov.at[idx[:, None], idx[None, :]].set(jnp.eye(dim, dtype=cov.dtype), mode="drop")
    return mean.at[idx].set(0.0, mode="drop"), cov
