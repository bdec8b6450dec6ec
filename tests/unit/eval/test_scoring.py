"""The one scorer (:mod:`nanoslam_jax.eval._scoring`): the failed-seed rule on a table made by hand, the
same rule in compare, sweep and study, the same score of the same run from run / compare / sweep /
study, and the recommended (smoothed) configuration through compare and sweep."""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from nanoslam_jax.eval._scoring import metric_goal, seed_summary, summarize_runs
from tests.helpers.paths import REPO_ROOT

ROOT = REPO_ROOT
BEST = ROOT / "configs" / "victoria_park_best.yaml"
#: A short simulated log and a small filter. FastSLAM 1.0: the proposal does not matter to the
#: scoring, and it compiles fastest (each test compiles a run's and a sweep batch's program).
SIM = [
    "data.kind=simulated",
    "sim.duration=20",
    "data.max_dr_per_segment=2",
    "filter.capacity=96",
    "filter.window=24",
    "filter.n_particles=4",
    "filter.method=fastslam1",
    "output.progress=false",
    "output.plots=false",
    "filter.row_buckets=never",
]

# Five seeds by hand; seed 3 failed. Its error counts as +inf: sorted 1, 2, 3, 5, inf.
TABLE = [
    {"seed": 0, "status": "ok", "reason": "", "rmse_fixed": 3.0, "n_landmarks": 10, "map_found_fraction": 0.9},
    {"seed": 1, "status": "ok", "reason": "", "rmse_fixed": 1.0, "n_landmarks": 12, "map_found_fraction": 0.8},
    {"seed": 2, "status": "ok", "reason": "", "rmse_fixed": 2.0, "n_landmarks": 14, "map_found_fraction": 0.7},
    {
        "seed": 3,
        "status": "failed",
        "reason": "non-finite estimate from segment 7 (t = 1.50 s)",
        "rmse_fixed": "",
        "n_landmarks": 99,
        "map_found_fraction": "",
    },
    {"seed": 4, "status": "ok", "reason": "", "rmse_fixed": 5.0, "n_landmarks": 16, "map_found_fraction": 0.6},
]


def test_a_failed_seed_is_counted_named_and_the_worst():
    s = summarize_runs(
        TABLE,
        ["rmse_fixed", "n_landmarks", "map_found_fraction"],
        stats=("median", "q1", "q3", "min", "max", "worst", "best"),
    )
    assert (s["n_runs"], s["n_ok"], s["n_failed"], s["failed_seeds"]) == (5, 4, 1, "3")
    assert s["reasons"] == "non-finite estimate from segment 7 (t = 1.50 s)"
    # the error: over 1, 2, 3, 5, inf (positions 1 and 3 of 0..4), not over the four that finished
    # (which would give a median of 2.5 and quartiles 1.75, 3.5)
    assert (s["rmse_fixed_median"], s["rmse_fixed_q1"], s["rmse_fixed_q3"]) == (3.0, 2.0, 5.0)
    assert s["rmse_fixed_worst"] == s["rmse_fixed_max"] == math.inf and s["rmse_fixed_best"] == 1.0
    # a found fraction (higher is better): the failure counts as -inf, sorted -inf, 0.6, 0.7, 0.8, 0.9
    assert metric_goal("map_found_fraction") == "max"
    assert (s["map_found_fraction_median"], s["map_found_fraction_q1"], s["map_found_fraction_q3"]) == (0.7, 0.6, 0.8)
    assert s["map_found_fraction_worst"] == -math.inf and s["map_found_fraction_best"] == 0.9
    # a descriptive column has no worst value: over the four seeds that finished (10, 12, 14, 16)
    assert metric_goal("n_landmarks") is None
    assert (s["n_landmarks_median"], s["n_landmarks_max"]) == (13.0, 16.0)


def test_the_median_is_inf_when_more_than_half_failed():
    v = [1.0, 2.0, 7.0, 3.0, 4.0]
    failed = [False, False, True, True, True]
    s = seed_summary(v, failed, "min", seeds=[10, 11, 12, 13, 14])  # 1, 2, inf, inf, inf
    assert s["median"] == math.inf and s["q1"] == 2.0 and s["n_failed"] == 3 and s["failed_seeds"] == [12, 13, 14]
    s = seed_summary([1.0, 2.0, 3.0, 4.0], [False, False, False, True])  # 1, 2, 3, inf: half failed
    assert s["median"] == 2.5 and s["q1"] == 1.75 and s["q3"] == math.inf  # the interpolation reaches inf


