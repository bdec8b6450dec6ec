"""Two operations whose batched form (under ``jax.vmap``, e.g. a sweep batch of runs) is written
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
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from jax.custom_batching import custom_vmap
from jaxtyping import Array, Bool, Int

__all__ = ["batch_max", "take_if"]


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
        i = members[j]
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
