"""The local window's search over a long map (``first_true_blocked``, used by ``gather_window``
from 1024 slots) finds exactly what a search of every slot finds: the lowest ``window`` active
landmarks within the radius, and how many there are. Independent truth: numpy's brute force over
the whole map, on random maps (landmarks scattered, or laid along a drive as a city's are, so that
near ones share a few blocks of slots) and random positions."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nanoslam_jax import float64
from nanoslam_jax.methods import LandmarkMap, gather_window
from nanoslam_jax.methods.maps._landmarks import SEARCH_FROM, first_true, first_true_blocked, free_slots

SLOTS = (1024, 2048)
WINDOW = 64


def _brute(active, mean, pos, radius, window):
    d = np.hypot(mean[:, 0] - pos[0], mean[:, 1] - pos[1])
    near = np.flatnonzero(active & (d * d < radius * radius))
    idx = np.full(window, len(active))
    idx[: min(window, len(near))] = near[:window]
    return idx, len(near)


@functools.cache
def _search(slots: int, window: int):
    with float64():
        return jax.jit(jax.vmap(lambda lm, p, r: gather_window(lm, p, window, r, slots)))


def _map(draw_seed: int, slots: int, used: int, layout: str, fill: float) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(draw_seed)
    if layout == "drive":  # created along a route: slot order follows the path, with revisits
        s = np.arange(slots) * 3.0
        s = np.where(rng.random(slots) < 0.2, rng.uniform(0, s.max() + 1, slots), s)
        mean = np.c_[s + rng.normal(0, 4, slots), rng.normal(0, 8, slots)]
    else:
        mean = rng.uniform(-300, 300, (slots, 2))
    active = (np.arange(slots) < used) & (rng.random(slots) < fill)
    return active, mean


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    slots=st.sampled_from(SLOTS),
    used_frac=st.floats(0.0, 1.0),
    layout=st.sampled_from(["drive", "scattered"]),
    fill=st.floats(0.05, 1.0),
    radius=st.floats(1.0, 200.0),
)
def test_the_window_search_finds_what_a_whole_map_search_finds(seed, slots, used_frac, layout, fill, radius):
    assert slots >= SEARCH_FROM  # the blocked search is the one under test
    members = 3  # particles of different maps in one vmapped call: each gets its own window
    maps = [_map(seed + i, slots, int(used_frac * slots), layout, fill) for i in range(members)]
    rng = np.random.default_rng(seed)
    span = max(float(np.max(np.abs(maps[0][1]))), 1.0)
    pos = rng.uniform(-span, span, (members, 2))
    with float64():
        lm = LandmarkMap.empty(slots, (members,))
        lm = lm._replace(
            active=jnp.asarray(np.stack([a for a, _ in maps])), mean=jnp.asarray(np.stack([m for _, m in maps]))
        )
        _, idx, overflow = _search(slots, WINDOW)(lm, jnp.asarray(pos), jnp.full(members, radius))
    for i, (active, mean) in enumerate(maps):
        want_idx, want_n = _brute(active, mean, pos[i], radius, WINDOW)
        got = np.asarray(idx[i])
        got = np.where(got < slots, got, slots)
        np.testing.assert_array_equal(got, want_idx)
        assert int(overflow[i]) == max(want_n - WINDOW, 0)


@pytest.mark.parametrize("n", [64, 128, 1024, 4096])
@pytest.mark.parametrize("size", [1, 5, 64, 200])
def test_the_blocked_first_true_equals_nonzero(n, size):
    rng = np.random.default_rng(n + size)
    masks = [np.zeros(n, bool), np.ones(n, bool)]
    for p in (0.001, 0.01, 0.2):
        masks.append(rng.random(n) < p)
    clustered = np.zeros(n, bool)
    clustered[rng.integers(0, n - 40) :][:40] = True
    masks.append(clustered)
    batch = jnp.asarray(np.stack(masks))
    got_idx, got_n = jax.vmap(lambda m: first_true_blocked(m, size))(batch)
    plain_idx, plain_n = jax.vmap(lambda m: first_true(m, size))(batch)
    with float64():  # the same types as the plain search, in the filter's precision too
        blocked = jax.eval_shape(lambda m: first_true_blocked(m, size), batch[0])
        plain = jax.eval_shape(lambda m: first_true(m, size), batch[0])
    assert blocked == plain
    for i, m in enumerate(masks):
        want = np.asarray(jnp.nonzero(jnp.asarray(m), size=size, fill_value=n)[0])
        np.testing.assert_array_equal(np.asarray(got_idx[i]), want)
        np.testing.assert_array_equal(np.asarray(plain_idx[i]), want)
        assert int(got_n[i]) == int(plain_n[i]) == int(m.sum())


@pytest.mark.parametrize("slots", [700, 1038, 2062, 4096])
def test_the_free_slots_of_a_long_prefix_are_the_first_free_ones(slots):
    """``free_slots`` over a prefix (the slot bucket plus one slot per detection; blocked from
    1024 slots): the first ``k`` free slots below the prefix's end in order, ``capacity`` past
    them, whatever the holes management left; numpy's brute force is the truth."""
    capacity, k = 4096, 14
    rng = np.random.default_rng(slots)
    masks = []
    for holes in (0.0, 0.002, 0.05, 0.5):
        active = np.zeros(capacity, bool)
        active[: slots - 10] = rng.random(slots - 10) >= holes
        masks.append(active)
    full = np.zeros(capacity, bool)
    full[:slots] = True  # no free slot below the prefix's end
    masks.append(full)
    got = jax.vmap(lambda a: free_slots(a, k, slots))(jnp.asarray(np.stack(masks)))
    for i, active in enumerate(masks):
        want = np.full(k, capacity)
        free = np.flatnonzero(~active[:slots])[:k]
        want[: len(free)] = free
        np.testing.assert_array_equal(np.asarray(got[i]), want)
