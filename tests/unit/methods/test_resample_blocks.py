"""Resampling long maps copies only the blocks whose version differs from the ancestor's, and
gives exactly the maps of copying every slot in use.

Independent truth: numpy's copy of every block below the bound from each particle's ancestor, on
stacked maps whose blocks hold what their versions say (any two blocks with one version hold the
same slots); then filter runs with block versions equal the runs that copy the slots in use.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nanoslam_jax import float64
from nanoslam_jax.methods._state import SEARCH_BLOCK, SEARCH_FROM, init_state, keeps_versions
from nanoslam_jax.methods.particle._resample import COPY_CHUNK, mark_written, take_changed_blocks


def _versioned_maps(rng, n: int, blocks: int, kinds: int):
    """Stacked maps of ``n`` particles whose block ``b`` at version ``v`` holds what ``(b, v)`` says."""
    version = rng.integers(0, kinds, (n, blocks)).astype(np.int32)
    content = rng.normal(size=(blocks, kinds, SEARCH_BLOCK, 2))
    flags = rng.random((blocks, kinds, SEARCH_BLOCK)) < 0.5
    b = np.arange(blocks)[None, :]
    mean = content[b, version].reshape(n, blocks * SEARCH_BLOCK, 2)
    active = flags[b, version].reshape(n, blocks * SEARCH_BLOCK)
    return version, {"mean": mean, "active": active}


def _copied(maps, anc, used):
    """Every particle's ancestor's blocks that hold a slot below ``used`` (``take_prefix_if``
    copies whole blocks; the slots past ``used`` are free in every map)."""
    upto = -(-used // SEARCH_BLOCK) * SEARCH_BLOCK
    want = {k: v.copy() for k, v in maps.items()}
    for k in want:
        want[k][:, :upto] = maps[k][anc, :upto]
    return want


@settings(max_examples=20, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    n=st.integers(1, 12),
    blocks=st.integers(1, 24),
    kinds=st.integers(1, 4),
    used_frac=st.floats(0.0, 1.0),
    flag=st.booleans(),
)
def test_the_changed_blocks_give_the_maps_of_a_whole_copy(seed, n, blocks, kinds, used_frac, flag):
    rng = np.random.default_rng(seed)
    version, maps = _versioned_maps(rng, n, blocks, kinds)
    anc = rng.integers(0, n, n).astype(np.int32)
    if rng.random() < 0.5:
        anc = np.sort(anc)  # systematic resampling's order
    used = int(used_frac * blocks * SEARCH_BLOCK)
    with float64():
        got, got_version = take_changed_blocks(
            jnp.asarray(flag),
            jnp.asarray(anc),
            {k: jnp.asarray(v) for k, v in maps.items()},
            jnp.asarray(version),
            jnp.asarray(used, jnp.int32),
        )
    want = _copied(maps, anc, used) if flag else maps
    for k in maps:
        np.testing.assert_array_equal(np.asarray(got[k]), want[k])
    below = np.arange(blocks) < -(-used // SEARCH_BLOCK)
    want_version = np.where(below & flag, version[anc], version)
    np.testing.assert_array_equal(np.asarray(got_version), want_version)


@pytest.mark.parametrize("changed", [0, 1, COPY_CHUNK + 1, 12, 30])
@pytest.mark.parametrize(
    "anc",
    [
        [0, 0, 2, 2, 2, 5],  # copies from below
        [1, 1, 3, 3, 5, 5],  # from above
        [0, 2, 2, 2, 3, 4],  # both, chained: 1 takes 2, which takes 3, which takes 4
        [3, 0, 0, 5, 1, 1],  # out of order: the slots in use are copied whole
    ],
)
def test_any_number_of_changed_blocks_and_any_ancestors_give_the_whole_copy(changed, anc):
    """``changed`` blocks per particle hold their own version: none, one pass's worth, several
    passes' (:data:`COPY_CHUNK` blocks per particle a pass), nearly every block."""
    n, blocks = 6, 32
    rng = np.random.default_rng(changed)
    version = np.zeros((n, blocks), np.int32)
    for i in range(n):
        version[i, rng.choice(blocks, changed, replace=False)] = i + 1
    content = rng.normal(size=(n + 1, blocks, SEARCH_BLOCK, 2))
    mean = content[version, np.arange(blocks)[None, :]].reshape(n, -1, 2)
    anc = np.asarray(anc, np.int32)
    used = blocks * SEARCH_BLOCK - 5
    with float64():
        got, _ = take_changed_blocks(
            jnp.asarray(True), jnp.asarray(anc), jnp.asarray(mean), jnp.asarray(version), jnp.asarray(used)
        )
    np.testing.assert_array_equal(np.asarray(got), _copied({"m": mean}, anc, used)["m"])


