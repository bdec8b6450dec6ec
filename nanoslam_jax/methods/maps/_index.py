"""The local-window search of a long map through its spatial index
(:class:`~nanoslam_jax.methods._state.BlockIndex`: the bounding box of the landmark positions in
each block of :data:`~nanoslam_jax.methods._state.SEARCH_BLOCK` slots, kept with the map).

:func:`gather_window_indexed` measures the distance to the landmarks of the blocks whose box comes
within the window's radius only, instead of to every landmark in use, and finds exactly what the
whole-map search (:func:`~._landmarks.gather_window`) finds: a landmark within the radius lies in
a box within it. The boxes only widen (every write of a landmark's position widens its block's
box to hold it; a removed landmark leaves its box as it was), so they always hold every active
landmark.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from nanoslam_jax.lib._batching import batch_max
from nanoslam_jax.models import AbstractMeasurementModel, RangeBearing
from nanoslam_jax.methods._state import SEARCH_BLOCK, BlockIndex, LandmarkMap
from nanoslam_jax.methods.maps._landmarks import first_true, local_map, window_slots

#: Blocks a search of :func:`gather_window_indexed` may visit (then the whole map is searched).
INDEX_BUDGETS = (2, 8, 32)


def index_of(lm: LandmarkMap) -> BlockIndex:
    """The exact index of one map (capacity a multiple of the block): the boxes of the positions
    of its active landmarks, block by block."""
    act = lm.active.reshape(-1, SEARCH_BLOCK)[..., None]
    xy = lm.mean[:, :2].reshape(-1, SEARCH_BLOCK, 2)
    return BlockIndex(jnp.min(jnp.where(act, xy, jnp.inf), axis=1), jnp.max(jnp.where(act, xy, -jnp.inf), axis=1))


def _search_blocks(
    lm: LandmarkMap,
    near_block: Bool[Array, " nb"],
    k: int,
    position: Float[Array, "2"],
    window: int,
    radius2: Float[Array, ""],
    model: AbstractMeasurementModel,
) -> tuple[Int[Array, " window"], Int[Array, ""]]:
    """The window's slots (``capacity`` for unused ones) and the count of near landmarks, from the
    first ``k`` near blocks (every near block, when there are at most ``k``)."""
    capacity, b, nb = lm.active.shape[0], SEARCH_BLOCK, near_block.shape[0]
    blocks, _ = first_true(near_block, k)  # ``nb`` past the near blocks
    slots = (blocks[:, None] * b + jnp.arange(b, dtype=jnp.int32)).reshape(-1)
    mean = lm.mean.at[slots].get(mode="fill", fill_value=0.0)
    active = lm.active.at[slots].get(mode="fill", fill_value=False) & (slots < nb * b)
    near = active & (model.window_distance2(position, mean) < radius2)
    j, n_near = first_true(near, window)
    idx = slots.at[j].get(mode="fill", fill_value=capacity)
    return jnp.where(idx < nb * b, idx, capacity), n_near


def gather_window_indexed(
    lm: LandmarkMap,
    index: BlockIndex,
    position: Float[Array, "2"],
    window: int,
    radius: Float[Array, ""],
    slots: int | None = None,
    model: AbstractMeasurementModel | None = None,
) -> tuple[LandmarkMap, Int[Array, " window"], Int[Array, ""]]:
    """:func:`~._landmarks.gather_window` of a map that keeps a
    :class:`~nanoslam_jax.methods._state.BlockIndex`: the same local map, slots and overflow.

    Only the blocks whose box comes within ``radius`` are searched: the fewest of
    :data:`INDEX_BUDGETS` blocks that hold them all (a ``lax.switch`` on
    :func:`~nanoslam_jax.lib._batching.batch_max`, so under ``vmap`` one branch serves every
    member), or the whole prefix of ``slots`` slots when more blocks are near.

    Args:
        lm: the particle's map (capacity slots).
        index: its index, whose boxes hold every active landmark's position.
        position: where the particle is.
        window: how many landmarks the local map holds.
        radius: landmarks within this distance of ``position`` are copied.
        slots: a prefix holding every active landmark (a multiple of the block; default: all).
        model: a point landmarks' measurement model (default: range-bearing).
    """
    model = RangeBearing() if model is None else model
    capacity = lm.active.shape[0]
    slots = capacity if slots is None else min(slots, capacity)
    nb = slots // SEARCH_BLOCK
    radius2 = jnp.square(radius)
    near_block = index.near(position, radius2, nb)
    budgets = tuple(k for k in INDEX_BUDGETS if k < nb)

    def search(k: int) -> tuple[Int[Array, " window"], Int[Array, ""]]:
        return _search_blocks(lm, near_block, k, position, window, radius2, model)

    if budgets:
        whole = functools.partial(window_slots, lm, position, window, radius, slots, model)
        branches = [functools.partial(search, k) for k in budgets] + [whole]
        branch = batch_max(jnp.sum(jnp.sum(near_block) > jnp.asarray(budgets, jnp.int32)).astype(jnp.int32))
        idx, n_near = jax.lax.switch(branch, branches)
    else:
        idx, n_near = search(nb)
    return local_map(lm, idx), idx, jnp.maximum(n_near - window, 0)
