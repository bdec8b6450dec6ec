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

A third does the same for a loop: under ``vmap`` a ``lax.while_loop`` runs every member's body
until the last member is done. :func:`compacted_while_loop` runs the whole batch only while many
members go on, then gathers the few that still do into a small batch and finishes them there
(NANO's iterations: most particles converge in 2 iterations, but in a batch of hundreds one
usually needs a third).
"""

from __future__ import annotations

from typing import Any, Callable

import jax
import jax.numpy as jnp
from jax.custom_batching import custom_vmap
from jaxtyping import Array, Bool, Int

__all__ = ["batch_max", "compacted_while_loop", "take_if"]


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


def compacted_while_loop(
    cond_fun: Callable[[Any, Any], Bool[Array, ""]],
    body_fun: Callable[[Any, Any], Any],
    operands: Any,
    init_val: Any,
    *,
    compact_to: int | None = None,
) -> Any:
    """``lax.while_loop(lambda c: cond_fun(operands, c), lambda c: body_fun(operands, c), init_val)``,
    whose batched form finishes the last members on a small batch.

    Args:
        cond_fun: ``(operands, carry) -> bool``, whether a member goes on.
        body_fun: ``(operands, carry) -> carry``, one iteration of a member.
        operands: the loop's constants (a pytree of arrays; every traced value the two functions
            use must be here, not closed over).
        init_val: the initial carry.
        compact_to: (static) the size of the small batch (default: an eighth of the batch); a
            small batch under 8 members or above half the batch is not worth its gathers, and
            the batch then runs as a plain batched loop.

    Under ``vmap`` over ``n`` members the loop runs the whole batch while more than
    ``compact_to`` members go on (members that are done keep their carry, as a batched
    ``while_loop`` does), then gathers the members still going on into a batch of
    ``compact_to``, runs it until each of them is done, and writes them back. Every member goes
    through the same iterations as alone: the result is the batched ``while_loop``'s.
    """
    loop = _compacted_loop(cond_fun, body_fun, compact_to)
    return loop(operands, init_val)


def _masked_step(vcond, vbody, operands, carry, valid=None):
    """One iteration of the members that go on (and are ``valid``); the others keep their carry."""
    going = vcond(operands, carry)
    going = going if valid is None else going & valid
    new = vbody(operands, carry)
    keep = lambda n, o: jnp.where(going.reshape(going.shape + (1,) * (n.ndim - 1)), n, o)  # noqa: E731
    return jax.tree.map(keep, new, carry)


def _compacted_loop(cond_fun, body_fun, compact_to: int):
    @custom_vmap
    def loop(operands, init_val):
        return jax.lax.while_loop(lambda c: cond_fun(operands, c), lambda c: body_fun(operands, c), init_val)

    @loop.def_vmap
    def _batched(axis_size, in_batched, operands, init_val):
        small = axis_size // 8 if compact_to is None else compact_to
        ops_b, init_b = in_batched
        operands = jax.tree.map(lambda a, b: _broadcast(axis_size, a, b), operands, ops_b)
        carry = jax.tree.map(lambda a, b: _broadcast(axis_size, a, b), init_val, init_b)
        vcond, vbody = jax.vmap(cond_fun), jax.vmap(body_fun)
        step = lambda ops, c, valid=None: _masked_step(vcond, vbody, ops, c, valid)  # noqa: E731
        if small < 8 or 2 * small > axis_size:
            carry = jax.lax.while_loop(lambda c: jnp.any(vcond(operands, c)), lambda c: step(operands, c), carry)
            return carry, jax.tree.map(lambda _: True, carry)
        # The whole batch while many members go on.
        carry = jax.lax.while_loop(lambda c: jnp.sum(vcond(operands, c)) > small,
                                   lambda c: step(operands, c), carry)
        # The rest (at most ``small``) gathered into a small batch; padding repeats member 0
        # and is masked out of the iterations and the write-back.
        (idx,) = jnp.nonzero(vcond(operands, carry), size=small, fill_value=axis_size)
        valid = idx < axis_size
        take = jnp.where(valid, idx, 0)
        sub_ops = jax.tree.map(lambda a: a[take], operands)
        sub = jax.tree.map(lambda a: a[take], carry)
        sub = jax.lax.while_loop(lambda c: jnp.any(vcond(sub_ops, c) & valid),
                                 lambda c: step(sub_ops, c, valid), sub)
        carry = jax.tree.map(lambda a, b: a.at[idx].set(b, mode="drop"), carry, sub)
        return carry, jax.tree.map(lambda _: True, carry)

    return loop
