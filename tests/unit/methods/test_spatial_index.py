"""The spatial index of a long map (``BlockIndex``: a bounding box per block of slots, kept as the
map is written) lets the local window's search visit only the blocks near the particle, and it
finds exactly what a search of every slot finds.

Independent truth: numpy's brute force over the whole map. The maps are written as the filter
writes them (landmarks added block after block along a drive with revisits, some moved by
updates, some removed, freed slots taken again by new landmarks elsewhere), the index kept only
through those writes, and searched from random positions; then a filter run on a simulated city
equals the same run without an index, and its index holds every particle's landmarks.
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nanoslam_jax import float64
from nanoslam_jax.methods import LandmarkMap, gather_window
from nanoslam_jax.methods._state import SEARCH_BLOCK, SEARCH_FROM, BlockIndex, init_state, keeps_index
from nanoslam_jax.models import Circle, LineSegment, RangeBearing

WINDOW = 48


def _brute(active, mean, pos, radius, window):
    d2 = np.square(mean[:, 0] - pos[0]) + np.square(mean[:, 1] - pos[1])
    near = np.flatnonzero(active & (d2 < radius * radius))
    idx = np.full(window, len(active))
    idx[: min(window, len(near))] = near[:window]
    return idx, len(near)


def _written(seed: int, slots: int, used: int, moves: float, removals: float, reuse: float):
    """A map and its index after the filter's kinds of writes, the index kept only by them."""
    rng = np.random.default_rng(seed)
    s = np.arange(slots) * 2.5  # along a drive: slot order follows the route, with revisits
    s = np.where(rng.random(slots) < 0.1, rng.uniform(0, s.max() + 1, slots), s)
    mean = np.c_[s + rng.normal(0, 4, slots), rng.normal(0, 8, slots)]
    active = np.arange(slots) < used
    with float64():
        index = BlockIndex.empty(slots)
        for start in range(0, used, 37):  # added a scan's worth at a time
            rows = jnp.arange(start, min(start + 37, used))
            index = index.widen(rows, jnp.asarray(mean[rows]))
        moved = np.flatnonzero(active & (rng.random(slots) < moves))  # updates move landmarks
        mean[moved] += rng.normal(0, 3, (len(moved), 2))
        index = index.widen(jnp.asarray(moved), jnp.asarray(mean[moved]))
        active &= rng.random(slots) >= removals  # management removes, the index is not told
        again = np.flatnonzero(~active[:used] & (rng.random(used) < reuse))  # freed slots reused
        mean[again] = rng.uniform(mean.min(0), mean.max(0), (len(again), 2))
        active[again] = True
        index = index.widen(jnp.asarray(again), jnp.asarray(mean[again]))
    return active, mean, index


@functools.cache
def _search(slots: int, window: int):
    with float64():
        return jax.jit(jax.vmap(lambda lm, ix, p, r: gather_window(lm, p, window, r, slots, index=ix)))


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    slots=st.sampled_from((1024, 4096)),
    used_frac=st.floats(0.0, 1.0),
    moves=st.floats(0.0, 0.5),
    removals=st.floats(0.0, 0.5),
    reuse=st.floats(0.0, 1.0),
    radius=st.floats(1.0, 300.0),
)
def test_the_indexed_search_finds_what_a_whole_map_search_finds(seed, slots, used_frac, moves, removals, reuse, radius):
    members = 3  # particles of different maps in one vmapped call
    maps = [_written(seed + i, slots, int(used_frac * slots), moves, removals, reuse) for i in range(members)]
    rng = np.random.default_rng(seed)
    lo, hi = maps[0][1].min(0) - 50, maps[0][1].max(0) + 50
    pos = rng.uniform(lo, hi, (members, 2))
    for i, (active, mean, _) in enumerate(maps[1:], 1):
        # Just inside the radius, above a block's northernmost landmark: only that landmark of
        # the block is near, and the block's box comes within the radius by a hair.
        if active.any():
            block = rng.choice(np.flatnonzero(active)) // SEARCH_BLOCK
            rows = block * SEARCH_BLOCK + np.flatnonzero(active[block * SEARCH_BLOCK :][:SEARCH_BLOCK])
            j = rows[np.argmax(mean[rows, 1])]
            pos[i] = mean[j] + [0.0, radius * rng.uniform(0.99, 0.9999)]
    with float64():
        lm = LandmarkMap.empty(slots, (members,))
        lm = lm._replace(
            active=jnp.asarray(np.stack([a for a, _, _ in maps])), mean=jnp.asarray(np.stack([m for _, m, _ in maps]))
        )
        index = jax.tree.map(lambda *a: jnp.stack(a), *[ix for _, _, ix in maps])
        search = _search(slots, WINDOW)
        local, idx, overflow = search(lm, index, jnp.asarray(pos), jnp.full(members, radius))
    for i, (active, mean, _) in enumerate(maps):
        want_idx, want_n = _brute(active, mean, pos[i], radius, WINDOW)
        np.testing.assert_array_equal(np.asarray(idx[i]), want_idx)
        assert int(overflow[i]) == max(want_n - WINDOW, 0)
        inside = want_idx < slots
        np.testing.assert_array_equal(np.asarray(local.mean[i])[inside], mean[want_idx[inside]])
        assert np.all(np.asarray(local.active[i]) == inside)


