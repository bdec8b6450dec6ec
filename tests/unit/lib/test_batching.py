"""take_if and batch_max: the same values as the plain code, alone and under vmap, and a switch on
batch_max stays a branch under vmap."""

import jax
import jax.extend.core
import jax.numpy as jnp
import numpy as np
import pytest

from nanoslam_jax.lib._batching import batch_max, map_prefix, prefix_max, take_if, take_prefix_if


def _tree(rng, *lead):
    return {
        "mean": jnp.asarray(rng.normal(size=(*lead, 5, 2))),
        "active": jnp.asarray(rng.random((*lead, 5)) < 0.5),
        "hits": jnp.asarray(rng.integers(0, 9, (*lead, 5)), jnp.int32),
    }


def _expected(flag, indices, tree):
    """NumPy: each member's leaves indexed by its indices where its flag is set."""
    out = {k: np.array(v) for k, v in tree.items()}
    for b in np.flatnonzero(np.asarray(flag)):
        for k in out:
            out[k][b] = np.asarray(tree[k])[b][np.asarray(indices)[b]]
    return out


def _assert_tree_equal(got, want):
    assert set(got) == set(want)
    for k in want:
        assert got[k].dtype == want[k].dtype
        np.testing.assert_array_equal(np.asarray(got[k]), want[k])


@pytest.mark.parametrize("flag", [True, False])
def test_take_if_alone_indexes_only_when_flagged(flag):
    rng = np.random.default_rng(0)
    tree = _tree(rng)
    indices = jnp.asarray([4, 4, 0, 2, 1])
    got = jax.jit(take_if)(jnp.asarray(flag), indices, tree)
    want = {k: np.asarray(v)[np.asarray(indices)] if flag else np.asarray(v) for k, v in tree.items()}
    _assert_tree_equal(got, want)


@pytest.mark.parametrize("flags", [[True, False, True, True, False, False], [False] * 6, [True] * 6])
def test_take_if_batched_equals_each_member_alone(flags):
    rng = np.random.default_rng(1)
    tree = _tree(rng, 6)
    indices = jnp.asarray(rng.integers(0, 5, (6, 5)))
    flag = jnp.asarray(flags)
    got = jax.jit(jax.vmap(take_if))(flag, indices, tree)
    _assert_tree_equal(got, _expected(flag, indices, tree))


def test_take_if_batched_with_unbatched_arguments():
    """Arguments shared by the batch (in_axes None) are broadcast to every member."""
    rng = np.random.default_rng(2)
    tree = _tree(rng)
    indices = jnp.asarray([1, 1, 3, 0, 2])
    flag = jnp.asarray([False, True, True, False])
    got = jax.vmap(take_if, (0, None, None))(flag, indices, tree)
    want = _expected(
        flag, np.broadcast_to(indices, (4, 5)), {k: np.broadcast_to(v, (4, *v.shape)) for k, v in tree.items()}
    )
    _assert_tree_equal(got, want)


def test_take_if_under_two_vmaps():
    rng = np.random.default_rng(3)
    tree = _tree(rng, 3, 4)
    indices = jnp.asarray(rng.integers(0, 5, (3, 4, 5)))
    flag = jnp.asarray(rng.random((3, 4)) < 0.5)
    got = jax.jit(jax.vmap(jax.vmap(take_if)))(flag, indices, tree)
    flat = lambda a: np.asarray(a).reshape(12, *np.shape(a)[2:])  # noqa: E731
    want = _expected(flat(flag), flat(indices), {k: flat(v) for k, v in tree.items()})
    _assert_tree_equal({k: flat(v) for k, v in got.items()}, want)


def test_batch_max_is_identity_alone_and_the_batch_maximum_under_vmap():
    assert int(jax.jit(batch_max)(jnp.int32(3))) == 3
    x = jnp.asarray([2, 0, 5, 1], jnp.int32)
    np.testing.assert_array_equal(jax.vmap(batch_max)(x), [5, 5, 5, 5])
    # Nested: the maximum over the inner batch, per outer member.
    np.testing.assert_array_equal(jax.vmap(jax.vmap(batch_max))(x.reshape(2, 2)), [[2, 2], [5, 5]])


def _primitives(jaxpr):
    names = set()
    for eqn in jaxpr.eqns:
        names.add(eqn.primitive.name)
        for sub in jax.extend.core.jaxprs_in_params(eqn.params):
            names |= _primitives(sub)
    return names