def test_a_nan_metric_fails_its_seed_and_a_metric_no_seed_has_is_nan():
    s = seed_summary([1.0, float("nan"), 3.0])  # a run that finished without this figure
    assert s["n_failed"] == 1 and s["failed_seeds"] == [1] and s["median"] == 3.0 and s["worst"] == math.inf
    s = seed_summary([float("nan")] * 3)  # not applicable (rmse_* of a log without GPS)
    assert math.isnan(s["median"]) and s["n_failed"] == 0
    s = seed_summary([float("nan")] * 2, [True, True])  # every seed failed
    assert s["median"] == math.inf


def test_compare_sweep_and_study_summarise_by_the_same_rule():
    """The hand table through each command's own summary: the same figures."""
    from nanoslam_jax.app.compare import MethodResult, MethodSpec, summarise
    from nanoslam_jax.app.study import summarize_points
    from nanoslam_jax.app.sweep import ConfigPoint, summarize

    res = MethodResult(MethodSpec("NANO", ("filter.method=nano",)), "nano", rows=[dict(r) for r in TABLE])
    c = summarise(res)
    point = ConfigPoint("c0000", {}, None)
    csv_rows = [
        {"config_id": "c0000", "run_id": f"c0000-s{r['seed']}", **{k: str(v) for k, v in r.items()}} for r in TABLE
    ]
    w = summarize(csv_rows, [point], {"c0000": "g0"}, ["rmse_fixed", "n_landmarks"])[0]
    st = summarize_points([{"method": "NANO", "particles": "4", **r} for r in csv_rows], ["rmse_fixed"])[0]
    assert c["rmse_fixed_median"] == w["rmse_fixed_median"] == st["rmse_fixed_median"] == 3.0
    assert c["rmse_fixed_q1"] == w["rmse_fixed_q1"] == st["rmse_fixed_q1"] == 2.0
    assert c["rmse_fixed_q3"] == w["rmse_fixed_q3"] == st["rmse_fixed_q3"] == 5.0
    assert c["rmse_fixed_worst"] == w["rmse_fixed_max"] == st["rmse_fixed_worst"] == math.inf
    assert c["n_failed"] == w["n_failed"] == st["n_failed"] == 1
    assert c["failed_seeds"] == w["failed_seeds"] == st["failed_seeds"] == "3"
    assert c["n_landmarks_median"] == w["n_landmarks_median"] == st["n_landmarks_median"] == 13.0


def test_a_sweep_goal_max_counts_a_failure_as_minus_inf():
    from nanoslam_jax.app.sweep import ConfigPoint, summarize

    rows = [
        {
            "config_id": "c0000",
            "run_id": f"c0000-s{r['seed']}",
            "seed": str(r["seed"]),
            "status": r["status"],
            "reason": r["reason"],
            "ess_mean": str(r["n_landmarks"]),
        }
        for r in TABLE
    ]
    w = summarize(rows, [ConfigPoint("c0000", {}, None)], {}, ["ess_mean"], {"ess_mean": "max"})[0]
    assert w["ess_mean_min"] == -math.inf and w["ess_mean_median"] == 12.0  # -inf, 10, 12, 14, 16


# --------------------------------------------------------------------------- the commands on a log

KEYS = (
    "rmse_fixed",
    "rmse_aligned",
    "rmse_fixed_clean",
    "rmse_aligned_clean",
    "final_error",
    "n_landmarks",
    "n_confirmed",
    "map_found_fraction",
    "map_found_fraction_aligned",
    "map_spurious_fraction",
)