def test_the_boxes_kept_by_writes_are_the_exact_boxes_until_a_landmark_moves_or_goes():
    """Landmarks added scan by scan along a drive: the widened boxes are exactly the boxes of each
    block's landmarks (numpy's min and max), a search near one end finds the window a whole search
    finds, and a moved landmark widens only its own block's box."""
    slots, rng = 4096, np.random.default_rng(5)
    xy = np.c_[np.arange(slots) * 2.0, rng.normal(0, 8, slots)]  # 64 slots: 128 m of road per block
    with float64():
        index = BlockIndex.empty(slots)
        for start in range(0, slots, 50):
            rows = np.arange(start, min(start + 50, slots))
            index = index.widen(jnp.asarray(rows), jnp.asarray(xy[rows]))
        blocks = xy.reshape(-1, SEARCH_BLOCK, 2)
        np.testing.assert_array_equal(np.asarray(index.lo), blocks.min(1))
        np.testing.assert_array_equal(np.asarray(index.hi), blocks.max(1))
        lm = LandmarkMap.empty(slots)._replace(mean=jnp.asarray(xy), active=jnp.ones(slots, bool))
        assert int(jnp.sum(index.near(jnp.array([10.0, 0.0]), jnp.asarray(300.0**2), slots // SEARCH_BLOCK))) == 3
        _, idx, overflow = gather_window(lm, jnp.array([10.0, 0.0]), WINDOW, jnp.asarray(300.0), index=index)
        want_idx, want_n = _brute(np.ones(slots, bool), xy, (10.0, 0.0), 300.0, WINDOW)
        np.testing.assert_array_equal(np.asarray(idx), want_idx)
        assert int(overflow) == want_n - WINDOW
        moved = index.widen(jnp.array([70]), jnp.array([[140.0, 500.0]]))
    assert float(moved.hi[1, 1]) == 500.0
    np.testing.assert_array_equal(np.delete(np.asarray(moved.hi), 1, 0), np.delete(np.asarray(index.hi), 1, 0))


def test_only_long_maps_of_points_keep_an_index():
    assert keeps_index(1024, RangeBearing()) and keeps_index(16384, Circle())  # a circle's centre
    assert not keeps_index(16384, LineSegment())  # a line's distance is not to a point
    assert not keeps_index(512, RangeBearing())  # short maps: the whole search is as cheap
    assert not keeps_index(1000, RangeBearing())  # not a whole number of blocks


@pytest.mark.slow
def test_a_city_run_with_the_index_equals_the_run_without():
    """NANO-SLAM on a 3 km simulated city with 8 particles and 4096 slots: every output and the
    final maps equal the run whose state keeps no index (the whole-map search), and the final
    index holds every active landmark of every particle in its block's box."""
    from nanoslam_jax.app.config import load_config
    from nanoslam_jax.app.experiment import load_log
    from nanoslam_jax.app.filters import settings_from_config
    from nanoslam_jax.methods import filter_scan

    cfg = load_config(
        None,
        ["data.kind=city", "city.distance_m=3000", "filter.n_particles=8", "filter.capacity=4096"],
    )
    with float64():
        log = load_log(cfg)
        static, params = settings_from_config(cfg, log.segments.z.shape[1], log.segments.time.shape[0])
        assert keeps_index(static.capacity, params.measurement)
        fresh = init_state(static, params, jax.random.PRNGKey(3))
        run = jax.jit(lambda s: filter_scan(static, params, log.segments, None, s), donate_argnums=())
        with_index, out_a = run(fresh)
        without, out_b = run(fresh._replace(particles=fresh.particles._replace(map_index=None)))
        assert int(with_index.slots) > SEARCH_FROM // 2  # searched in a bucket of 1024 slots or more: indexed
    for a, b in zip(jax.tree.leaves(out_a), jax.tree.leaves(out_b)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    for a, b in zip(jax.tree.leaves(with_index.particles.landmarks), jax.tree.leaves(without.particles.landmarks)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    lm, ix = with_index.particles.landmarks, with_index.particles.map_index
    block = np.arange(static.capacity) // SEARCH_BLOCK
    xy = np.asarray(lm.mean)[..., :2]
    held = np.all((np.asarray(ix.lo)[:, block] <= xy) & (xy <= np.asarray(ix.hi)[:, block]), axis=-1)
    assert np.all(held[np.asarray(lm.active)])
