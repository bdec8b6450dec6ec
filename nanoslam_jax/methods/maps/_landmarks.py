"""Landmark map operations: the local window, EKF update, initialisation (eq. 16), write-back,
and their unscented counterparts (UFastSLAM).

A scan touches only landmarks near the particle. :func:`gather_window` copies the (at most
``window``) active landmarks within the sensor range plus a margin into a small local map, so
all per-detection work is over ``window`` slots (and one provisional landmark per detection)
instead of the full capacity. :func:`update_slots` writes back only the landmarks the scan's
detections updated, :func:`add_landmarks` places the new ones in free slots, and
:func:`scatter_window` writes a whole local map back (when landmark management changes every
local landmark's existence).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from nanoslam_jax.lib._batching import batch_max
from nanoslam_jax.lib._linalg import chol_small, gaussian_logpdf, inv_small, is_pd_small, mm, mmt, mt, mv, sandwich, sym
from nanoslam_jax.lib._trig import computed_once
from nanoslam_jax.models import AbstractMeasurementModel, Composite, OfKind, RangeBearing, wrap_angle
from nanoslam_jax.lib.quadrature import Unscented, sigma_point_cross_cov, sigma_point_stats
from nanoslam_jax.methods._state import SEARCH_BLOCK, SEARCH_FROM, BlockIndex, LandmarkMap


def _model(model: AbstractMeasurementModel | None) -> AbstractMeasurementModel:
    """``model``, or the range-bearing model where none is given."""
    return RangeBearing() if model is None else model


def prefix_count(mask: Bool[Array, " n"] | Int[Array, " n"], block: int = 32) -> Int[Array, " n"]:
    """Inclusive running count of ``mask`` (``cumsum``; of counts, their running sum), as two small
    matrix products.

    XLA:CPU lowers ``cumsum`` to a windowed reduction costing ~8x more than a blocked product with
    a triangular matrix of ones (exact: counts are far below float32's 2^24).
    """
    n = mask.shape[0]
    m = jnp.pad(mask, (0, -n % block)).astype(jnp.float32).reshape(-1, block)
    within = m @ jnp.triu(jnp.ones((block, block), jnp.float32))  # running count inside each block
    offsets = within[:, -1] @ jnp.triu(jnp.ones((m.shape[0],) * 2, jnp.float32), 1)  # counts of the blocks before
    return (within + offsets[:, None]).reshape(-1)[:n].astype(jnp.int32)


def first_true(mask: Bool[Array, " n"], size: int) -> tuple[Int[Array, " size"], Int[Array, ""]]:
    """Indices of the first ``size`` True entries of ``mask`` in order (``n`` where there are fewer)
    and the number of True entries: ``jnp.nonzero(mask, size=size, fill_value=n)`` at a third of
    its cost on CPU, O(n) unlike a top-k (a sort)."""
    n = mask.shape[0]
    rank = prefix_count(mask)
    target = jnp.where(mask, rank - 1, size)  # beyond ``size``: dropped
    idx = jnp.full(size, n, jnp.int32).at[target].set(jnp.arange(n, dtype=jnp.int32), mode="drop")
    return idx, rank[-1]


#: Blocks :func:`first_true_blocked` may gather (then every block holding a True, at most ``size``).
SEARCH_BUDGETS = (2, 8)


def first_true_blocked(mask: Bool[Array, " n"], size: int) -> tuple[Int[Array, " size"], Int[Array, ""]]:
    """:func:`first_true` of a long ``mask`` at a cost that follows the blocks holding its first
    ``size`` True entries, not ``n``: the entries are counted per block of :data:`SEARCH_BLOCK`,
    and only the first blocks that hold any of the first ``size`` are searched (the fewest of
    :data:`SEARCH_BUDGETS` blocks that hold them, a ``lax.switch`` on
    :func:`~nanoslam_jax.lib._batching.batch_max`, so under ``vmap`` one branch serves every member).
    The same indices and count as :func:`first_true`; ``n`` must be a multiple of the block."""
    n, b = mask.shape[0], SEARCH_BLOCK
    nb = n // b
    counts = jnp.sum(mask.reshape(nb, b), axis=1, dtype=jnp.int32)
    before = prefix_count(counts) - counts  # Trues in the blocks before each block
    # The first ``size`` Trues lie in the blocks that start with fewer than ``size`` before them.
    wanted = (counts > 0) & (before < size)
    need = jnp.sum(wanted)
    budgets = tuple(k for k in SEARCH_BUDGETS if k < min(size, nb)) + (min(size, nb),)
    branch = batch_max(jnp.sum(need > jnp.asarray(budgets[:-1], jnp.int32)).astype(jnp.int32))

    def search(k: int) -> Int[Array, " size"]:
        blocks, _ = first_true(wanted, k)  # ``nb`` past the last wanted block
        slots = (blocks[:, None] * b + jnp.arange(b, dtype=jnp.int32)).reshape(-1)
        hit = mask.at[slots].get(mode="fill", fill_value=False)
        idx, _ = first_true(hit, size)
        return jnp.where(idx < slots.shape[0], slots.at[idx].get(mode="fill", fill_value=n), n)

    total = jnp.sum(counts, dtype=jnp.int32)
    if len(budgets) == 1:
        return search(budgets[0]), total
    return jax.lax.switch(branch, [functools.partial(search, k) for k in budgets]), total


def gather_window(
    lm: LandmarkMap,
    position: Float[Array, "2"],
    window: int,
    radius: Float[Array, ""],
    slots: int | None = None,
    model: AbstractMeasurementModel | None = None,
    index: BlockIndex | None = None,
) -> tuple[LandmarkMap, Int[Array, " window"], Int[Array, ""]]:
    """The local map of one particle.

    Args:
        lm: the particle's map (capacity slots).
        position: where the particle is (its prior mean position).
        window: how many landmarks the local map holds.
        radius: landmarks within this distance of ``position`` are copied (the sensor range
            plus a margin for the pose uncertainty).
        slots: search only the first ``slots`` slots, which must hold every active landmark
            (the search costs in proportion to the slots; default: all).
        model: the measurement model, whose
            :meth:`~nanoslam_jax.models.AbstractMeasurementModel.window_distance2` measures the
            distance to a landmark (None: range-bearing, the Euclidean distance to a point).
        index: the map's spatial index (point landmarks only), whose boxes hold every active
            landmark: from :data:`SEARCH_FROM` slots only the blocks whose box comes within
            ``radius`` are searched (the fewest of :data:`INDEX_BUDGETS` blocks that hold them, a
            ``lax.switch`` on :func:`~nanoslam_jax.lib._batching.batch_max`, else every slot),
            with the same result. None: every slot.

    Returns:
        The local map (``window`` slots; unused ones inactive, zero mean, unit covariance), the
        global slot index of each local slot (``capacity`` for unused ones), and how many
        landmarks within ``radius`` did not fit the window (0 unless the window is too small for
        the local landmark density; the lowest slots, i.e. the oldest landmarks, are kept).
    """
    idx, n_near = window_slots(lm, position, window, radius, slots, model, index)
    return local_map(lm, idx), idx, jnp.maximum(n_near - window, 0)


#: Blocks the search through a spatial index may visit (then every slot is searched).
INDEX_BUDGETS = (2, 8, 32)


def _near_in_blocks(
    lm: LandmarkMap,
    near_block: Bool[Array, " nb"],
    k: int,
    position: Float[Array, "2"],
    window: int,
    radius2: Float[Array, ""],
    model: AbstractMeasurementModel,
) -> tuple[Int[Array, " window"], Int[Array, ""]]:
    """:func:`window_slots` from the first ``k`` near blocks (every near block, when there are at
    most ``k``)."""
    capacity, b, nb = lm.active.shape[0], SEARCH_BLOCK, near_block.shape[0]
    blocks, _ = first_true(near_block, k)  # ``nb`` past the near blocks
    slots = (blocks[:, None] * b + jnp.arange(b, dtype=jnp.int32)).reshape(-1)
    mean = lm.mean.at[slots].get(mode="fill", fill_value=0.0)
    active = lm.active.at[slots].get(mode="fill", fill_value=False) & (slots < nb * b)
    near = active & (model.window_distance2(position, mean) < radius2)
    j, n_near = first_true(near, window)
    idx = slots.at[j].get(mode="fill", fill_value=capacity)
    return jnp.where(idx < nb * b, idx, capacity), n_near


def window_slots(
    lm: LandmarkMap,
    position: Float[Array, "2"],
    window: int,
    radius: Float[Array, ""],
    slots: int | None = None,
    model: AbstractMeasurementModel | None = None,
    index: BlockIndex | None = None,
) -> tuple[Int[Array, " window"], Int[Array, ""]]:
    """The slots of :func:`gather_window`'s local map (``capacity`` for unused ones) and how many
    active landmarks lie within ``radius`` (of which the lowest ``window`` slots are kept)."""
    capacity = lm.active.shape[0]
    slots = capacity if slots is None else min(slots, capacity)
    model = _model(model)
    nb = slots // SEARCH_BLOCK
    budgets = tuple(k for k in INDEX_BUDGETS if k < nb)
    if index is not None and slots >= SEARCH_FROM and slots % SEARCH_BLOCK == 0 and budgets:
        radius2 = jnp.square(radius)
        near_block = index.near(position, radius2, nb)
        search = functools.partial(_near_in_blocks, lm, near_block)
        branches = [functools.partial(search, k, position, window, radius2, model) for k in budgets]
        whole = functools.partial(window_slots, lm, position, window, radius, slots, model)
        branch = batch_max(jnp.sum(jnp.sum(near_block) > jnp.asarray(budgets, jnp.int32)).astype(jnp.int32))
        return jax.lax.switch(branch, [*branches, whole])
    if isinstance(model, Composite):  # each landmark by its type's distance
        assert lm.kind is not None, "a composite model's map has the kind field"
        model = model.of_kind(lm.kind[:slots])
    d2 = model.window_distance2(position, lm.mean[:slots])
    near = lm.active[:slots] & (d2 < jnp.square(radius))
    long = slots >= SEARCH_FROM and slots % SEARCH_BLOCK == 0
    idx, n_near = first_true_blocked(near, window) if long else first_true(near, window)
    if slots < capacity:
        idx = jnp.where(idx < slots, idx, capacity)  # unused window slots point at ``capacity``
    return idx, n_near


def local_map(lm: LandmarkMap, idx: Int[Array, " window"]) -> LandmarkMap:
    """The local map of the slots ``idx`` of ``lm`` (``capacity``: an unused local slot, inactive,
    with zero mean and unit covariance)."""
    capacity = lm.active.shape[0]
    local = jax.tree.map(lambda a: a.at[idx].get(mode="fill", fill_value=0), lm)
    dim = lm.cov.shape[-1]
    return local._replace(
        active=idx < capacity, cov=jnp.where((idx < capacity)[:, None, None], local.cov, jnp.eye(dim))
    )


#: Prefix sizes of the local window (then the whole window) that the association
#: (:func:`._association.associate_window_prefix`) and management
#: (:func:`._management.manage_window_prefix`) run over: the smallest that holds the window's
#: landmarks, which :func:`gather_window` puts in its leading slots.
WINDOW_BUCKETS = (16, 32)


def window_prefixes(w: int, n_local: Int[Array, ""]) -> tuple[tuple[int, ...], Int[Array, ""]]:
    """The prefix sizes of a ``w``-slot local window (:data:`WINDOW_BUCKETS` below ``w``, then
    ``w``) and the index of the smallest that holds ``n_local`` landmarks.

    The index is :func:`~nanoslam_jax.lib._batching.batch_max` of ``n_local``: under ``vmap`` (the
    particles, a sweep's batch) it is the same for every member, so a ``lax.switch`` on it stays
    one branch.
    """
    sizes = tuple(b for b in WINDOW_BUCKETS if b < w) + (w,)
    return sizes, jnp.sum(batch_max(n_local) > jnp.asarray(sizes[:-1], jnp.int32)).astype(jnp.int32)


#: The fields landmark management changes in a local map (:func:`._management.manage_window`).
MANAGED_FIELDS = ("log_odds", "misses", "confirmed", "active")


def scatter_window(
    lm: LandmarkMap, local: LandmarkMap, idx: Int[Array, " window"], fields: tuple[str, ...] | None = None
) -> LandmarkMap:
    """Write the fields of a local map back to their slots (``idx``; ``capacity`` is dropped).

    Args:
        lm: the particle's map.
        local: its local map (from :func:`gather_window`), changed.
        idx: the global slot of each local slot.
        fields: the fields to write (default: every field).
    """
    if fields is None:
        return jax.tree.map(lambda a, b: a.at[idx].set(b, mode="drop"), lm, local)
    return lm._replace(**{f: getattr(lm, f).at[idx].set(getattr(local, f), mode="drop") for f in fields})


def update_slots(
    lm: LandmarkMap,
    slots: Int[Array, " k"],
    mean: Float[Array, "k l"],
    cov: Float[Array, "k l l"],
    diam: Float[Array, " k"] | None = None,
    diam_var: Float[Array, " k"] | None = None,
) -> LandmarkMap:
    """Set the mean and covariance (and the diameter estimate) of the landmarks in ``slots`` and
    count a hit for each.

    ``slots`` are distinct, or ``capacity`` (or beyond) for rows that change nothing: a scan
    changes only the landmarks its detections matched, so this writes ``k`` rows rather than
    the whole window.
    """
    lm = lm._replace(
        mean=lm.mean.at[slots].set(mean, mode="drop"),
        cov=lm.cov.at[slots].set(cov, mode="drop"),
        hits=lm.hits.at[slots].add(1, mode="drop"),
    )
    if diam is not None:
        lm = lm._replace(
            diam=lm.diam.at[slots].set(diam, mode="drop"), diam_var=lm.diam_var.at[slots].set(diam_var, mode="drop")
        )
    return lm


def free_slots(active: Bool[Array, " capacity"], k: int, slots: int | None = None) -> Int[Array, " k"]:
    """The first ``k`` free slots of a map in order (``capacity`` where there are fewer).

    Args:
        active: which slots hold a landmark.
        k: how many free slots are wanted.
        slots: search only the first ``slots`` slots (the search costs in proportion to them;
            from :data:`SEARCH_FROM`, only the blocks holding the free slots found are
            searched); they must hold every active landmark and ``k`` free slots, e.g. a prefix
            holding every active landmark plus ``k`` (default: all).
    """
    capacity = active.shape[0]
    slots = capacity if slots is None else min(slots, capacity)
    span = min(-(-slots // SEARCH_BLOCK) * SEARCH_BLOCK, capacity)  # whole blocks, for the blocked search
    if span >= SEARCH_FROM and span % SEARCH_BLOCK == 0:
        free, _ = first_true_blocked(~active[:span], k)
    else:
        free, _ = first_true(~active[:slots], k)
    return free if slots == capacity else jnp.where(free < slots, free, capacity)


def add_landmarks(
    lm: LandmarkMap,
    new: LandmarkMap,
    is_new: Bool[Array, " k"],
    contiguous: bool = False,
    free: Int[Array, " k"] | None = None,
) -> tuple[LandmarkMap, Int[Array, ""]]:
    """Place new landmarks in free slots, in order.

    New landmarks that find no free slot are dropped and counted (overflow), never silently.

    Args:
        lm: the particle's map.
        new: candidate landmarks (``k`` slots), of which those with ``is_new`` are placed.
        is_new: which candidates are placed.
        contiguous: the active slots are a prefix of the map (always so without landmark
            management, since landmarks are only added): the free slots then start at the active
            count, which avoids a search over the whole capacity; a free slot then already holds
            zero misses.
        free: the first ``k`` free slots when the caller has found them already
            (:func:`free_slots` over a prefix); default: searched here.

    Returns:
        The updated map and the number of landmarks dropped for lack of capacity.
    """
    lm, target = place_landmarks(lm, new, is_new, contiguous, free)
    return lm, jnp.sum(is_new & (target == lm.active.shape[0]))


def place_landmarks(
    lm: LandmarkMap,
    new: LandmarkMap,
    is_new: Bool[Array, " k"],
    contiguous: bool = False,
    free: Int[Array, " k"] | None = None,
) -> tuple[LandmarkMap, Int[Array, " k"]]:
    """:func:`add_landmarks`, returning the slot each candidate went to (``capacity``: not placed,
    for lack of a free slot or not being new) instead of the overflow."""
    capacity = lm.active.shape[0]
    k_max = is_new.shape[0]
    order = jnp.clip(jnp.cumsum(is_new) - 1, 0, k_max - 1)
    if contiguous:
        free = jnp.sum(lm.active) + jnp.arange(k_max)
        free = jnp.where(free < capacity, free, capacity)
    elif free is None:
        free = free_slots(lm.active, k_max)
    target = jnp.where(is_new, free[order], capacity)
    fields = [f for f in LandmarkMap._fields if not (contiguous and f == "misses") and getattr(lm, f) is not None]
    lm = lm._replace(**{f: getattr(lm, f).at[target].set(getattr(new, f), mode="drop") for f in fields})
    return lm, target


def init_landmark(
    x: Float[Array, "3"], z: Float[Array, " d"], R: Float[Array, "d d"], model: AbstractMeasurementModel | None = None
) -> tuple[Float[Array, " l"], Float[Array, "l l"]]:
    """New landmark from pose ``x`` and detection ``z`` (eq. 16): ``g^-1(x, z)``, ``Gm^-1 R Gm^-T``
    (``g`` the measurement model, default range-bearing; ``Gm`` square: ``landmark_dim ==
    measurement_dim``). A type of a composite (:class:`~nanoslam_jax.models.OfKind`) whose
    landmarks are padded has no inverse of ``Gm`` (its padding is not measured): ``Gm^-1`` is then
    the Jacobian of ``g^-1`` in ``z``, which starts the padding with the padding's noise."""
    model = _model(model)
    m = computed_once(model.landmark_from(x, z))
    if isinstance(model, OfKind):
        _, Gi = model.inverse_jacobians(x, z)
    else:
        _, Gm = model.jacobians(x, m)
        Gi = inv_small(Gm)
    return m, sym(sandwich(Gi, R))


def ekf_update_loglik(
    x: Float[Array, "3"],
    z: Float[Array, " d"],
    mean: Float[Array, " l"],
    cov: Float[Array, "l l"],
    R: Float[Array, "d d"],
    model: AbstractMeasurementModel | None = None,
) -> tuple[Float[Array, " l"], Float[Array, "l l"], Float[Array, ""]]:
    """EKF update of one landmark at pose ``x`` with detection ``z`` (Joseph form), and the
    detection's log-likelihood ``log N(z; g(x, mean), Gm cov Gm' + R)`` from the same quantities
    (``g`` the measurement model, default range-bearing)."""
    model = _model(model)
    z_hat = computed_once(model.h(x, mean))
    _, Gm = model.jacobians(x, mean)
    S = sandwich(Gm, cov) + R
    K = mm(mm(cov, mt(Gm)), inv_small(S))
    IKG = jnp.eye(mean.shape[-1]) - mm(K, Gm)
    nu = model.innovation(z, z_hat)
    return mean + mv(K, nu), sym(sandwich(IKG, cov) + sandwich(K, R)), gaussian_logpdf(nu, S)


def ekf_update(
    x: Float[Array, "3"],
    z: Float[Array, " d"],
    mean: Float[Array, " l"],
    cov: Float[Array, "l l"],
    R: Float[Array, "d d"],
    model: AbstractMeasurementModel | None = None,
) -> tuple[Float[Array, " l"], Float[Array, "l l"]]:
    """EKF update of one landmark at pose ``x`` with detection ``z`` (Joseph form)."""
    return ekf_update_loglik(x, z, mean, cov, R, model)[:2]


def _unscented_landmark_points(
    centre: Float[Array, " n"], cov: Float[Array, "n n"], rule: Unscented
) -> tuple[Float[Array, "p n"], Float[Array, " p"], Float[Array, " p"]]:
    """The ``p = 2n + 1`` unscented sigma points of ``N(centre, cov)`` and their weights."""
    xi, wm, wc = rule.unit_points(centre.shape[-1])
    return centre + mmt(xi, chol_small(sym(cov))), wm, wc


def ukf_update_loglik(
    x: Float[Array, "3"],
    z: Float[Array, " d"],
    mean: Float[Array, " l"],
    cov: Float[Array, "l l"],
    R: Float[Array, "d d"],
    rule: Unscented,
    model: AbstractMeasurementModel | None = None,
) -> tuple[Float[Array, " l"], Float[Array, "l l"], Float[Array, ""]]:
    """Unscented (UKF) update of one landmark at pose ``x`` with detection ``z`` (UFastSLAM).

    Sigma points of ``N(mean, cov)`` go through the measurement model; the predicted
    detection is their weighted mean relative to the centre point's prediction (bearing
    deviations wrapped), ``S = Pzz + R``, ``K = Pmz S^-1``, ``mean + K nu`` and
    ``cov - K S K'`` (symmetrised; ``cov`` is kept should the result not be positive definite).

    Args:
        x: the (sampled) pose (3,).
        z: the detection (d,).
        mean: the landmark mean (l,).
        cov: the landmark covariance (l, l).
        R: measurement noise covariance (d, d).
        rule: the unscented transform's parameters (may be traced).
        model: the measurement model (default range-bearing): its ``h`` and its angular
            components ``angles`` (deviations and the innovation wrapped). Any object with these
            two attributes serves.

    Returns:
        The updated mean and covariance and the detection's log-likelihood
        ``log N(nu; 0, S)``, as :func:`ekf_update_loglik`.
    """
    model = _model(model)
    h, angles = model.h, model.angles
    M, wm, wc = _unscented_landmark_points(mean, cov, rule)
    Z = jax.vmap(h, (None, 0))(x, M)
    dZ = Z - Z[0]
    for i in angles:
        dZ = dZ.at[:, i].set(wrap_angle(dZ[:, i]))
    dz_mean, Pzz = sigma_point_stats(dZ, wm, wc)
    Pmz = sigma_point_cross_cov(M, mean, dZ, dz_mean, wc)
    S = sym(Pzz + R)
    K = mm(Pmz, inv_small(S))
    nu = z - (Z[0] + dz_mean)
    for i in angles:
        nu = nu.at[i].set(wrap_angle(nu[i]))
    new_cov = sym(cov - mmt(mm(K, S), K))
    pd = is_pd_small(new_cov)
    return mean + mv(K, nu), jnp.where(pd, new_cov, cov), gaussian_logpdf(nu, S)


def ukf_init_landmark(
    x: Float[Array, "3"],
    z: Float[Array, " d"],
    R: Float[Array, "d d"],
    rule: Unscented,
    model: AbstractMeasurementModel | None = None,
) -> tuple[Float[Array, " l"], Float[Array, "l l"]]:
    """New landmark by the unscented transform of the inverse model over ``z ~ N(z, R)`` (UFastSLAM).

    The unscented counterpart of :func:`init_landmark` (eq. 16): sigma points of the detection
    noise go through ``g^-1(x, .)``; the landmark is their weighted mean and covariance.

    Args:
        x: the (sampled) pose (3,).
        z: the detection (d,).
        R: measurement noise covariance (d, d).
        rule: the unscented transform's parameters (may be traced).
        model: the measurement model (default range-bearing), whose inverse is used.
    """
    Zs, wm, wc = _unscented_landmark_points(z, R, rule)
    M = jax.vmap(_model(model).landmark_from, (None, 0))(x, Zs)
    return sigma_point_stats(M, wm, wc)
