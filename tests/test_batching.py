"""take_if, batch_max and chunked_while_loop: the same values as the plain code, alone and under
vmap, a switch on batch_max stays a branch under vmap, and the chunked loop iterates each chunk
only until its own members are done."""

import jax
import jax.extend.core
import jax.numpy as jnp
import numpy as np
import pytest

from nanoslam_jax._batching import batch_max, chunked_while_loop, take_if


def _tree(rng, *lead):
    return {"mean": jnp.asarray(rng.normal(size=(*lead, 5, 2))), "active": jnp.asarray(rng.random((*lead, 5)) < 0.5),
            "hits": jnp.asarray(rng.integers(0, 9, (*lead, 5)), jnp.int32)}


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
    want = _expected(flag, np.broadcast_to(indices, (4, 5)), {k: np.broadcast_to(v, (4, *v.shape)) for k, v in tree.items()})
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


# chunked_while_loop on Newton's iteration for square roots: each member iterates until its own
# tolerance is met, so the members take from 0 to about 20 iterations.
MAX_ITER = 60


def _newton_cond(ops, c):
    a, tol = ops
    i, x = c
    return (i < MAX_ITER) & (jnp.abs(x * x - a) > tol * a)


def _newton_body(ops, c):
    a, _ = ops
    i, x = c
    return i + 1, 0.5 * (x + a / x)


def _newton_reference(a, tol, x0):
    """Each member alone, in Python: its iteration count and its root."""
    out_i, out_x = [], []
    for ai, ti, xi in zip(np.broadcast_to(a, np.shape(x0)), np.broadcast_to(tol, np.shape(x0)), x0):
        i, x = 0, float(xi)
        while i < MAX_ITER and abs(x * x - ai) > ti * ai:
            i, x = i + 1, 0.5 * (x + ai / x)
        out_i.append(i)
        out_x.append(x)
    return np.asarray(out_i), np.asarray(out_x)


def _newton(a, tol, x0, **kw):
    return chunked_while_loop(_newton_cond, _newton_body, (a, tol), (jnp.int32(0), x0), **kw)


def test_chunked_while_loop_alone_is_the_while_loop():
    i, x = jax.jit(lambda a, t, x: _newton(a, t, x, chunk=4))(jnp.float64(7.0), jnp.float64(1e-12), jnp.float64(1.0))
    want_i, want_x = _newton_reference(7.0, 1e-12, np.asarray([1.0]))
    assert int(i) == want_i[0] and float(x) == want_x[0]
    np.testing.assert_allclose(float(x), np.sqrt(7.0), rtol=1e-12)


@pytest.mark.parametrize("n,chunk", [(256, 0), (256, 64), (250, 64), (40, 64), (37, 5), (300, 299)])
def test_chunked_while_loop_batched_equals_each_member_alone(n, chunk):
    """Batched (the whole batch at once; chunks dividing it; chunks padded at the end: 250 in 4
    of 63, 37 in 8 of 5, 300 in 2 of 150; a batch no larger than a chunk), every member's
    iteration count and root are its own, bit for bit: members that need many iterations,
    members done at once, and a shared tolerance."""
    rng = np.random.default_rng(4)
    a = np.exp(rng.uniform(-8.0, 18.0, n))
    x0 = np.where(rng.random(n) < 0.2, np.sqrt(a), 1.0)  # a fifth start at the root: done at once
    tol = 1e-13
    got_i, got_x = jax.jit(jax.vmap(lambda a, x: _newton(a, tol, x, chunk=chunk)))(jnp.asarray(a), jnp.asarray(x0))
    want_i, want_x = _newton_reference(a, tol, x0)
    assert want_i.max() > 15 and (want_i == 0).sum() > n // 10  # the spread the test is about
    np.testing.assert_array_equal(np.asarray(got_i), want_i)
    np.testing.assert_array_equal(np.asarray(got_x), want_x)


def test_chunked_while_loop_with_unbatched_operands():
    """The operands shared by the batch (in_axes None) are broadcast to every chunk."""
    n = 128
    x0 = np.full(n, 3.0)
    x0[[5, 70, 127]] = [1e-3, 1e6, 42.0]  # far from the root: many iterations
    got_i, got_x = jax.vmap(lambda a, t, x: _newton(a, t, x, chunk=32), (None, None, 0))(
        jnp.float64(9.0), jnp.float64(1e-14), jnp.asarray(x0))
    want_i, want_x = _newton_reference(9.0, 1e-14, x0)
    np.testing.assert_array_equal(np.asarray(got_i), want_i)
    np.testing.assert_array_equal(np.asarray(got_x), want_x)


def test_chunked_while_loop_under_two_vmaps():
    """A sweep batch of runs (outer vmap) over chunked particles (inner vmap)."""
    rng = np.random.default_rng(5)
    a = np.exp(rng.uniform(-5.0, 12.0, (3, 80)))
    got_i, got_x = jax.jit(jax.vmap(jax.vmap(lambda a, x: _newton(a, 1e-12, x, chunk=24))))(jnp.asarray(a), jnp.ones((3, 80)))
    want_i, want_x = _newton_reference(a.reshape(-1), 1e-12, np.ones(240))
    np.testing.assert_array_equal(np.asarray(got_i).reshape(-1), want_i)
    np.testing.assert_array_equal(np.asarray(got_x).reshape(-1), want_x)


def _loop_passes(a, x0, chunk):
    """Passes of the batched loop's body, counted by a host callback in the body."""
    passes = []

    def body(ops, c):
        jax.debug.callback(lambda: passes.append(1))
        return _newton_body(ops, c)

    run = jax.vmap(lambda a, x: chunked_while_loop(_newton_cond, body, (a, 1e-13), (jnp.int32(0), x), chunk=chunk))
    jax.block_until_ready(jax.jit(run)(a, x0))
    return len(passes)


def test_chunked_while_loop_iterates_each_chunk_until_its_own_members_are_done():
    """One slow member per batch: whole, the batch makes the slow member's passes; in chunks of
    16, only its chunk does, the others the passes of their own slowest member."""
    a = jnp.full(64, 4.0)
    x0 = jnp.full(64, 2.5).at[40].set(1e6)  # member 40 needs many more iterations
    want_i, _ = _newton_reference(np.asarray(a), 1e-13, np.asarray(x0))
    slow, fast = int(want_i[40]), int(want_i[0])
    assert slow > fast + 10
    # The body's callback runs once per pass of a batched loop (once for the whole batch).
    assert _loop_passes(a, x0, 0) == slow
    assert _loop_passes(a, x0, 16) == slow + 3 * fast
