"""Operations on the leading slots of landmark arrays, and two whose batched form (under ``jax.vmap``, e.g. a sweep batch of runs) is written
by hand, so that a batch of runs keeps the branches a single run takes.

Under ``vmap`` a ``lax.cond`` or ``lax.switch`` whose predicate differs between the batch members
becomes a select over every branch: each member computes every branch. For the two branches of a
filter step that touch the whole landmark maps this costs far more than the branch itself:

* :func:`take_if`, the copy of the maps at resampling, is a conditional gather in a single run;
  batched, each member copies its own maps only when it resamples (a loop over the members),
  instead of every member gathering and selecting its maps at every step.
* :func:`batch_max`, a bound a branch index is computed from, is the bound itself in a single
  run; batched, it is the largest over the batch and unbatched, so a ``lax.switch`` on it stays
  a branch (every member takes the branch the largest needs, which gives each the same result).

The prefix operations (:func:`map_prefix`, :func:`prefix_max`, :func:`take_prefix_if`) touch only
the slots below a traced bound (every active landmark of a map lies there), in blocks of
:data:`CHUNK` slots, so that their cost follows the landmarks in use, not the map's capacity.
"""

from __future__ import annotations

import functools
from typing import Any, Callable

import jax
import jax.numpy as jnp
from jax.custom_batching import custom_vmap
from jaxtyping import Array, Bool, Int

__all__ = ["CHUNK", "batch_max", "map_prefix", "prefix_max", "take_if", "take_prefix_if"]

#: Slots per block of the prefix operations.
CHUNK = 64


def _broadcast(axis_size: int, x, batched: bool):
    return x if batched else jnp.broadcast_to(x, (axis_size,) + jnp.shape(x))


def _take(indices, tree):
    return jax.tree.map(lambda a: a[indices], tree)


@custom_vmap
def take_if(flag: Bool[Array, ""], indices: Int[Array, " n"], tree: Any) -> Any:
    """``tree`` indexed by ``indices`` along the leading axis of every leaf if ``flag``, else
    ``tree`` (``lax.cond``).

    Args:
        flag: whether to index.
        indices: the ``n`` entries to take (e.g. the ancestors of resampled particles).
        tree: a pytree of arrays with leading axis ``n``.

    Under ``vmap`` this is a loop over the members whose ``flag`` is set, each indexing its own
    entries in place; the values are those of the members computed alone.
    """
    return jax.lax.cond(flag, _take, lambda _, t: t, indices, tree)


@take_if.def_vmap
def _take_if_batched(axis_size, in_batched, flag, indices, tree):
    flag_b, indices_b, tree_b = in_batched
    flag = _broadcast(axis_size, flag, flag_b)
    indices = _broadcast(axis_size, indices, indices_b)
    tree = jax.tree.map(lambda a, b: _broadcast(axis_size, a, b), tree, tree_b)

    # The members whose flag is set first (in order), then a loop over just those.
    members = jnp.argsort(~flag, stable=True)

    def copy(j, t):
        i = members[j].astype(jnp.int32)
        return jax.tree.map(lambda a: jax.lax.dynamic_update_index_in_dim(a, _take(indices[i], a[i]), i, 0), t)

    out = jax.lax.fori_loop(0, jnp.sum(flag), copy, tree)
    return out, jax.tree.map(lambda _: True, out)


@custom_vmap
def batch_max(x: Int[Array, ""]) -> Int[Array, ""]:
    """``x`` itself; under ``vmap``, the largest ``x`` of the batch, unbatched.

    For an index that a ``lax.switch`` branches on where any branch at or above a member's own
    index gives that member the same result (a bucket of array sizes large enough for it).
    """
    return x


@batch_max.def_vmap
def _batch_max_batched(axis_size, in_batched, x):
    (x_b,) = in_batched
    return (jnp.max(x, axis=0) if x_b else x), False


