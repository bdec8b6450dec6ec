"""Batch hyperparameter sweeps (nanoslam_jax.app.sweep).

Independent truths: the Cartesian product and the documented sampler for the expansion; a trace
counter inside the compiled function for "one compilation per shape group"; ``run_filter`` run
alone for the vmapped batch; an uninterrupted sweep for a resumed one; a landmark capacity that
cannot hold the map for a failed run.

Every sweep here uses one static configuration (FastSLAM 1.0, 4 particles, capacity 96, window
24, two DR pieces per segment, on a 20 s simulated log) and one batch size (4), so the module
compiles the vmapped batch program once, plus ``run_filter``'s program and the ``lax.map`` batch
program once each; the worker-process and Ray tests load the program from the persistent
compilation cache instead of compiling it.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import numpy as np
import pytest
import yaml

from nanoslam_jax import __version__, enable_compile_cache
from nanoslam_jax.app._devices import SWEEP_DEVICES_PER_CORE
from nanoslam_jax.app.config import ConfigError, load_config
from nanoslam_jax.methods import run_filter
from nanoslam_jax.app.filters import settings_from_config
from nanoslam_jax.app.sweep import _batch
from nanoslam_jax.app.sweep import (
    TIMING_COLUMNS,
    SweepOverrides,
    expand,
    load_log_data,
    make_tasks,
    plan_groups,
    read_results,
    run_sweep,
)
from nanoslam_jax.app.sweep._batch import log_key
from tests.helpers.paths import REPO_ROOT
from tests.helpers.sweeps import BASE, MAIN, SMALL, spec_of


def rows_by_id(path: Path, drop: tuple = ()) -> dict[str, dict]:
    """Rows by run id without the timing columns (and without ``drop``)."""
    return {r["run_id"]: {k: v for k, v in r.items() if k not in TIMING_COLUMNS + drop} for r in read_results(path)}


def grid_rows_of_main(main_sweep) -> dict[str, dict]:
    """The main sweep's rows of the grid configurations c0000-c0003, as the SMALL sweep writes them."""
    full = rows_by_id(main_sweep[0] / "results.csv", drop=("noise.sigma_r",))
    return {k: v for k, v in full.items() if k[:5] in ("c0000", "c0001", "c0002", "c0003")}


@pytest.fixture(scope="module", autouse=True)
def trace_counter(tmp_path_factory):
    """Counts traces of the sweep program (Python calls of filter_scan inside it) and keeps JAX's
    persistent compilation cache in a module directory (reset afterwards)."""
    from jax._src import compilation_cache

    counter = {"n": 0}
    original = _batch.filter_scan

    def counting(*args, **kwargs):
        counter["n"] += 1
        return original(*args, **kwargs)

    mp = pytest.MonkeyPatch()
    mp.setattr(_batch, "filter_scan", counting)
    previous = jax.config.jax_compilation_cache_dir
    if not previous:
        enable_compile_cache(tmp_path_factory.mktemp("jax_cache"))
    yield counter
    mp.undo()
    if not previous:
        jax.config.update("jax_compilation_cache_dir", None)
        compilation_cache.reset_cache()


@pytest.fixture(scope="module")
def main_sweep(tmp_path_factory):
    """The main sweep, uninterrupted."""
    out = tmp_path_factory.mktemp("main") / "sweep"
    res = run_sweep(spec_of(MAIN), out, progress=False)
    return out, res


# --------------------------------------------------------------------------- expansion