def test_switch_on_batch_max_stays_a_branch_under_vmap():
    """Batched, a switch on a per-member index computes every branch (a select); on batch_max of
    it, one branch: the values are those of the largest index's branch, which here (branches that
    agree where the smaller ones apply) equal each member's own."""
    branches = [lambda v, n=n: jnp.cumsum(v)[:4] if n else v[:4] for n in (0, 1, 1)]

    def plain(i, v):
        return jax.lax.switch(i, branches, v)

    def bounded(i, v):
        return jax.lax.switch(batch_max(i), branches, v)

    i = jnp.asarray([1, 2, 1], jnp.int32)
    v = jnp.arange(18.0).reshape(3, 6)
    assert "cond" not in _primitives(jax.make_jaxpr(jax.vmap(plain))(i, v).jaxpr)  # every branch, selected
    assert "cond" in _primitives(jax.make_jaxpr(jax.vmap(bounded))(i, v).jaxpr)
    np.testing.assert_array_equal(jax.vmap(bounded)(i, v), np.cumsum(np.asarray(v), axis=1)[:, :4])


def _maps(rng, n, slots, used):
    """Stacked maps whose slots from ``used`` on hold nothing another entry could need."""
    mean = rng.normal(size=(n, slots, 2))
    active = rng.random((n, slots)) < 0.5
    active[:, used:] = False
    return {"mean": jnp.asarray(mean), "active": jnp.asarray(active)}


@pytest.mark.parametrize("slots, used", [(256, 0), (256, 70), (256, 256), (100, 37), (100, 99), (30, 12)])
def test_take_prefix_if_equals_take_if_below_used_and_keeps_the_rest(slots, used):
    rng = np.random.default_rng(slots + used)
    n = 7
    tree = _maps(rng, n, slots, used)
    anc = jnp.asarray(rng.integers(0, n, n))
    full = take_if(jnp.asarray(True), anc, tree)
    part = take_prefix_if(jnp.asarray(True), anc, tree, jnp.asarray(used))
    for f in tree:
        np.testing.assert_array_equal(np.asarray(part[f])[:, :used], np.asarray(full[f])[:, :used])
        if slots % 64 == 0:  # whole blocks only: those above ``used`` are left as they were
            cut = -(-used // 64) * 64
            np.testing.assert_array_equal(np.asarray(part[f])[:, cut:], np.asarray(tree[f])[:, cut:])
    same = take_prefix_if(jnp.asarray(False), anc, tree, jnp.asarray(used))
    for f in tree:
        np.testing.assert_array_equal(np.asarray(same[f]), np.asarray(tree[f]))


def test_take_prefix_if_under_vmap_takes_each_members_own_branch():
    rng = np.random.default_rng(3)
    b, n, slots, used = 3, 5, 200, 90
    trees = [_maps(rng, n, slots, used) for _ in range(b)]
    tree = {f: jnp.stack([t[f] for t in trees]) for f in trees[0]}
    anc = jnp.asarray(rng.integers(0, n, (b, n)))
    flag = jnp.asarray([True, False, True])
    got = jax.vmap(take_prefix_if, (0, 0, 0, None))(flag, anc, tree, jnp.asarray(used))
    for i in range(b):
        want = take_if(flag[i], anc[i], trees[i])
        for f in tree:
            np.testing.assert_array_equal(np.asarray(got[f][i])[:, :used], np.asarray(want[f])[:, :used])


@pytest.mark.parametrize("slots", [20, 64, 200, 256])
def test_prefix_max_is_one_past_the_highest_set_slot(slots):
    rng = np.random.default_rng(slots)
    for used in (0, 1, slots // 3, slots):
        mask = np.zeros((4, slots), bool)
        if used:
            mask[rng.integers(0, 4, 3), rng.integers(0, used, 3)] = True
        want = int(np.max(np.nonzero(mask)[1]) + 1) if mask.any() else 0
        assert int(prefix_max(jnp.asarray(mask), jnp.asarray(used))) == want


def test_map_prefix_applies_fn_below_used_and_reads_without_carrying():
    x = jnp.arange(300.0)
    other = jnp.full(300, 2.0)
    out = map_prefix(lambda a, o: a * o, x, jnp.asarray(130), read=other)
    np.testing.assert_array_equal(np.asarray(out)[:130], 2 * np.arange(130.0))
    # whole blocks of 64 up to 192 and the tail past 256 are visited; the block 192-255 is not
    np.testing.assert_array_equal(np.asarray(out)[192:256], np.arange(192.0, 256.0))
