"""EKF-SLAM: one joint Gaussian over the pose and all landmarks (docs/method/ekf-slam.md).

The state is a fixed-capacity joint Gaussian ``N(mean, cov)`` over
``(px, py, phi, m_0, ..., m_{C-1})``, ``n = 3 + l C`` with ``l`` the measurement model's
``landmark_dim`` (2 for points), with an ``active`` mask (the operations on it are in
:mod:`._joint_gaussian`). An inactive slot has mean 0, an identity diagonal block and zero
cross-covariance with everything: it affects nothing, so the results do not depend on the
capacity. ``count`` is one past the highest active slot: every landmark lies below it, and the
covariance update touches only the leading ``3 + l count`` rows and columns.

Per segment (:func:`ekf_slam_step`):

1. **Prediction** (:func:`~._joint_gaussian.ekf_slam_predict`): the pose is propagated through
   the segment's DR pieces by first-order linearisation with autodiff Jacobians, touching only
   the three pose rows and columns: O(C), not O(C^2). EKF-SLAM always uses this linearised prior
   (``static.prior``'s transform is not used): mixing an unscented ``P_xx`` with Jacobian cross-covariances
   would not be a joint linearisation and need not stay positive semi-definite.
2. **Sequential detections** (a loop over the scan's real detections, in order): the innovation
   covariance of every slot, ``S_j = H_j P H_j' + R`` (pose-landmark cross-covariance included),
   is assembled from gathered blocks (O(C)); the nearest available landmark by Mahalanobis
   distance (plus the diameter term with ``map.use_diameter``) is matched if ``d2 < gate`` and
   gets an EKF update of the whole joint state; a detection whose best ``d2 > new_landmark``
   augments the state in the lowest free slot; detections in between are dropped. With
   ``static.sequential`` a landmark is claimed at most once per scan and one created by detection
   k can be matched by a later detection; without it, all detections are associated with the
   landmarks existing after the prediction (the closest claimant keeps a contested landmark) and
   then applied in order.
3. **Landmark management** (``static.manage``, the ``map`` config section; see
   :mod:`._management`): every landmark in the joint state takes part in association and
   updates (the joint Gaussian has no proposal or weights, so ``map.use_tentative`` does not
   apply); each keeps existence log-odds (hits, and misses at the updated pose mean, occlusion
   included), is confirmed by the same rule as in the particle filters, and is removed, i.e.
   marginalised out of the joint Gaussian, when its existence falls below the removal threshold
   or it stays tentative too long. Without management every new landmark is confirmed and
   permanent.
4. The covariance update is the symmetric rank-d form ``P <- P - V'V`` (exactly symmetric, no
   n x n product) over the tiles of the leading part that can hold landmarks. Positive
   semi-definiteness is not enforced beyond that: ``S`` is symmetrised and its Cholesky factor
   has floored pivots, and a non-finite state is reported (``n_nonfinite``), never hidden.
5. No ``cond``/``switch`` around the big buffers (XLA would copy ``P``): an unmatched
   detection's update runs over zero tiles, an augmentation or removal that does not happen
   scatters to out-of-range indices (dropped), and the pose rows are written in place.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from nanoslam_jax.data import Segments
from nanoslam_jax.methods.gaussian._joint_gaussian import (
    association_distances,
    ekf_slam_augment,
    ekf_slam_marginalise,
    ekf_slam_predict,
    ekf_slam_update,
    landmark_blocks,
    landmark_means,
)
from nanoslam_jax.methods.maps._landmarks import first_true, gather_window, scatter_window
from nanoslam_jax.models import is_composite
from nanoslam_jax.methods.maps._association import ScanDetections
from nanoslam_jax.methods.maps._management import Management, diameter_update, drop_stale, manage_window
from nanoslam_jax.methods._params import Params, Static
from nanoslam_jax.methods._state import LandmarkMap
from nanoslam_jax.methods.gaussian._gaussian import GaussianStepOutput


class EkfSlamState(NamedTuple):
    """The EKF-SLAM state carried from one segment to the next (a
    :class:`~._gaussian.GaussianState`).

    Attributes:
        mean: joint mean ``(px, py, phi, m_0, ..., m_{C-1})``, ``n = 3 + l C``.
        cov: joint covariance (exactly symmetric).
        landmarks: the per-landmark bookkeeping (``active``, ``hits``, ``misses``, ``log_odds``,
            ``confirmed``, ``born``, ``diam``, ``diam_var``) as a :class:`LandmarkMap` whose
            ``mean`` and ``cov`` are not used (they live in the joint Gaussian).
        count: one past the highest active slot (every landmark lies below it).
        overflow: new landmarks dropped so far because the state was full.
        scan: laser scans processed so far (the clock of ``born``).
    """

    mean: Float[Array, " n"]
    cov: Float[Array, "n n"]
    landmarks: LandmarkMap
    count: Int[Array, ""]  # type: ignore[assignment]  # the field shadows tuple.count
    overflow: Int[Array, ""]
    scan: Int[Array, ""]

    @property
    def pose(self) -> Float[Array, "3"]:
        """The pose mean (the joint mean's first three entries)."""
        return self.mean[:3]

    @property
    def pose_cov(self) -> Float[Array, "3 3"]:
        """The pose's marginal covariance (the joint covariance's leading block)."""
        return self.cov[:3, :3]

    def landmark_map(self) -> LandmarkMap:
        """The landmark marginals (means and diagonal blocks of the joint Gaussian) with the bookkeeping."""
        capacity = self.landmarks.active.shape[0]
        dim = (self.mean.shape[0] - 3) // capacity
        return self.landmarks._replace(
            mean=landmark_means(self.mean, dim), cov=landmark_blocks(self.cov, capacity, dim)
        )


def init_ekf_state(static: Static, params: Params) -> EkfSlamState:
    """The pose at the origin with covariance ``init_cov * I``, no landmarks.

    Args:
        static: static settings (``capacity``).
        params: hyperparameters (``init_cov``).
    """
    c = static.capacity
    dim = params.measurement.landmark_dim
    n = 3 + dim * c
    diag = jnp.concatenate([jnp.full((3,), params.init_cov, dtype=float), jnp.ones(dim * c)])
    zero = jnp.zeros((), jnp.int32)
    # The bookkeeping of an empty map; its mean and covariance are placeholders of one element.
    book = LandmarkMap.empty(
        c, ident=static.association.known, dim=dim, kinds=is_composite(params.measurement)
    )._replace(mean=jnp.zeros((1, dim)), cov=jnp.zeros((1, dim, dim)))
    return EkfSlamState(
        mean=jnp.zeros(n),
        cov=jnp.diag(diag),
        landmarks=book,
        count=zero,
        overflow=zero,
        scan=zero,
    )


class _Carry(NamedTuple):
    """The state of the loop over a scan's detections."""

    mean: Float[Array, " n"]
    cov: Float[Array, "n n"]
    available: Bool[Array, " capacity"]
    book: LandmarkMap
    seen: Bool[Array, " capacity"]
    count: Int[Array, ""]  # type: ignore[assignment]  # the field shadows tuple.count
    n_associated: Int[Array, ""]
    n_new: Int[Array, ""]
    overflow: Int[Array, ""]


class _Detections(NamedTuple):
    """A scan's detections as the loop takes them.

    Attributes:
        z_mask: the real detections (of a known landmark id with known association).
        order: their indices, first ``n_real`` entries (the rest 0).
        n_real: how many there are.
        pre: the non-sequential association with the landmarks after the prediction (slot,
            matched, new per detection; :func:`_batch_association`), None otherwise.
    """

    z_mask: Bool[Array, " k"]
    order: Int[Array, " k"]
    n_real: Int[Array, ""]
    pre: tuple[Int[Array, " k"], Bool[Array, " k"], Bool[Array, " k"]] | None


def _diameter_terms(book: LandmarkMap, d: Float[Array, ""], params: Params) -> Float[Array, " capacity"]:
    """The association's diameter term of a detection of diameter ``d`` against every slot (0 when
    ``map.use_diameter`` is off)."""
    mp = params.map
    term = jnp.square(d - book.diam) / (book.diam_var + jnp.square(mp.sigma_diameter))
    return jnp.where(mp.use_diameter, term, 0.0)


def _batch_association(
    mean: Float[Array, " n"],
    cov: Float[Array, "n n"],
    seg: Segments,
    z_mask: Bool[Array, " k"],
    book: LandmarkMap,
    params: Params,
) -> tuple[Int[Array, " k"], Bool[Array, " k"], Bool[Array, " k"]]:
    """Non-sequential association with the existing landmarks (the closest claimant wins)."""
    k_max = z_mask.shape[0]
    terms = jax.vmap(_diameter_terms, (None, 0, None))(book, seg.diam, params)
    composite = is_composite(params.measurement)
    d2 = jax.vmap(association_distances, (None, None, 0, None, None, 0, None, (None, 0) if composite else None))(
        mean,
        cov,
        seg.z,
        params.R,
        book.active,
        terms,
        params.measurement,
        (book.kind, seg.z_kind) if composite else None,
    )
    j = jnp.argmin(d2, axis=1)
    best = jnp.min(d2, axis=1)
    matched = z_mask & (best < params.gate)
    claim = jnp.where(matched[:, None] & (j[:, None] == jnp.arange(d2.shape[1])), best[:, None], jnp.inf)
    winner = jnp.argmin(claim, axis=0)
    matched = matched & (winner[j] == jnp.arange(k_max))
    return j, matched, z_mask & (best > params.new_landmark)


def _high_water(active: Bool[Array, " capacity"]) -> Int[Array, ""]:
    """One past the highest active slot (0 for an empty map)."""
    return jnp.max(jnp.where(active, jnp.arange(1, active.shape[0] + 1, dtype=jnp.int32), 0), initial=0)


def _remove(mean, cov, book: LandmarkMap, remove: Bool[Array, " capacity"]):
    """Marginalise every landmark in ``remove`` out of the joint Gaussian (a loop over them only)."""
    capacity = remove.shape[0]
    dim = (mean.shape[0] - 3) // capacity
    n_remove = jnp.sum(remove).astype(jnp.int32)
    slots, _ = first_true(remove, capacity)

    def body(i, mc):
        m, c = mc
        return ekf_slam_marginalise(m, c, slots[i], dim=dim)

    mean, cov = jax.lax.fori_loop(0, n_remove, body, (mean, cov))
    return mean, cov, book._replace(active=book.active & ~remove)


def _detections(
    static: Static, params: Params, mean: Float[Array, " n"], cov: Float[Array, "n n"], seg: Segments, valid, book
) -> _Detections:
    """The scan's real detections in order, with their non-sequential association when the step
    associates them all at once (``static.sequential`` off, association not ``known``).

    Args:
        static, params: the step's settings.
        mean, cov: the joint Gaussian after the prediction.
        seg: the segment; ``valid``: False for padding (no detection is real).
        book: the landmark bookkeeping after the prediction.
    """
    z_mask = seg.z_mask & valid
    k_max = z_mask.shape[0]
    n_real = jnp.sum(z_mask).astype(jnp.int32)
    (order,) = jnp.nonzero(z_mask, size=k_max, fill_value=0)
    pre = None
    if static.association.known:  # a detection without a landmark id is not associated
        z_mask = z_mask & (seg.z_id >= 0)
        n_real = jnp.sum(z_mask).astype(jnp.int32)
        (order,) = jnp.nonzero(z_mask, size=k_max, fill_value=0)
    elif not static.sequential:
        pre = _batch_association(mean, cov, seg, z_mask, book, params)
    return _Detections(z_mask, order, n_real, pre)


def _associate(
    static: Static, params: Params, c: _Carry, seg: Segments, k: Int[Array, ""], kind, pre
) -> tuple[Int[Array, ""], Bool[Array, ""], Bool[Array, ""]]:
    """Detection ``k``'s landmark slot, whether it is matched to it and whether it starts a new
    landmark: by its landmark id (association ``known``), the nearest available landmark in the
    current state (``static.sequential``), or the scan's association ``pre``.

    Args:
        static, params: the step's settings.
        c: the loop's state before this detection.
        seg: the segment; ``k``: the detection's index; ``kind``: its type (composite models, else None).
        pre: the non-sequential association (:attr:`_Detections.pre`).
    """
    if static.association.known:  # the landmark started by this id, or a new one
        same = c.book.active & (c.book.ident == seg.z_id[k])
        j = jnp.argmax(same).astype(jnp.int32)
        matched = jnp.any(same)
        return j, matched, ~matched
    if static.sequential:
        d2 = association_distances(
            c.mean,
            c.cov,
            seg.z[k],
            params.R,
            c.available,
            _diameter_terms(c.book, seg.diam[k], params),
            params.measurement,
            (c.book.kind, kind),
        )
        j = jnp.argmin(d2).astype(jnp.int32)
        best = jnp.min(d2)
        return j, best < params.gate, best > params.new_landmark
    pre_slot, pre_matched, pre_new = pre
    return pre_slot[k].astype(jnp.int32), pre_matched[k], pre_new[k]


class _Change(NamedTuple):
    """What one detection changes: landmark ``slot`` is updated where ``matched``; a new landmark
    fills slot ``free`` where ``add``."""

    slot: Int[Array, ""]
    matched: Bool[Array, ""]
    free: Int[Array, ""]
    add: Bool[Array, ""]


def _book_detection(
    static: Static, params: Params, b: LandmarkMap, scan, seg: Segments, k, kind, change: _Change
) -> LandmarkMap:
    """The bookkeeping ``b`` after detection ``k`` of type ``kind`` (None: no types) makes
    ``change`` (a new landmark is born at ``scan``); the scatters of a change that does not happen
    go to slot ``capacity`` and are dropped."""
    j, matched, free, add = change
    mp = params.map
    capacity = static.capacity
    dk = seg.diam[k]
    jc = jnp.where(matched, j, capacity)
    fc = jnp.where(add, free, capacity)
    d_new, dv_new = diameter_update(b.diam[j], b.diam_var[j], dk, mp.sigma_diameter)
    var_d = jnp.square(mp.sigma_diameter)
    return b._replace(
        active=b.active.at[fc].set(True, mode="drop"),
        hits=b.hits.at[jc].add(1, mode="drop").at[fc].set(1, mode="drop"),
        misses=b.misses.at[fc].set(0, mode="drop"),
        log_odds=b.log_odds.at[fc].set(mp.log_odds_birth, mode="drop"),
        confirmed=b.confirmed.at[fc].set(not static.manage, mode="drop"),
        born=b.born.at[fc].set(scan, mode="drop"),
        diam=b.diam.at[jc].set(d_new, mode="drop").at[fc].set(dk, mode="drop"),
        diam_var=b.diam_var.at[jc].set(dv_new, mode="drop").at[fc].set(var_d, mode="drop"),
        ident=None if b.ident is None else b.ident.at[fc].set(seg.z_id[k], mode="drop"),
        kind=None if b.kind is None else b.kind.at[fc].set(kind, mode="drop"),
    )


def _detection_step(
    static: Static, params: Params, scan: Int[Array, ""], seg: Segments, dets: _Detections, i, c: _Carry
) -> _Carry:
    """The ``i``-th real detection of the scan (the body of the loop over them): association, the
    EKF update of a matched landmark, the augmentation with a new one, the bookkeeping.

    Args:
        static, params: the step's settings.
        scan: the scan counter before the segment (a new landmark's ``born``).
        seg: the segment; ``dets``: its detections in order.
        i: the detection's rank among the real ones.
        c: the loop's state before it.

    Returns:
        The loop's state after it.
    """
    capacity = static.capacity
    model = params.measurement
    dim = model.landmark_dim
    composite = is_composite(model)
    assert seg.z_kind is not None or not composite, "a composite model's segments have z_kind"
    slots = jnp.arange(capacity)
    k = dets.order[i]
    zk = seg.z[k]
    # A composite's detection is updated and starts a landmark by its type's model and noise.
    kk = seg.z_kind[k] if seg.z_kind is not None and composite else None
    model_k = model.of_kind(kk) if composite else model  # type: ignore[attr-defined]  # a Composite
    R_k = model_k.noise_cov() if composite else params.R
    j, matched, new = _associate(static, params, c, seg, k, kk, dets.pre)
    free = jnp.argmin(c.book.active).astype(jnp.int32)  # the lowest free slot
    room = ~c.book.active[free]
    add = new & room
    # No conditionals around the big buffers (they would copy P): masked operations whose
    # covariance work is skipped (update: zero tiles; augment: dropped scatters).
    mean, cov = ekf_slam_update(c.mean, c.cov, zk, j, R_k, size=3 + dim * c.count, apply=matched, model=model_k)
    mean, cov = ekf_slam_augment(mean, cov, zk, free, R_k, apply=add, model=model_k)
    book = _book_detection(static, params, c.book, scan, seg, k, kk, _Change(j, matched, free, add))
    claimed = matched & (slots == j)
    created = add & (slots == free)
    # Sequential: a landmark is claimed once per scan; a new one can be matched next.
    available = (c.available & ~claimed) | created if static.sequential else c.available
    return _Carry(
        mean=mean,
        cov=cov,
        available=available,
        book=book,
        seen=(c.seen | claimed) & ~created,
        count=jnp.maximum(c.count, jnp.where(add, free + 1, 0)),
        n_associated=c.n_associated + matched.astype(jnp.int32),
        n_new=c.n_new + add.astype(jnp.int32),
        overflow=c.overflow + (new & ~room).astype(jnp.int32),
    )


def _manage(static: Static, params: Params, state: EkfSlamState, seg: Segments, valid, z_mask, c: _Carry) -> _Carry:
    """Landmark management after the scan's detections (``static.manage``; the loop's state
    unchanged without it): existence of the landmarks near the updated pose mean (gathered as the
    particle filters' local window; those created in this scan are not tested), removal of those
    that fail it (marginalised out), and the new high-water mark.

    Args:
        static, params: the step's settings.
        state: the state before the segment (its landmarks: those before this scan).
        seg: the segment; ``valid``: False for padding; ``z_mask``: its real detections.
        c: the loop's state after the detections.

    Returns:
        ``c`` with the managed joint Gaussian, bookkeeping and ``count``.
    """
    if not static.manage:
        return c
    capacity = static.capacity
    mp = params.map
    dim = params.measurement.landmark_dim
    mean, cov, book = c.mean, c.cov, c.book
    old = state.landmarks.active
    full = book._replace(mean=landmark_means(mean, dim), cov=landmark_blocks(cov, capacity, dim), active=old)
    radius = params.max_range + params.window_margin
    local, idx, _ = gather_window(full, mean[:2], min(static.window, capacity), radius, model=params.measurement)
    local = manage_window(
        local,
        mean[:3],
        c.seen.at[idx].get(mode="fill", fill_value=False),
        ScanDetections(seg.z, z_mask, seg.diam),
        valid & seg.is_scan,
        state.scan,
        params.measurement,
        Management(mp, static.occlusion),
    )
    managed = drop_stale(scatter_window(full, local, idx), state.scan, mp)
    remove = old & ~managed.active
    created = book.active & ~old
    book = managed._replace(active=old | created, mean=book.mean, cov=book.cov)
    mean, cov, book = _remove(mean, cov, book, remove)
    return c._replace(mean=mean, cov=cov, book=book, count=_high_water(book.active))


def _output(state: EkfSlamState, seg: Segments, valid, c: _Carry) -> tuple[EkfSlamState, GaussianStepOutput]:
    """The new state and the segment's record from the loop's state ``c`` after management
    (``state``: the state before the segment; ``valid``: False for padding)."""
    book = c.book
    diag = jnp.diagonal(c.cov)
    finite = jnp.all(jnp.isfinite(c.mean)) & jnp.all(jnp.isfinite(diag))
    new_state = EkfSlamState(
        mean=c.mean,
        cov=c.cov,
        landmarks=book,
        count=c.count,
        overflow=state.overflow + c.overflow,
        scan=state.scan + (valid & seg.is_scan).astype(jnp.int32),
    )
    record = GaussianStepOutput(
        pose=new_state.pose,
        pose_cov=new_state.pose_cov,
        n_landmarks=jnp.sum(book.active).astype(jnp.int32),
        n_confirmed=jnp.sum(book.active & book.confirmed).astype(jnp.int32),
        n_associated=c.n_associated,
        n_new=c.n_new,
        overflow=c.overflow,
        n_nonfinite=(~finite).astype(jnp.int32),
    )
    return new_state, record


def ekf_slam_step(
    static: Static,
    params: Params,
    state: EkfSlamState,
    seg: Segments,
    valid: Bool[Array, ""] | bool = True,
) -> tuple[EkfSlamState, GaussianStepOutput]:
    """Advance EKF-SLAM through one segment: prediction, the scan's detections in order, then
    landmark management.

    Args:
        static: static settings (``capacity``, ``sequential``, ``manage``, ``occlusion``).
        params: hyperparameters (noise, ``gate``, ``new_landmark``, ``map``).
        state: the state at the previous segment.
        seg: one segment (a :class:`Segments` without the leading axis).
        valid: False for a padding segment (no detections, ``dt = 0``): the state is then
            returned unchanged.

    Returns:
        The new state and the segment's :class:`~._gaussian.GaussianStepOutput` (the pose mean
        and its covariance).
    """
    valid = jnp.asarray(valid)
    # A padding segment has no real DR piece (dr_mask False): the prediction is then exact identity.
    mean, cov = ekf_slam_predict(state.mean, state.cov, seg.dt, seg.u, seg.dr_mask & valid, params)
    dets = _detections(static, params, mean, cov, seg, valid, state.landmarks)
    zero = jnp.zeros((), jnp.int32)
    book0 = state.landmarks
    init = _Carry(mean, cov, book0.active, book0, jnp.zeros(static.capacity, bool), state.count, zero, zero, zero)
    body = functools.partial(_detection_step, static, params, state.scan, seg, dets)
    c = jax.lax.fori_loop(0, dets.n_real, body, init)
    return _output(state, seg, valid, _manage(static, params, state, seg, valid, dets.z_mask, c))
