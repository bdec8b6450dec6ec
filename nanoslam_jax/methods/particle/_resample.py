"""The maps at resampling: each particle's map takes its ancestor's, copying only the blocks of
slots in which the two differ.

A long map (from :data:`~nanoslam_jax.methods._state.SEARCH_FROM` slots, one device) keeps a
version per block of :data:`~nanoslam_jax.methods._state.SEARCH_BLOCK` slots of every particle
(``Particles.map_version``), with one invariant: two particles' blocks with the same version hold
the same slots. A scan writes only the slots of a particle's local window and its new landmarks;
:func:`mark_written` gives those blocks a version no other particle holds. The rest of a step's
map work (dropping stale tentative landmarks) is the same function of every particle's slots, so
it keeps equal blocks equal. At resampling, :func:`take_changed_blocks` then copies only the
blocks whose version differs from the ancestor's: the blocks either particle wrote since their
last common ancestor, a few per particle, where a copy of the slots in use costs the whole map.
The result equals :func:`~nanoslam_jax.lib._batching.take_prefix_if`.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Int

from nanoslam_jax.lib._batching import batch_max, take_prefix_if
from nanoslam_jax.methods._state import SEARCH_BLOCK
from nanoslam_jax.methods.maps._landmarks import first_true

__all__ = ["mark_written", "take_changed_blocks"]

#: Blocks per particle that one pass of :func:`take_changed_blocks`'s copy loop copies.
COPY_CHUNK = 2


def mark_written(
    version: Int[Array, "n blocks"], written: Int[Array, "n k"], epoch: Int[Array, ""]
) -> Int[Array, "n blocks"]:
    """The particles' block versions after a step wrote the slots ``written`` of each particle's map.

    Args:
        version: each particle's block versions before the step.
        written: per particle, the slots the step wrote (the map's capacity, or beyond, for none).
        epoch: resamplings so far. A written block takes the version ``epoch * n + i + 1`` for
            particle ``i``: no other particle holds it, since versions spread between particles only
            at resampling, which starts a new epoch.
    """
    n, blocks = version.shape
    fresh = epoch.astype(version.dtype) * n + jnp.arange(1, n + 1, dtype=version.dtype)
    rows = jnp.broadcast_to(jnp.arange(n)[:, None], written.shape)
    block = written // SEARCH_BLOCK  # from ``blocks`` on (no slot written): dropped
    return version.at[rows, block].set(jnp.broadcast_to(fresh[:, None], written.shape), mode="drop")


def take_changed_blocks(
    flag: Bool[Array, ""],
    indices: Int[Array, " n"],
    maps: Any,
    version: Int[Array, "n blocks"],
    used: Int[Array, ""],
) -> tuple[Any, Int[Array, "n blocks"]]:
    """:func:`~nanoslam_jax.lib._batching.take_prefix_if` of stacked maps with block versions:
    if ``flag``, each particle ``i`` takes the slots below ``used`` of particle ``indices[i]``.

    Args:
        flag: whether the particles were resampled.
        indices: each particle's ancestor.
        maps: a pytree of arrays of shape ``(n, blocks * SEARCH_BLOCK, ...)`` (the landmark maps),
            updated in place.
        version: each particle's block versions (equal versions: equal slots in the block).
        used: one past the highest slot to copy (unbatched under ``vmap``).

    Returns:
        The maps, equal to those of ``take_prefix_if``, and the new block versions (the
        ancestor's below ``used``, each particle's own above, where nothing was copied).

    Only the blocks below ``used`` whose version differs from the ancestor's are copied, in
    place, :data:`COPY_CHUNK` blocks per particle at a time. Ancestors in order (systematic and
    stratified resampling give them so) let the copies run in an order in which no
    block is read after it was written: first the particles whose ancestor comes after them,
    upwards, then those whose ancestor comes before them, downwards. Ancestors out of order
    (multinomial and residual resampling) are copied as ``take_prefix_if`` copies them.
    """
    n, blocks = version.shape
    rows = jnp.arange(n, dtype=indices.dtype)
    in_use = jnp.arange(blocks) < jnp.minimum((used + SEARCH_BLOCK - 1) // SEARCH_BLOCK, blocks)
    theirs = version[indices]
    ordered = jnp.all(indices[1:] >= indices[:-1])
    stale = (flag & ordered) & in_use & (theirs != version)
    chunk = COPY_CHUNK * n
    size = n * blocks + chunk  # every entry, then a pass's worth past the last
    none = jnp.full(size, n * blocks, jnp.int32)

    def lists(_):
        up, down = stale & (indices > rows)[:, None], stale & (indices < rows)[:, None]
        (a, ca), (b, cb) = first_true(up.reshape(-1), size), first_true(down.reshape(-1), size)
        return a, ca, b, cb

    # Under a sweep's vmap, listed for every member when any has blocks to copy.
    any_stale = batch_max(jnp.any(stale).astype(jnp.int32)) > 0
    up_list, n_up, down_list, n_down = jax.lax.cond(
        any_stale, lists, lambda _: (none, jnp.int32(0), none, jnp.int32(0)), None
    )

    def copy(entries, tree):
        dst, blk = entries // blocks, entries % blocks  # past the last entry: ``n``, dropped
        src = indices.at[dst].get(mode="fill", fill_value=0)

        def leaf(a):
            b = a.reshape((n, blocks, SEARCH_BLOCK) + a.shape[2:])
            return b.at[dst, blk].set(b[src, blk], mode="drop").reshape(a.shape)

        return jax.tree.map(leaf, tree)

    def upwards(i, tree):
        return copy(jax.lax.dynamic_slice_in_dim(up_list, i * chunk, chunk), tree)

    def downwards(i, tree):
        at = n_down - 1 - i * chunk - jnp.arange(chunk)
        return copy(jnp.where(at >= 0, down_list.at[at].get(mode="fill", fill_value=n * blocks), n * blocks), tree)

    passes = lambda count: batch_max((count + chunk - 1) // chunk)  # noqa: E731
    maps = jax.lax.fori_loop(0, passes(n_up), upwards, maps)
    maps = jax.lax.fori_loop(0, passes(n_down), downwards, maps)
    maps = take_prefix_if(flag & ~ordered, indices, maps, used)
    return maps, jnp.where(flag & in_use, theirs, version)