@pytest.mark.slow
def test_sweep_compiles_once_per_shape_and_writes_its_results(main_sweep, trace_counter):
    out, res = main_sweep
    assert res.n_runs == 12 and res.n_new == 12 and len(res.groups) == 1 and res.groups[0].batch == 4
    # Three batches of one group: one trace, one compilation.
    assert trace_counter["n"] == 1
    static = res.groups[0].static
    assert [e["batch"] for e in _batch.compile_events() if e["static"] == static] == [4]
    rows = read_results(out / "results.csv")
    assert len(rows) == 12 and all(r["status"] == "ok" for r in rows)
    header = next(csv.reader(open(out / "results.csv")))
    for col in (
        "run_id",
        "config_id",
        "group",
        "filter.gate",
        "filter.new_landmark",
        "noise.sigma_r",
        "seed",
        "status",
        "reason",
        "rmse_fixed",
        "rmse_aligned",
        "rmse_fixed_clean",
        "final_error",
        "n_landmarks",
        "landmark_overflow",
        "resample_count",
        "ess_mean",
        "run_s",
        "compile_s",
    ):
        assert col in header
    # The best configuration: the lowest median rmse_aligned over the seeds, as a loadable config.
    med = {}
    for r in rows:
        med.setdefault(r["config_id"], []).append(float(r["rmse_aligned"]))
    best_id = min(sorted(med), key=lambda c: np.median(med[c]))
    assert res.best["config_id"] == best_id
    best = load_config(out / "best.yaml")
    bp = next(p for p in expand(spec_of(MAIN))[0] if p.config_id == best_id)
    assert (best.filter.gate, best.filter.new_landmark, best.noise.sigma_r) == (
        bp.values["filter.gate"],
        bp.values["filter.new_landmark"],
        bp.values["noise.sigma_r"],
    )
    summary = list(csv.DictReader(open(out / "summary.csv")))
    assert len(summary) == 6
    s = next(x for x in summary if x["config_id"] == best_id)
    q1, q3 = np.percentile(med[best_id], [25, 75])
    assert float(s["rmse_aligned_median"]) == pytest.approx(np.median(med[best_id]), rel=1e-12)
    assert (float(s["rmse_aligned_q1"]), float(s["rmse_aligned_q3"])) == pytest.approx((q1, q3), rel=1e-12)
    # The worst and best seed: the largest and smallest of the seeds' errors.
    assert (float(s["rmse_aligned_min"]), float(s["rmse_aligned_max"])) == (min(med[best_id]), max(med[best_id]))
    for f in ("sweep.yaml", "base_config.yaml", "version.json", "configs.csv", "summary.md"):
        assert (out / f).is_file()
    assert __version__ in (out / "version.json").read_text()


@pytest.mark.slow
def test_vmapped_runs_equal_the_same_runs_alone(main_sweep):
    """The batch program's members equal run_filter of the same configuration and seed: to rounding
    with vmap (here exactly, or within 1e-12), bit for bit with lax.map (vectorize: map)."""
    spec = spec_of(MAIN)
    _, runs, _ = expand(spec)
    log = load_log_data(runs[0].point.config, segments=None)
    logs = {log_key(runs[0].point.config): (0, log)}
    groups = plan_groups(spec, runs, logs)
    task = make_tasks(spec, groups, logs, done=set())[-1]  # the last batch: c0004, c0005 (random sigma_r)
    assert task.vectorize == "vmap"
    host, _, _ = _batch.batch_outputs(task, log)
    mapped, _, _ = _batch.batch_outputs(dataclasses.replace(task, vectorize="map"), log)
    by_id = {r.run_id: r for r in runs}
    for i in (0, 3):
        run = by_id[task.run_ids[i]]
        static, params = settings_from_config(run.point.config, log.segments.k_max)
        alone = run_filter(static, params, log.segments, run.seed, chunk=500)
        np.testing.assert_allclose(host.best_pose[i], np.asarray(alone.outputs.best_pose), rtol=0, atol=1e-12)
        np.testing.assert_allclose(host.mean_pose[i], np.asarray(alone.outputs.mean_pose), rtol=0, atol=1e-12)
        assert int(host.resample_count[i]) == int(alone.state.resample_count)
        np.testing.assert_array_equal(host.map_active[i], alone.state.particles.landmarks.active[int(alone.state.best)])
        np.testing.assert_array_equal(mapped.best_pose[i], np.asarray(alone.outputs.best_pose))
        np.testing.assert_array_equal(mapped.mean_pose[i], np.asarray(alone.outputs.mean_pose))
        np.testing.assert_array_equal(mapped.ess[i], np.asarray(alone.outputs.ess))
    # Members with other seeds or other values really differ (the comparison is not vacuous).
    assert np.abs(host.best_pose[0] - host.best_pose[1]).max() > 1e-3