def _blocks(size: int, used: Int[Array, ""], chunk: int) -> tuple[int, Int[Array, ""], int]:
    """Block size, blocks to visit (those holding slots below ``used``) and the first slot of the
    tail that the whole blocks leave (always visited) for ``size`` slots."""
    c = min(chunk, size)
    whole = size // c
    return c, jnp.minimum((used + c - 1) // c, whole), whole * c


def map_prefix(
    fn: Callable[..., Any],
    tree: Any,
    used: Int[Array, ""],
    axis: int = 0,
    chunk: int = CHUNK,
    read: Any = None,
) -> Any:
    """``tree`` with ``fn`` applied to its slots below ``used`` along ``axis`` (in whole blocks of
    ``chunk`` slots, and the tail past the last whole block); the slots above are unchanged.

    Args:
        fn: maps a block of every leaf (the slots along ``axis`` cut to the block) to the new
            block, each slot independently of the others; with ``read``, called as
            ``fn(block, read_block)``.
        tree: a pytree of arrays sharing the slot axis, updated in place.
        used: one past the highest slot ``fn`` must see (traced).
        axis: the slot axis of every leaf.
        chunk: slots per block.
        read: a pytree of arrays with the same slot axis that ``fn`` reads and does not change
            (kept out of the loop's carry, so that they are not copied).

    The blocks are visited in a loop with a traced trip count.
    """
    size = jax.tree.leaves(tree)[0].shape[axis]
    c, n, tail = _blocks(size, used, chunk)

    def apply(t, start, width):
        cut = lambda x: jax.tree.map(lambda a: jax.lax.dynamic_slice_in_dim(a, start, width, axis), x)  # noqa: E731
        new = fn(cut(t)) if read is None else fn(cut(t), cut(read))
        return jax.tree.map(lambda a, p: jax.lax.dynamic_update_slice_in_dim(a, p, start, axis), t, new)

    out = jax.lax.fori_loop(0, n, lambda i, t: apply(t, i * c, c), tree)
    return apply(out, tail, size - tail) if tail < size else out


def prefix_max(mask: Bool[Array, "*lead slots"], used: Int[Array, ""], chunk: int = CHUNK) -> Int[Array, ""]:
    """One past the highest set slot (last axis) over all leading entries of ``mask``, searched
    below ``used`` only (0 when none is set there)."""
    size = mask.shape[-1]
    c, n, tail = _blocks(size, used, chunk)
    flat = mask.reshape(-1, size)

    def top(block, start):
        slot = start + jnp.arange(1, block.shape[-1] + 1, dtype=jnp.int32)
        return jnp.max(jnp.where(block, slot, 0), initial=0)

    def body(i, best):
        return jnp.maximum(best, top(jax.lax.dynamic_slice_in_dim(flat, i * c, c, 1), i * c))

    best = jax.lax.fori_loop(0, n, body, jnp.zeros((), jnp.int32))
    if tail < size:
        best = jnp.maximum(best, jnp.where(used > tail, top(flat[:, tail:], tail), 0))
    return best


def _take_blocks(indices, tree, used):
    return map_prefix(functools.partial(_take, indices), tree, used, axis=1)


@custom_vmap
def take_prefix_if(flag: Bool[Array, ""], indices: Int[Array, " n"], tree: Any, used: Int[Array, ""]) -> Any:
    """:func:`take_if` of the slots below ``used`` (axis 1 of every leaf, the landmark slots of
    stacked maps): the other slots keep their own entries.

    For maps whose slots from ``used`` on are free in every entry (their contents are never read),
    this equals the whole :func:`take_if` at a cost that follows ``used``, not the capacity.

    Args:
        flag: whether to index.
        indices: the ``n`` entries to take along the leading axis.
        tree: a pytree of arrays of shape ``(n, slots, ...)``.
        used: one past the highest slot to copy (traced; unbatched under ``vmap``, e.g. through
            :func:`batch_max`).
    """
    return jax.lax.cond(flag, _take_blocks, lambda _, t, u: t, indices, tree, used)


def _origin(a, member, start) -> tuple:
    """Start indices (int32) of member ``member``'s block from slot ``start`` in a batched leaf."""
    zero = jnp.zeros((), jnp.int32)
    return (jnp.asarray(member, jnp.int32), zero, jnp.asarray(start, jnp.int32)) + (zero,) * (a.ndim - 3)


@take_prefix_if.def_vmap
def _take_prefix_if_batched(axis_size, in_batched, flag, indices, tree, used):
    flag_b, indices_b, tree_b, used_b = in_batched
    if used_b:
        used = jnp.max(used)
    flag = _broadcast(axis_size, flag, flag_b)
    indices = _broadcast(axis_size, indices, indices_b)
    tree = jax.tree.map(lambda a, b: _broadcast(axis_size, a, b), tree, tree_b)
    members = jnp.argsort(~flag, stable=True)

    def copy(j, t):
        i = members[j].astype(jnp.int32)

        # Member i's leaves, with the member axis kept (length 1) so that the blocks of its slot
        # axis (now axis 2) are updated in place in the batched arrays.
        def fn(part):
            return jax.tree.map(lambda a: a[:, indices[i]], part)

        size = jax.tree.leaves(t)[0].shape[2]
        c, n, tail = _blocks(size, used, CHUNK)

        def body(k, tt):
            start = jnp.asarray(k * c, jnp.int32)
            part = jax.tree.map(
                lambda a: jax.lax.dynamic_slice(a, _origin(a, i, start), (1, a.shape[1], c) + a.shape[3:]),
                tt,
            )
            new = fn(part)
            return jax.tree.map(lambda a, p: jax.lax.dynamic_update_slice(a, p, _origin(a, i, start)), tt, new)

        t = jax.lax.fori_loop(0, n, body, t)
        if tail < size:
            part = jax.tree.map(
                lambda a: jax.lax.dynamic_slice(a, _origin(a, i, tail), (1, a.shape[1], size - tail) + a.shape[3:]),
                t,
            )
            t = jax.tree.map(
                lambda a, p: jax.lax.dynamic_update_slice(a, p, _origin(a, i, tail)),
                t,
                fn(part),
            )
        return t

    out = jax.lax.fori_loop(0, jnp.sum(flag), copy, tree)
    return out, jax.tree.map(lambda _: True, out)