def test_a_batch_of_runs_takes_each_members_own_copy():
    """Under ``vmap`` (a sweep's batch) each member copies from its own ancestors only if it resampled."""
    rng = np.random.default_rng(4)
    n, blocks, used = 5, 8, 8 * SEARCH_BLOCK - 10
    members = [_versioned_maps(rng, n, blocks, 3) for _ in range(3)]
    anc = rng.integers(0, n, (3, n)).astype(np.int32)
    flag = np.array([True, False, True])
    with float64():
        got, _ = jax.vmap(take_changed_blocks, (0, 0, 0, 0, None))(
            jnp.asarray(flag),
            jnp.asarray(anc),
            {"mean": jnp.asarray(np.stack([m["mean"] for _, m in members]))},
            jnp.asarray(np.stack([v for v, _ in members])),
            jnp.asarray(used),
        )
    for j, (_, maps) in enumerate(members):
        want = _copied(maps, anc[j], used) if flag[j] else maps
        np.testing.assert_array_equal(np.asarray(got["mean"][j]), want["mean"])


def test_a_written_block_takes_a_version_no_other_particle_holds():
    n, blocks = 4, 6
    version = jnp.asarray(np.random.default_rng(0).integers(0, 3, (n, blocks)), jnp.int32)
    cap = blocks * SEARCH_BLOCK
    written = jnp.asarray([[0, 1, cap, cap], [cap, cap, cap, cap], [5 * SEARCH_BLOCK + 3, cap, 70, 64], [cap + 9] * 4])
    new = np.asarray(mark_written(version, written, jnp.asarray(2)))
    touched = {(0, 0), (2, 5), (2, 1)}
    for i in range(n):
        for b in range(blocks):
            if (i, b) in touched:
                assert new[i, b] == 2 * n + i + 1
                assert new[i, b] not in np.delete(new, i, axis=0)  # held by no other particle
            else:
                assert new[i, b] == version[i, b]


def test_only_long_maps_on_one_device_keep_versions():
    assert keeps_versions(SEARCH_FROM, 1) and keeps_versions(16384, 1)
    assert not keeps_versions(512, 1)  # short maps: the slots in use are few
    assert not keeps_versions(16384, 2)  # split over devices: resampling gathers across them
    assert not keeps_versions(SEARCH_FROM + 1, 1)  # not a whole number of blocks


def _runs_with_and_without_versions(overrides: list[str]):
    from nanoslam_jax.app.config import load_config
    from nanoslam_jax.app.experiment import load_log
    from nanoslam_jax.app.filters import settings_from_config
    from nanoslam_jax.methods import filter_scan

    cfg = load_config(None, overrides)
    with float64():
        log = load_log(cfg)
        static, params = settings_from_config(cfg, log.segments.z.shape[1], log.segments.time.shape[0])
        fresh = init_state(static, params, jax.random.PRNGKey(3))
        assert fresh.particles.map_version is not None
        run = jax.jit(lambda s: filter_scan(static, params, log.segments, None, s))
        with_versions = run(fresh)
        copies = run(fresh._replace(particles=fresh.particles._replace(map_version=None)))
    return with_versions, copies


def _assert_equal_runs(a, b):
    (state_a, out_a), (state_b, out_b) = a, b
    for x, y in zip(jax.tree.leaves(out_a), jax.tree.leaves(out_b)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    for x, y in zip(jax.tree.leaves(state_a.particles.landmarks), jax.tree.leaves(state_b.particles.landmarks)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


@pytest.mark.slow
def test_a_run_with_block_versions_equals_the_run_that_copies():
    """The embedded default's park log, 90 s, 10 particles, 1024 slots: every output and the
    final maps equal the run whose state keeps no versions (resampling copies the slots in use)."""
    a, b = _runs_with_and_without_versions(["data.t_end=90", "filter.n_particles=10", "filter.capacity=1024"])
    assert int(a[0].resample_count) > 10 and int(a[0].slots) > SEARCH_BLOCK  # resampled, over two blocks
    _assert_equal_runs(a, b)


@pytest.mark.slow
def test_a_city_run_with_block_versions_equals_the_run_that_copies():
    """A 3 km drive through the simulated city, 8 particles, 4096 slots, with landmark management."""
    a, b = _runs_with_and_without_versions(
        ["data.kind=city", "city.distance_m=3000", "filter.n_particles=8", "filter.capacity=4096"]
    )
    assert int(a[0].resample_count) > 100 and int(a[0].slots) > SEARCH_FROM // 2
    _assert_equal_runs(a, b)