@pytest.mark.slow
def test_resume_skips_finished_runs_and_reproduces_the_rows(main_sweep, tmp_path, trace_counter):
    out_full, _ = main_sweep
    out = tmp_path / "sweep"
    spec = spec_of(MAIN)
    traces = trace_counter["n"]

    def stop_after_first_batch(rows):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_sweep(spec, out, progress=False, on_batch=stop_after_first_batch)
    first = read_results(out / "results.csv")
    assert len(first) == 4  # the first batch is on disk
    # A killed append leaves a cut-off record: it is discarded, not taken for a finished run.
    with open(out / "results.csv", "a") as f:
        f.write("c0003-s1,c0003,g0,5.991,20.0,0.5,1,ok,,0.12")
    assert len(read_results(out / "results.csv")) == 4
    with pytest.raises(ConfigError, match="holds a sweep already"):
        run_sweep(spec, out, progress=False)
    with pytest.raises(ConfigError, match="seeds"):
        run_sweep(spec_of(MAIN, seeds=3), out, resume=True, progress=False)
    done = []
    res = run_sweep(
        spec, out, resume=True, progress=False, on_batch=lambda rows: done.extend(r["run_id"] for r in rows)
    )
    assert res.n_skipped == 4 and res.n_new == 8 and sorted(done) == sorted(set(done))
    assert not set(done) & {r["run_id"] for r in first}
    assert rows_by_id(out / "results.csv") == rows_by_id(out_full / "results.csv")
    assert trace_counter["n"] == traces  # the group's program was reused, never traced again
    text = (out / "results.csv").read_text()
    assert text.endswith("\n") and text.count("\n") == 13  # header + 12 complete rows


@pytest.mark.slow
def test_failed_runs_are_recorded_and_the_sweep_goes_on(tmp_path, trace_counter, monkeypatch):
    traces = trace_counter["n"]
    # gate 0.01, new_landmark 0.02: (nearly) every detection starts a landmark, which overflows the
    # capacity of 96 on this log; (5.991, 0.02) is invalid (new_landmark < gate) and skipped:
    # 5 configurations x 2 seeds in 3 batches of 4 (the program of the other tests).
    raw = {
        **MAIN,
        "random": None,
        "seeds": 2,
        "grid": {"filter.gate": [0.01, 5.991], "filter.new_landmark": [0.02, 13.816, 20.0]},
        "run": {"batch": 4, "parallel": "single", "vectorize": "vmap", "skip_invalid": True},
    }
    res = run_sweep(spec_of(raw), tmp_path / "a", progress=False)
    rows = {r["run_id"]: r for r in read_results(tmp_path / "a" / "results.csv")}
    assert len(rows) == 10 and res.groups[0].batch == 4
    for seed in (0, 1):
        bad, good = rows[f"c0000-s{seed}"], rows[f"c0003-s{seed}"]
        assert bad["status"] == "failed" and "landmark capacity overflow" in bad["reason"]
        assert int(bad["landmark_overflow"]) > 0 and int(bad["n_landmarks"]) == 96
        assert good["status"] == "ok" and good["reason"] == "" and int(good["landmark_overflow"]) == 0
    # The failed configuration never wins, however small its error; the best is the lowest median of the rest.
    ok = ("c0001", "c0002", "c0003", "c0004")
    assert all(rows[f"{c}-s{k}"]["status"] == "ok" for c in ok for k in (0, 1))
    med = {c: np.median([float(rows[f"{c}-s{k}"]["rmse_aligned"]) for k in (0, 1)]) for c in ok}
    assert res.best["config_id"] == min(med, key=med.get)
    assert "landmark capacity overflow" in (tmp_path / "a" / "summary.md").read_text()

    # An exception in one group fails that group's runs with the reason; the other group runs.
    original = _batch.batch_outputs

    def broken(task, log):
        if task.static.n_particles == 5:
            raise MemoryError("boom")
        return original(task, log)

    monkeypatch.setattr(_batch, "batch_outputs", broken)
    raw = {**MAIN, "random": None, "grid": {"filter.gate": [4.0, 5.991]}, "shapes": {"filter.n_particles": [4, 5]}}
    res = run_sweep(spec_of(raw), tmp_path / "b", progress=False)
    rows = read_results(tmp_path / "b" / "results.csv")
    assert len(rows) == 8 and len(res.groups) == 2
    failed = [r for r in rows if r["status"] == "failed"]
    assert {r["filter.n_particles"] for r in failed} == {"5"} and len(failed) == 4
    assert all(r["reason"] == "error: MemoryError: boom" for r in failed)
    assert all(r["status"] == "ok" for r in rows if r["filter.n_particles"] == "4")
    assert trace_counter["n"] == traces


