"""Sweep files and their plan (nanoslam_jax.app.sweep): expansion, sampling, validation, groups
and batches, identity, and the scoring of a failed run, without running a sweep.

Independent truths: the Cartesian product and the documented sampler for the expansion; the
batch arithmetic for the groups; a path with NaNs for a failed run.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import yaml

from nanoslam_jax.app.config import ConfigError
from nanoslam_jax.app.sweep import _batch, _plan
from nanoslam_jax.app.sweep import (
    expand,
    load_log_data,
    load_sweep,
    make_tasks,
    plan_groups,
    sample_random,
)
from nanoslam_jax.app.sweep._batch import BatchOutput, BatchTask, _score, log_key
from tests.helpers.paths import REPO_ROOT
from tests.helpers.sweeps import BASE, GRID, MAIN, spec_of
from tests.helpers.internals import filter_params


def test_grid_expansion_is_the_cartesian_product_with_seeds():
    grid = {"filter.gate": [3.0, 4.0, 5.0], "filter.new_landmark": [14.0, 20.0], "noise.sigma_r": [0.5, 1.0]}
    spec = spec_of({"base": {**BASE, "seed": 5}, "grid": grid, "seeds": 3, "shapes": {"filter.n_particles": [4, 8]}})
    points, runs, skipped = expand(spec)
    assert not skipped
    assert len(points) == 2 * 3 * 2 * 2 and len(runs) == len(points) * 3
    expected = [(n, *c) for n in (4, 8) for c in itertools.product(*grid.values())]
    got = [
        (
            p.values["filter.n_particles"],
            p.values["filter.gate"],
            p.values["filter.new_landmark"],
            p.values["noise.sigma_r"],
        )
        for p in points
    ]
    assert got == expected  # shapes outermost, then the grid in file order, last key fastest
    assert [p.config_id for p in points] == [f"c{i:04d}" for i in range(len(points))]
    # Seeds: base seed 5 and the next two, configuration-major; ids are unique.
    assert [r.seed for r in runs[:6]] == [5, 6, 7, 5, 6, 7]
    assert len({r.run_id for r in runs}) == len(runs) and runs[4].run_id == "c0001-s6"
    # Every configuration is the base with the swept values (and only those) changed.
    cfg = points[7].config
    assert (cfg.filter.n_particles, cfg.filter.gate, cfg.filter.new_landmark, cfg.noise.sigma_r) == expected[7]
    assert cfg.noise.sigma_v == 0.3 and cfg.filter.capacity == 96 and cfg.seed == 5
    # An explicit list of seeds is kept as given.
    assert spec_of({"base": BASE, "grid": grid, "seeds": [9, 2]}).seeds == (9, 2)


def test_random_samples_are_reproducible_within_bounds_and_combined_as_documented():
    params = {
        "noise.sigma_r": {"low": 0.1, "high": 10.0, "log": True},
        "filter.p0": {"low": 0.01, "high": 0.2},
        "filter.resample_threshold": {"choice": [0.25, 0.5, 0.75]},
    }
    rand = {"n": 4000, "seed": 11, "params": params}
    spec = spec_of({"base": BASE, "random": rand})
    samples = sample_random(spec.random)
    assert len(samples) == 4000
    assert samples == sample_random(spec_of({"base": BASE, "random": rand}).random)
    assert samples != sample_random(spec_of({"base": BASE, "random": {**rand, "seed": 12}}).random)
    r = np.array([s["noise.sigma_r"] for s in samples])
    p0 = np.array([s["filter.p0"] for s in samples])
    thr = [s["filter.resample_threshold"] for s in samples]
    assert r.min() >= 0.1 and r.max() <= 10.0 and p0.min() >= 0.01 and p0.max() <= 0.2
    assert set(thr) == {0.25, 0.5, 0.75} and abs(thr.count(0.5) / 4000 - 1 / 3) < 0.03
    # Log-uniform: log10 uniform on [-1, 1] (median near 1, a quarter below 10^-0.5); uniform p0.
    assert abs(np.median(np.log10(r))) < 0.06 and abs(np.mean(r < 10**-0.5) - 0.25) < 0.03
    assert abs(np.mean(p0) - 0.105) < 0.004
    # The documented sampler: numpy default_rng(seed), keys in file order for each sample in turn.
    rng = np.random.default_rng(11)
    first = {
        "noise.sigma_r": math.exp(rng.uniform(math.log(0.1), math.log(10.0))),
        "filter.p0": rng.uniform(0.01, 0.2),
        "filter.resample_threshold": [0.25, 0.5, 0.75][int(rng.integers(3))],
    }
    assert samples[0] == first
    # The configurations carry the samples (validated, in sample order).
    points, runs, _ = expand(spec_of({"base": BASE, "random": {**rand, "n": 20}}))
    assert len(points) == len(runs) == 20
    assert [p.values for p in points] == samples[:20]
    assert points[5].config.noise.sigma_r == samples[5]["noise.sigma_r"]
    # combine: product crosses every sample with every grid point; union puts them side by side.
    small = {"n": 3, "seed": 0, "params": {"noise.sigma_r": {"low": 0.2, "high": 1.0}}}
    prod, _, _ = expand(spec_of({"base": BASE, "grid": GRID, "random": {**small, "combine": "product"}}))
    union, _, _ = expand(spec_of({"base": BASE, "grid": GRID, "random": {**small, "combine": "union"}}))
    assert len(prod) == 4 * 3 and len(union) == 4 + 3
    assert [p.values["noise.sigma_r"] for p in union[:4]] == [0.5] * 4  # grid points keep the base value
    assert {p.values["noise.sigma_r"] for p in prod} == {p.values["noise.sigma_r"] for p in union[4:]}
    assert [(p.values["filter.gate"], p.values["filter.new_landmark"]) for p in prod[::3]] == list(
        itertools.product(*GRID.values())
    )


def test_invalid_sweeps_name_the_file_and_key(tmp_path):
    def err(raw):
        with pytest.raises(ConfigError) as e:
            expand(spec_of(raw))
        return str(e.value)

    assert "test-sweep.yaml" in (m := err({"base": BASE, "grid": {"filter.gatee": [1.0]}})) and "filter.gatee" in m
    assert "shapes" in err({"base": BASE, "grid": {"filter.n_particles": [4, 8]}})
    assert "grid" in err({"base": BASE, "shapes": {"filter.gate": [4.0, 5.0]}})
    assert "random.params.noise.sigma_r" in err(
        {"base": BASE, "random": {"n": 2, "params": {"noise.sigma_r": {"low": 2.0, "high": 1.0}}}}
    )
    assert "seeds" in err({"base": BASE, "seeds": 0})
    assert "'seed' cannot be swept" in err({"base": BASE, "grid": {"seed": [1, 2]}})
    assert "unknown key 'grdi'" in err({"base": BASE, "grdi": {}})
    # A value the config rejects names the configuration and the key...
    m = err({"base": BASE, "grid": {"filter.gate": [-1.0]}})
    assert "filter.gate=-1.0" in m and "key 'filter.gate'" in m
    # ... and with skip_invalid such configurations are dropped and reported.
    spec = spec_of(
        {
            "base": BASE,
            "grid": {"filter.gate": [5.0, 15.0], "filter.new_landmark": [10.0, 20.0]},
            "run": {"skip_invalid": True},
        }
    )
    points, _, skipped = expand(spec)
    assert len(points) == 3 and len(skipped) == 1 and "filter.new_landmark" in skipped[0][1]
    # A sweep file: the base is relative to it; errors name the file.
    (tmp_path / "base.yaml").write_text(yaml.safe_dump(BASE))
    (tmp_path / "s.yaml").write_text(yaml.safe_dump({"base": "base.yaml", "grid": {"noise.sigma_r": [0.5, 1.0]}}))
    assert load_sweep(tmp_path / "s.yaml").base["filter"]["capacity"] == 96
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump({"base": "missing.yaml"}))
    with pytest.raises(ConfigError, match=r"bad\.yaml.*'base'"):
        load_sweep(tmp_path / "bad.yaml")


@pytest.mark.slow
def test_shipped_sweep_files_load_and_expand():
    """Every sweep file in configs/ (the example and the tuning sweeps behind the shipped
    configs) loads, validates and expands to its stated configurations and seeds."""
    root = REPO_ROOT / "configs"
    files = [root / "sweep_example.yaml", *sorted((root / "sweeps").glob("*.yaml"))]
    assert len(files) >= 5
    for f in files:
        spec = load_sweep(f)
        points, runs, _ = expand(spec)
        assert len(runs) == len(points) * len(spec.seeds) > 0, f.name


@pytest.mark.slow
def test_groups_and_batches(monkeypatch):
    """Runs are grouped by static settings; batches are as equal as possible, and fixed per group."""
    grid = {"noise.sigma_r": [0.3 + 0.01 * i for i in range(13)]}
    spec = spec_of({"base": BASE, "grid": grid, "seeds": 5, "shapes": {"filter.n_particles": [4, 8]}})
    _, runs, _ = expand(spec)
    log = load_log_data(runs[0].point.config)
    logs = {log_key(runs[0].point.config): (0, log)}
    groups = plan_groups(spec, runs, logs, batch=64)
    assert [(g.label, g.static.n_particles, len(g.runs)) for g in groups] == [("g0", 4, 65), ("g1", 8, 65)]
    assert all(r.point.config.filter.n_particles == g.static.n_particles for g in groups for r in g.runs)
    assert [g.batch for g in groups] == [33, 33]  # 2 batches of 33 (one padding run), not 64 + 1
    assert plan_groups(spec, runs, logs, batch=64, devices=2)[0].batch == 34
    assert _plan.resolve_vectorize("auto") == "vmap" and _plan.resolve_vectorize("map") == "map"
    assert plan_groups(spec, runs, logs, batch=16, split=2)[0].batch == 13  # 5 batches of 13, not 16 x 4 + 1
    assert plan_groups(spec, runs, logs, batch=100, split=2)[0].batch == 33
    tasks = make_tasks(spec, groups, logs, done={r.run_id for r in runs[:40]})
    assert [t.n_real for t in tasks] == [25, 33, 32] and all(t.batch == 33 for t in tasks)
    # filter.row_buckets: auto is off for this little work: 33 runs of 4 or 8 particles over the
    # short log's segments in 2 batches...
    n_seg = int(log.segments.time.shape[0])
    assert 8 * 33 * n_seg * 2 < filter_params.ROW_BUCKETS_WORK
    assert {t.static.row_buckets for t in tasks} == {()}
    # ...and with work enough it counts the particles one call carries per device: 4 x 33 and
    # 8 x 33 vmapped (>= 64), 4 x 16 per device of two, but one run at a time under lax.map.
    monkeypatch.setattr(filter_params, "ROW_BUCKETS_WORK", 4 * 33 * n_seg * 2)
    tasks = make_tasks(spec, groups, logs, done=set())
    assert [t.static.row_buckets for t in tasks] == [(4, 8)] * 4
    monkeypatch.setattr(filter_params, "ROW_BUCKETS_WORK", 4 * 33 * n_seg * 2 + 1)  # g0's 4 particles: not enough
    assert [t.static.row_buckets for t in make_tasks(spec, groups, logs, done=set())] == [(), (), (4, 8), (4, 8)]
    monkeypatch.setattr(filter_params, "ROW_BUCKETS_WORK", 1)
    tasks = make_tasks(spec, groups, logs, done={r.run_id for r in runs[:40]})
    assert {t.static.row_buckets for t in make_tasks(spec, groups, logs, done=set(), devices=2)} == {(4, 8)}
    assert {t.static.row_buckets for t in make_tasks(spec, groups, logs, done=set(), vectorize="map")} == {()}
    assert all(t.static.devices == 1 for t in tasks)
    assert tasks[0].run_ids[0] == runs[40].run_id and tasks[0].seeds.shape == (33,)
    # Padding repeats the first run of the batch.
    assert tasks[2].seeds[32] == tasks[2].seeds[0] and tasks[2].params.sigma_r[32] == tasks[2].params.sigma_r[0]


# --------------------------------------------------------------------------- running


def test_sweep_identity_ignores_the_name_and_sees_every_setting():
    """A sweep resumes under another name (a label), never with another setting or seed list."""
    from nanoslam_jax.app.sweep import spec_identity, stored_identity

    ident = spec_identity(spec_of(MAIN))
    assert spec_identity(spec_of(MAIN, base={**BASE, "name": "renamed"})) == ident
    assert spec_identity(spec_of(MAIN, base={**BASE, "noise": {**BASE["noise"], "sigma_r": 0.6}})) != ident
    assert spec_identity(spec_of(MAIN, seeds=3)) != ident
    # A directory written while the name was part of the identity resumes too.
    old = {**ident, "base": {**ident["base"], "name": "old-name"}}
    assert stored_identity(old) == ident and stored_identity(None) == {}


def test_a_non_finite_estimate_fails_the_run():
    from nanoslam_jax.methods import Static

    n = 6
    pose = np.zeros((1, n, 3))
    pose[0, :, 0] = np.linspace(0, 5, n)
    pose[0, 4:, 1] = np.nan
    z = np.zeros((1, n))
    out = BatchOutput(
        pose,
        pose,
        z + 4,
        z,
        z + 1,
        z,
        z,
        z,
        z.astype(bool),
        np.array([0]),
        np.array([1]),
        np.zeros((1, 8, 2)),
        np.zeros((1, 8), bool),
        np.zeros((1, 8), bool),
    )
    t = np.arange(n) * 0.5
    gps = np.c_[t, np.linspace(0, 5, n), np.zeros(n)]
    from nanoslam_jax.data import Segments

    seg = Segments(
        t,
        np.zeros((n, 1)),
        np.zeros((n, 1, 2)),
        np.zeros((n, 1), bool),
        np.zeros((n, 2, 2)),
        np.zeros((n, 2), bool),
        np.zeros((n, 2)),
        np.ones(n, bool),
        np.full((n, 2), -1),
    )
    log = _batch.LogData(seg, gps, "slam", None, "test")
    from nanoslam_jax.app.config import MetricsConfig

    opts = (MetricsConfig(gps_rotation_deg=0.0, jump_speed=8.0, map_radius=1.0),)
    task = BatchTask("g0", Static(), 0, None, np.array([0]), 1, opts, True, ("c0-s0",))
    r = _score(0, out, log, task)
    assert r["status"] == "failed" and r["reason"] == "non-finite estimate from segment 4 (t = 2.00 s)"
    pose[0, 4:, 1] = 0.0
    r = _score(0, out, log, task)
    assert r["status"] == "ok" and r["rmse_fixed"] == pytest.approx(0.0, abs=1e-12)