def _csv(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _compare(tmp_path: Path, base, overrides: list[str], seeds: int, chunk: int) -> list[dict]:
    """A comparison of one method; its timing run in chunks of ``chunk`` segments (the run's
    ``output.chunk``: the program `nanoslam run` compiled, loaded again)."""
    from nanoslam_jax.app.compare import load_compare_spec, run_compare

    f = tmp_path / "cmp.yaml"
    f.write_text(
        yaml.safe_dump(
            {
                "name": "one",
                "base": None if base is None else str(base),
                "seeds": seeds,
                "first_seed": 0,
                "set": overrides,
                "timing_chunk": chunk,
                "methods": [{"label": "FastSLAM 1.0", "set": ["filter.method=fastslam1"]}],
            }
        )
    )
    run_compare(load_compare_spec(f), tmp_path / "cmp", plots=False, stream=io.StringIO())
    return _csv(tmp_path / "cmp" / "runs.csv")


def _sweep(tmp_path: Path, cfg, seeds: list[int]) -> list[dict]:
    from nanoslam_jax.app.config import config_to_dict
    from nanoslam_jax.app.sweep import run_sweep, sweep_from_dict

    spec = sweep_from_dict(
        {
            "name": "one",
            "base": config_to_dict(cfg),
            "seeds": seeds,
            "plots": False,
            "run": {"vectorize": "map", "parallel": "single", "compile_cache": False},
        }
    )
    run_sweep(spec, tmp_path / "sweep", progress=False)
    return sorted(_csv(tmp_path / "sweep" / "results.csv"), key=lambda r: int(r["seed"]))


@pytest.mark.slow
def test_run_compare_sweep_and_study_give_the_same_score(tmp_path, monkeypatch):
    """One run (seed 0 on a short simulated log) scored by `nanoslam run`, compare,
    sweep and study: the same figures. The sweep runs it with ``vectorize: map`` (each member
    computed as a run alone), so all four see the same trajectory and map and differ only if
    their scoring did."""
    from nanoslam_jax.app.config import load_config
    from nanoslam_jax.app.experiment import execute
    from nanoslam_jax.app.study import load_study, run_study
    from tests.helpers.internals import study_runner

    cfg = load_config(None, SIM)
    ref = execute(cfg).metrics
    assert ref["finite"] and ref["rmse_fixed"] > 0
    cmp_row = _compare(tmp_path, None, SIM, 1, cfg.output.chunk)[0]
    sweep_row = _sweep(tmp_path, cfg, [0])[0]

    study_file = tmp_path / "study.yaml"
    study_file.write_text(
        yaml.safe_dump(
            {
                "name": "one",
                "base": None,
                "set": SIM,
                "first_seed": 0,
                "particles": {4: 1},
                "run": {"vectorize": "map", "parallel": "single", "compile_cache": False},
                "methods": [{"label": "FastSLAM 1.0", "set": ["filter.method=fastslam1"]}],
            }
        )
    )
    # the study's timing process (a fresh interpreter) is not what this test is about
    monkeypatch.setattr(
        study_runner,
        "_time_point",
        lambda spec, pt, *a: {
            "point_id": pt.point_id,
            "method": pt.label,
            "particles": pt.particles,
            "seed": pt.seeds[0],
            "status": "failed",
            "reason": "not timed in this test",
        },
    )
    res = run_study(load_study(study_file), tmp_path / "study", plots=False, progress=False)
    study_row = _csv(tmp_path / "study" / "runs.csv")[0]

    assert cmp_row["status"] == sweep_row["status"] == study_row["status"] == "ok"
    for k in KEYS:
        want = float(ref[k])
        assert float(cmp_row[k]) == pytest.approx(want, rel=1e-9, abs=1e-12), k
        assert float(sweep_row[k]) == pytest.approx(want, rel=1e-9, abs=1e-12), k
        if k in study_row:
            assert float(study_row[k]) == pytest.approx(want, rel=1e-9, abs=1e-12), k
    assert res.summary[0]["rmse_fixed_median"] == pytest.approx(ref["rmse_fixed"], rel=1e-9)


@pytest.mark.slow
def test_the_smoothed_recommended_config_through_compare_and_sweep(tmp_path):
    """configs/victoria_park_best.yaml (smoother, loop closure and map history on) on a short
    simulated log (FastSLAM 1.0's proposal, see SIM), in chunks of 40 segments so that the map
    history has several entries: compare and sweep smooth each seed after the batch and score the
    smoothed path as `nanoslam run` does (the same figures for the same seed), with the path it
    started from beside it."""
    from nanoslam_jax.app.config import load_config
    from nanoslam_jax.app.experiment import execute

    over = SIM + ["sim.duration=30", "output.chunk=40"]
    cfg = load_config(BEST, over)
    assert cfg.smoother.enabled and cfg.smoother.loop_closure and cfg.smoother.map_history
    ref = execute(cfg).metrics
    assert ref["smoother_iterations"] > 0 and np.isfinite(ref["rmse_fixed_path"])

    sweep_rows = _sweep(tmp_path, cfg, [0, 1])
    cmp_rows = _compare(tmp_path, BEST, over, 1, 40)
    for rows in (sweep_rows, cmp_rows):
        r = rows[0]
        assert r["status"] == "ok" and int(r["smoother_iterations"]) > 0
        for k in ("rmse_fixed", "rmse_aligned", "rmse_fixed_path", "rmse_aligned_path", "rmse_fixed_best"):
            assert float(r[k]) == pytest.approx(float(ref[k]), rel=1e-9), k
    assert sweep_rows[1]["status"] == "ok" and float(sweep_rows[1]["rmse_fixed"]) > 0
    summary = _csv(tmp_path / "sweep" / "summary.csv")[0]
    assert int(summary["n_failed"]) == 0 and float(summary["rmse_fixed_path_median"]) > 0