@pytest.mark.slow
def test_cli_end_to_end(main_sweep, tmp_path, capsys):
    """The command line, with lax.map batches (vectorize: map): the sweep's numbers equal the
    vmapped sweep's to rounding, and `nanoslam run best.yaml` reproduces its row exactly."""
    import json

    from nanoslam_jax.app.cli import main

    spec_file = tmp_path / "tiny.yaml"
    spec_file.write_text(
        yaml.safe_dump({**MAIN, "run": {"batch": 4, "parallel": "single"}, "plots": True}, sort_keys=False)
    )
    out = tmp_path / "cli"
    assert main(["sweep", str(spec_file), "--out", str(out), "--vectorize", "map", "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "best: c" in printed and str(out) in printed
    assert yaml.safe_load((out / "sweep.yaml").read_text())["vectorize"] == "map"
    # The same numbers as the vmapped sweep (to rounding).
    ours, theirs = rows_by_id(out / "results.csv"), rows_by_id(main_sweep[0] / "results.csv")
    assert ours.keys() == theirs.keys()
    for rid, row in ours.items():
        for k, v in row.items():
            try:
                assert float(v) == pytest.approx(float(theirs[rid][k]), rel=1e-9, abs=1e-12, nan_ok=True), (rid, k)
            except ValueError:
                assert v == theirs[rid][k], (rid, k)
    plots = sorted(p.name for p in (out / "plots").iterdir())
    assert "heatmap_rmse_aligned_filter.gate_filter.new_landmark.png" in plots
    assert {"rmse_aligned_vs_filter.gate.png", "rmse_aligned_vs_noise.sigma_r.png"} <= set(plots)
    # Resuming a finished sweep runs nothing; errors are one line, no traceback.
    assert main(["sweep", str(spec_file), "--out", str(out), "--resume", "--quiet"]) == 0  # keeps map
    assert "12 runs (0 failed, 12 resumed)" in capsys.readouterr().out
    assert main(["sweep", str(spec_file), "--out", str(out), "--quiet"]) == 2
    assert "holds a sweep already" in capsys.readouterr().err
    assert main(["sweep", str(spec_file), "--out", str(out), "--resume", "--vectorize", "vmap", "--quiet"]) == 2
    assert "vectorize" in capsys.readouterr().err
    # best.yaml runs as it is, and `nanoslam run` reproduces the sweep's row of its seed exactly.
    assert main(["run", str(out / "best.yaml"), "--out", str(tmp_path / "best"), "--quiet"]) == 0
    metrics = json.loads((tmp_path / "best" / "metrics.json").read_text())
    best_id = re.search(r"best: (c\d+)", printed).group(1)
    row = ours[f"{best_id}-s0"]
    for k in ("rmse_fixed", "rmse_aligned", "final_error", "n_landmarks", "resample_count"):
        assert float(row[k]) == metrics[k], k


# --------------------------------------------------------------------------- other executors


@pytest.mark.slow
def test_worker_processes_write_the_same_results(main_sweep, tmp_path):
    out = tmp_path / "proc"
    res = run_sweep(spec_of(SMALL), out, progress=False, overrides=SweepOverrides(parallel="processes", workers=2))
    assert res.n_new == 8
    assert rows_by_id(out / "results.csv") == grid_rows_of_main(main_sweep)


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore:os.fork:RuntimeWarning")  # Ray starts its processes from the driver
def test_ray_backend_writes_the_same_results(main_sweep, tmp_path):
    ray = pytest.importorskip("ray", reason="Ray is not installed (pip install 'nanoslam-jax[ray]')")
    out = tmp_path / "ray"
    spec = spec_of(SMALL, ray={"num_cpus": 1})  # one worker process: its two tasks reuse its program
    try:
        res = run_sweep(spec, out, progress=False, overrides=SweepOverrides(backend="ray"))
    finally:
        if ray.is_initialized():
            ray.shutdown()
    assert res.n_new == 8
    assert rows_by_id(out / "results.csv") == grid_rows_of_main(main_sweep)


@pytest.mark.slow
def test_device_split_sweep_keeps_least_squares_methods_on_one_device(tmp_path):
    """``run.parallel: devices`` splits each batch over JAX devices with ``shard_map``. optimistix's
    least squares (method ``iterated``) fails to compile under ``shard_map`` (lineax issue #185,
    reproduced here so that this test notices when it is fixed): such a group runs each batch on
    one device, the others stay split, and every run finishes, the iterated ones exactly as in a
    single-device sweep. JAX fixes its device count at start-up, so this runs in a fresh
    interpreter."""
    code = textwrap.dedent(f"""
        import csv, json
        import jax
        jax.config.update("jax_enable_x64", True)
        from nanoslam_jax.app.sweep import SweepOverrides, _batch, run_sweep, sweep_from_dict
        base = {BASE!r}
        raw = {{"base": base, "seeds": 2, "grid": {{"filter.gate": [5.991]}}, "plots": False,
               "run": {{"batch": 2, "vectorize": "vmap", "compile_cache": False}}}}
        both = sweep_from_dict({{**raw, "shapes": {{"filter.method": ["fastslam1", "iterated"]}}}})
        run_sweep(both, {str(tmp_path / "devices")!r}, progress=False,
                  overrides=SweepOverrides(parallel="devices", workers=2))  # 2 cores
        split = sorted({{(e["static"].method.name, e["devices"]) for e in _batch.compile_events()}})
        it = sweep_from_dict({{**raw, "base": {{**base, "filter": {{**base["filter"], "method": "iterated"}}}}}})
        run_sweep(it, {str(tmp_path / "single")!r}, progress=False, overrides=SweepOverrides(parallel="single"))
        rows = {{}}
        for name in ("devices", "single"):
            with open({str(tmp_path)!r} + "/" + name + "/results.csv") as f:
                rows[name] = list(csv.DictReader(f))
        # The shard_map split of the iterated batch itself still fails:
        import numpy as np
        from nanoslam_jax.app.config import config_from_dict
        from nanoslam_jax.app.filters import settings_from_config
        from nanoslam_jax.app.sweep import load_log_data
        cfg = config_from_dict(it.base)
        log = load_log_data(cfg)
        static, params = settings_from_config(cfg, log.segments.k_max)
        stacked = jax.tree.map(lambda x: np.stack([np.asarray(x)] * 2), params)
        try:
            _batch.batch_program.lower(static, "vmap", 2, stacked, np.arange(2), log.segments).compile()
            upstream = "compiles"
        except ValueError as e:
            upstream = str(e)
        print(json.dumps(dict(split=split, upstream=upstream, rows=rows)))
    """)
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    r = json.loads(res.stdout.strip().splitlines()[-1])
    (m1, d1), (m2, d2) = r["split"]  # the sweep sets up SWEEP_DEVICES_PER_CORE devices per core
    assert (m1, m2) == ("fastslam1", "iterated") and d1 == 2 * SWEEP_DEVICES_PER_CORE and d2 == 1
    assert "pytree does not match out_structure" in r["upstream"], r["upstream"]
    devices, single = r["rows"]["devices"], r["rows"]["single"]
    assert [row["status"] for row in devices] == ["ok"] * 4
    # The same runs as alone on one device, to rounding (the device sweep pads the batch to 8).
    iterated = [row for row in devices if row["filter.method"] == "iterated"]
    assert [row["seed"] for row in iterated] == [row["seed"] for row in single]
    for a, b in zip(iterated, single):
        for k in ("rmse_fixed", "rmse_aligned", "final_error", "ess_min", "n_landmarks", "resample_count"):
            assert float(a[k]) == pytest.approx(float(b[k]), rel=1e-9), k
    assert all(math.isfinite(float(row["rmse_aligned"])) for row in devices)


@pytest.mark.slow
def test_adaptive_noise_sweep_records_where_the_estimates_ended(main_sweep, tmp_path):
    """A sweep with ``noise.adaptive`` records ``noise_sigma_*_final`` and ``noise_at_floor_*``
    (a sweep without it has no such columns). The filter starts from 1.0 m and 4 deg against the
    simulator's 0.3 m and 1 deg: with ``noise.adaptive_floor`` 1.0 the floor is the configured
    noise, which every particle's estimate, free, falls below (measured: 0.27 m), so it must end
    there; with 0.01 (0.1 m, 0.4 deg) the estimates are free."""
    assert "noise_at_floor_range" not in next(csv.reader(open(main_sweep[0] / "results.csv")))
    base = {
        **BASE,
        "filter": {**BASE["filter"], "method": "fastslam2", "capacity": 192, "window": 40},
        "noise": {**BASE["noise"], "sigma_r": 1.0, "sigma_beta_deg": 4.0, "adaptive": True},
        "map": {"manage": True},
    }
    raw = {
        "base": base,
        "seeds": 1,
        "grid": {"noise.adaptive_floor": [0.01, 1.0]},
        "plots": False,
        "run": {"batch": 2, "parallel": "single", "vectorize": "vmap"},
    }
    run_sweep(spec_of(raw), tmp_path / "adaptive", progress=False)
    rows = {float(r["noise.adaptive_floor"]): r for r in read_results(tmp_path / "adaptive" / "results.csv")}
    free, held = rows[0.01], rows[1.0]
    assert free["status"] == held["status"] == "ok", (free["reason"], held["reason"])
    assert float(held["noise_at_floor_range"]) == float(held["noise_at_floor_bearing"]) == 1.0
    assert float(held["noise_sigma_r_final"]) == pytest.approx(1.0, rel=1e-9)
    assert float(held["noise_sigma_beta_deg_final"]) == pytest.approx(4.0, rel=1e-9)
    assert float(free["noise_at_floor_range"]) == float(free["noise_at_floor_bearing"]) == 0.0
    assert 0.1 < float(free["noise_sigma_r_final"]) < 1.0


@pytest.mark.slow
def test_sweep_no_cache_turns_the_sweep_files_cache_off(tmp_path, monkeypatch):
    import argparse

    from nanoslam_jax.app.sweep import _runner
    from nanoslam_jax.app.sweep._cli import sweep_command

    seen = {}

    def fake_run_sweep(spec, out, **kwargs):
        seen["compile_cache"] = spec.run.compile_cache
        raise KeyboardInterrupt  # stop before anything runs

    monkeypatch.setattr(_runner, "run_sweep", fake_run_sweep)
    sweep = REPO_ROOT / "configs" / "sweep_example.yaml"
    for flag, expected in ((True, False), (False, True)):
        args = argparse.Namespace(
            sweep=str(sweep),
            overrides=[],
            ray_address=None,
            workers=None,
            batch=None,
            dry_run=False,
            out=str(tmp_path / "s"),
            resume=False,
            data=None,
            quiet=True,
            backend=None,
            parallel=None,
            vectorize=None,
            no_cache=flag,
        )
        assert sweep_command(args) == 130
        assert seen["compile_cache"] is expected
