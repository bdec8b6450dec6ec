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

A third does it for a loop: under ``vmap`` a ``lax.while_loop`` runs every member's body until the
last member of the whole batch is done, over intermediates the size of the whole batch.
:func:`chunked_while_loop` runs the batch in chunks, one after the other, each until its own
members are done (NANO's iterations: most particles converge in 2 iterations, but in a batch of
hundreds one usually needs a third; a chunk's per-point products also stay in the cache).
"""

from __future__ import annotations

from typing import Any, Callable

import jax
import jax.numpy as jnp
from jax.custom_batching import custom_vmap
from jaxtyping import Array, Bool, Int

__all__ = ["batch_max", "chunked_while_loop", "take_if"]


def _broadcast(axis_size: int, x, batched: bool):
    return x if batched else jnp.broadcast_to(x, (axis_size,) + jnp.shape(x))


def _take(indices, tree):
    return jax.tree.map(lambda a: a[indices], tree)


@custom_vmap
def take_if(flag: Bool[Array, ""], indices: Int[Array, "n"], tree: Any) -> Any:
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


def chunked_while_loop(
    cond_fun: Callable[[Any, Any], Bool[Array, ""]],
    body_fun: Callable[[Any, Any], Any],
    operands: Any,
    init_val: Any,
    *,
    chunk: int = 0,
) -> Any:
    """``lax.while_loop(lambda c: cond_fun(operands, c), lambda c: body_fun(operands, c), init_val)``,
    whose batched form runs the batch in chunks.

    Args:
        cond_fun: ``(operands, carry) -> bool``, whether a member goes on.
        body_fun: ``(operands, carry) -> carry``, one iteration of a member.
        operands: the loop's constants (a pytree of arrays; every traced value the two functions
            use must be here, not closed over).
        init_val: the initial carry.
        chunk: (static) the members per chunk under ``vmap``; 0, or a batch of at most
            ``chunk`` members, runs the batch as one batched ``while_loop``.

    Under ``vmap`` over ``n`` members the batch is cut into ``ceil(n / chunk)`` chunks of equal
    size (the last padded with copies of the last member, whose results are dropped), and a
    ``lax.map`` runs each chunk's batched loop until each of its members is done. Members that
    are done keep their carry, as in a batched ``while_loop``: every member goes through the same
    iterations as alone, and the result is the batched ``while_loop``'s.
    """
    return _chunked_loop(cond_fun, body_fun, chunk)(operands, init_val)


def _batched_loop(cond_fun, body_fun, operands, carry):
    """The batched ``while_loop`` over the leading axis of ``operands`` and ``carry``."""
    vcond, vbody = jax.vmap(cond_fun), jax.vmap(body_fun)

    def step(c):
        going = vcond(operands, c)
        new = vbody(operands, c)
        keep = lambda n, o: jnp.where(going.reshape(going.shape + (1,) * (n.ndim - 1)), n, o)  # noqa: E731
        return jax.tree.map(keep, new, c)

    return jax.lax.while_loop(lambda c: jnp.any(vcond(operands, c)), step, carry)


def _chunked_loop(cond_fun, body_fun, chunk: int):
    @custom_vmap
    def loop(operands, init_val):
        return jax.lax.while_loop(lambda c: cond_fun(operands, c), lambda c: body_fun(operands, c), init_val)

    @loop.def_vmap
    def _batched(axis_size, in_batched, operands, init_val):
        ops_b, init_b = in_batched
        operands = jax.tree.map(lambda a, b: _broadcast(axis_size, a, b), operands, ops_b)
        carry = jax.tree.map(lambda a, b: _broadcast(axis_size, a, b), init_val, init_b)
        n_chunks = -(-axis_size // chunk) if chunk > 0 else 1
        if n_chunks <= 1:
            out = _batched_loop(cond_fun, body_fun, operands, carry)
            return out, jax.tree.map(lambda _: True, out)
        size = -(-axis_size // n_chunks)
        pad = n_chunks * size - axis_size

        def split(a):
            if pad:
                a = jnp.concatenate([a, jnp.broadcast_to(a[-1:], (pad,) + a.shape[1:])])
            return a.reshape((n_chunks, size) + a.shape[1:])

        chunks = jax.lax.map(lambda oc: _batched_loop(cond_fun, body_fun, *oc),
                             jax.tree.map(split, (operands, carry)))
        out = jax.tree.map(lambda a: a.reshape((n_chunks * size,) + a.shape[2:])[:axis_size], chunks)
        return out, jax.tree.map(lambda _: True, out)

    return loop
