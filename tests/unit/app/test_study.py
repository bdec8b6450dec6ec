"""The accuracy-against-compute study (nanoslam_jax.app.study) and the GPS floor (nanoslam_jax.eval.gps_floor).

Independent truths: the study file's counts for the expansion; hand-computed medians, quartiles,
sign-test p-values and interpolations on small fake result tables; a synthetic GPS track made
from a known path with a known frame rotation, antenna offset, clock shift, white noise and jumps
for the floor; the per-point sweep results for the study's tables, and an uninterrupted study for
a resumed one.
"""

from __future__ import annotations

import csv
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from nanoslam_jax.app._devices import DEVICES_PER_CORE, available_cores
from nanoslam_jax.app.cli import main
from nanoslam_jax.methods import particle_devices
from nanoslam_jax.app.config import ConfigError
from nanoslam_jax.eval.gps_floor import estimate_gps_floor
from nanoslam_jax.eval.metrics import rotation_matrix
from nanoslam_jax.app.study import (
    equal_time,
    expand_study,
    load_study,
    paired_comparison,
    summarize_points,
    summary_stats,
)
from tests.helpers.paths import REPO_ROOT

ROOT = REPO_ROOT
STUDY = ROOT / "configs" / "accuracy_vs_compute.yaml"
#: A small, cheap-to-compile simulated log (as the sweep tests use).
SIM = ["data.kind=simulated", "sim.duration=20", "data.max_dr_per_segment=2", "filter.capacity=96", "filter.window=24"]


def _write(path: Path, d: dict) -> Path:
    path.write_text(yaml.safe_dump(d, sort_keys=False))
    return path


# --------------------------------------------------------------------------- the study file


def test_expansion_of_the_shipped_study_is_exact():
    spec = load_study(STUDY)
    raw = yaml.safe_load(STUDY.read_text())
    pts = expand_study(spec)
    gaussian = ("ekf_slam", "nasrukf")  # deterministic: one run each
    particle_methods = [m["label"] for m in raw["methods"] if not any(g in " ".join(m["set"]) for g in gaussian)]
    n_gaussian = len(raw["methods"]) - len(particle_methods)
    counts = raw["particles"]
    assert set(counts) == {10, 30, 100, 300, 1000}
    assert all(s >= 16 for n, s in counts.items() if n < 1000) and counts[1000] >= 8
    # methods x particle counts, plus EKF-SLAM and NASRUKF once, with exactly the file's seeds
    assert n_gaussian == 2
    assert len(pts) == len(particle_methods) * len(counts) + n_gaussian
    assert sum(len(p.seeds) for p in pts) == len(particle_methods) * sum(counts.values()) + n_gaussian
    got = {(p.label, p.particles): p.seeds for p in pts}
    first = raw["first_seed"]
    assert first >= 16  # seeds the tuning (on 0-15) never saw
    for label in particle_methods:
        for n, s in counts.items():
            assert got[(label, n)] == tuple(range(first, first + s))
    assert got[("EKF-SLAM", None)] == (first,) and got[("NASRUKF", None)] == (first,)
    for p in pts:  # each point's config is the method's at its particle count
        assert p.config.filter.method == p.method
        if p.particles is not None:
            assert p.config.filter.n_particles == p.particles
    order = [p.particles or 0 for p in pts]
    assert order == sorted(order)  # cheapest particle counts first
    assert {"NANO-SLAM", "UFastSLAM", "FastSLAM 2.0"} <= set(particle_methods)
    assert spec.paired.reference == "NANO-SLAM" and set(spec.paired.against) == {"UFastSLAM", "FastSLAM 2.0"}


def test_quick_variant_seeds_and_methods_overrides(tmp_path):
    quick = load_study(STUDY, quick=True)
    q = yaml.safe_load(STUDY.read_text())["quick"]
    pts = expand_study(quick)
    particle_methods = [m for m in q["methods"] if m not in ("EKF-SLAM", "NASRUKF")]
    assert len(pts) == len(particle_methods) * len(q["particles"]) + 2
    assert {(p.label, p.particles): len(p.seeds) for p in pts if p.particles} == {
        (m, n): s for m in particle_methods for n, s in q["particles"].items()
    }
    assert quick.segments == q["segments"] and quick.timing.repeats == q["timing"]["repeats"]
    assert quick.name.endswith("-quick")

    two = load_study(STUDY, quick=True, seeds=2, only=["NANO-SLAM", "EKF-SLAM"])
    f = yaml.safe_load(STUDY.read_text())["first_seed"]
    assert [(p.label, p.particles, p.seeds) for p in expand_study(two)] == [
        ("EKF-SLAM", None, (f,)),
        ("NANO-SLAM", 10, (f, f + 1)),
        ("NANO-SLAM", 100, (f, f + 1)),
    ]
    # --methods narrows what runs, not the study: the comparison stays (it pairs whatever points
    # the directory holds, e.g. after a --resume with the other methods)
    assert two.paired.reference == "NANO-SLAM" and set(two.paired.against) == {"UFastSLAM", "FastSLAM 2.0"}
    assert load_study(STUDY, quick=True, only=["NANO-SLAM"], counts=[10]).paired == two.paired

    own = _write(
        tmp_path / "own.yaml",
        {
            "base": str(ROOT / "configs" / "victoria_park_nano.yaml"),
            "first_seed": 5,
            "particles": {10: 3, 20: 2},
            "methods": [
                {"label": "A", "set": ["filter.method=fastslam1"], "particles": {40: 1}},
                {"label": "B", "set": ["filter.method=nano"]},
            ],
        },
    )
    assert [(p.point_id, p.seeds) for p in expand_study(load_study(own))] == [
        ("B_N0010", (5, 6, 7)),
        ("B_N0020", (5, 6)),
        ("A_N0040", (5,)),
    ]
    # --particles keeps only those counts (a method's own counts too), with the same point ids
    assert [(p.point_id, p.seeds) for p in expand_study(load_study(own, counts=[20, 40]))] == [
        ("B_N0020", (5, 6)),
        ("A_N0040", (5,)),
    ]
    assert [p.point_id for p in expand_study(load_study(own, counts=[10]))] == ["B_N0010"]
    for bad in ([7], [], [10, 30]):
        with pytest.raises(ConfigError, match=r"--particles: expected particle counts of the study \[10, 20, 40\]"):
            load_study(own, counts=bad)


@pytest.mark.parametrize(
    "change, fragment",
    [
        ({"particles": {10: 0}}, "particles.10"),
        ({"particles": [10, 100]}, "'particles'"),
        ({"bogus": 1}, "bogus"),
        ({"paired": {"reference": "NANO", "against": ["UFastSLAM"]}}, "paired.reference"),
        ({"timing": {"repeats": 0}}, "timing.repeats"),
        ({"run": {"batch": "many"}}, "run.batch"),
        ({"methods": [{"label": "X", "set": ["filter.method=dead_reckoning"]}]}, "dead_reckoning"),
        ({"methods": [{"label": "X", "set": ["filter.n_particle=3"]}]}, "filter.n_particle"),
    ],
)
def test_invalid_study_files_name_the_file_and_key(tmp_path, change, fragment):
    raw = yaml.safe_load(STUDY.read_text())
    raw["base"] = str(ROOT / "configs" / "victoria_park_nano.yaml")
    if "methods" in change:
        raw.pop("paired")
    path = _write(tmp_path / "bad.yaml", {**raw, **change})
    with pytest.raises(ConfigError) as e:
        load_study(path)
    assert str(path) in str(e.value) and fragment in str(e.value)


def test_a_method_not_registered_is_named(tmp_path, monkeypatch):
    """A study naming a method the registry does not hold (here: NANO-SLAM taken out of it)
    stops before anything runs, naming the entry and the method."""
    import nanoslam_jax.app.registry as methods

    monkeypatch.delitem(methods._REGISTRY, "nano")
    raw = {
        "base": str(ROOT / "configs" / "victoria_park_fastslam1.yaml"),
        "particles": {10: 2},
        "methods": [{"label": "New", "set": ["filter.method=nano"]}],
    }
    with pytest.raises(ConfigError, match="'New'.*filter.method.*'nano' is not a registered method"):
        load_study(_write(tmp_path / "new.yaml", raw))


def test_quick_and_methods_errors(tmp_path, capsys):
    with pytest.raises(ConfigError, match="--methods"):
        load_study(STUDY, only=["NANO"])
    with pytest.raises(ConfigError, match="quick.methods"):
        raw = yaml.safe_load(STUDY.read_text())
        raw["base"] = str(ROOT / "configs" / "victoria_park_nano.yaml")
        raw["quick"]["methods"] = ["nope"]
        load_study(_write(tmp_path / "q.yaml", raw), quick=True)
    # --quick is for study files: a Table I comparison says so in one line, exit 2
    assert main(["compare", str(ROOT / "configs" / "table1.yaml"), "--quick"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--quick applies to study files" in err[0]


# --------------------------------------------------------------------------- statistics


def _row(method, particles, seed, fixed, aligned=None, status="ok"):
    return {
        "method": method,
        "particles": particles,
        "seed": seed,
        "status": status,
        "rmse_fixed": fixed,
        "rmse_aligned": fixed if aligned is None else aligned,
        "n_landmarks": 100 + seed,
    }


def test_summary_medians_quartiles_and_worst_seed_by_hand():
    rows = [_row("A", 10, s, v) for s, v in enumerate([4.0, 1.0, 3.0, 2.0, 10.0])]
    rows += [_row("A", 100, 0, 2.0), _row("A", 100, 1, 1.0), _row("A", 100, 2, 9.0, status="failed")]
    rows += [_row("E", None, 0, 3.5)]
    s = {
        (r["method"], r["particles"]): r
        for r in summarize_points(rows, ["rmse_fixed"], {("A", 10): {"seconds_per_log": 2.5}})
    }
    a = s[("A", 10)]  # sorted 1 2 3 4 10: median 3, q1 2, q3 4 (linear), worst 10
    assert (
        a["rmse_fixed_median"],
        a["rmse_fixed_q1"],
        a["rmse_fixed_q3"],
        a["rmse_fixed_worst"],
        a["rmse_fixed_best"],
    ) == (3.0, 2.0, 4.0, 10.0, 1.0)
    assert a["seeds"] == 5 and a["n_ok"] == 5 and a["seconds_per_log"] == 2.5 and a["n_landmarks_median"] == 102
    b = s[("A", 100)]  # 1, 2, inf: median 2, q1 1.5, q3 between 2 and inf -> inf, worst inf
    assert (b["rmse_fixed_median"], b["rmse_fixed_q1"], b["rmse_fixed_q3"], b["rmse_fixed_worst"]) == (
        2.0,
        1.5,
        math.inf,
        math.inf,
    )
    assert b["n_failed"] == 1 and b["n_landmarks_median"] == 100.5
    assert s[("E", None)]["rmse_fixed_median"] == 3.5 and "seconds_per_log" not in s[("E", None)]
    # values read back from a CSV (strings) give the same statistics
    as_text = [{k: ("" if v is None else str(v)) for k, v in r.items()} for r in rows]
    assert summarize_points(as_text, ["rmse_fixed"])[0]["rmse_fixed_median"] == 3.0
    assert math.isnan(summary_stats(np.array([]))["median"])


def test_paired_comparison_by_hand():
    nano = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0]
    other = [2.0, 3.0, 4.5, 4.5, 6.0, 5.0, 9.0, 10.0, 9.0]  # differences -1 -1 -1.5 -0.5 -1 1 -2 -2 0
    rows = [_row("N", 10, s, v) for s, v in enumerate(nano)] + [_row("U", 10, s, v) for s, v in enumerate(other)]
    rows += [_row("U", 10, 99, 1.0)]  # a seed only one method ran: not a pair
    r = paired_comparison(rows, "N", "U", 10, "rmse_fixed", n_resamples=2000, seed=1)
    assert (r["pairs"], r["wins"], r["losses"], r["ties"]) == (9, 7, 1, 1)
    assert r["sign_p"] == pytest.approx(2 * (1 + 8) / 2**8)  # P(X <= 1) + P(X >= 7), X ~ B(8, 1/2)
    assert r["median_diff"] == -1.0 and r["n_diff"] == 9
    assert -2.0 <= r["diff_low"] <= -1.0 <= r["diff_high"] <= 1.0
    assert paired_comparison(rows, "N", "U", 10, "rmse_fixed", n_resamples=2000, seed=1) == r  # reproducible
    assert r["median_ref"] == 5.0 and r["median_other"] == 5.0 and r["ratio"] == 1.0

    # a failed run loses to a finished one; two failed runs tie; differences only where both finished
    rows = [
        _row("N", 10, 0, 1.0),
        _row("N", 10, 1, 5.0, status="failed"),
        _row("N", 10, 2, 3.0, status="failed"),
        _row("U", 10, 0, 2.0),
        _row("U", 10, 1, 4.0),
        _row("U", 10, 2, 1.0, status="failed"),
    ]
    r = paired_comparison(rows, "N", "U", 10, "rmse_fixed")
    assert (r["wins"], r["losses"], r["ties"], r["n_diff"], r["median_diff"]) == (1, 1, 1, 1, -1.0)
    assert math.isnan(r["diff_low"]) and r["sign_p"] == 1.0


def test_equal_time_interpolates_in_log_seconds_by_hand():
    summary = [
        {"method": "U", "particles": n, "rmse_fixed_median": m, "seconds_per_log": t}
        for n, m, t in [(10, 8.0, 1.0), (100, 6.0, 10.0), (1000, 4.0, 100.0)]
    ]
    summary += [
        {"method": "N", "particles": 10, "rmse_fixed_median": 5.0, "seconds_per_log": math.sqrt(10.0)},
        {"method": "N", "particles": 1000, "rmse_fixed_median": 3.0, "seconds_per_log": 400.0},
    ]
    r = equal_time(summary, "N", "U", 10, "rmse_fixed")
    # sqrt(10) s is half-way between 1 s and 10 s in log time: U's median there is 7
    assert r["median_other_at_time"] == pytest.approx(7.0) and r["diff"] == pytest.approx(-2.0)
    assert r["bracket"] == "10-100"
    out = equal_time(summary, "N", "U", 1000, "rmse_fixed")  # beyond U's slowest point: no extrapolation
    assert math.isnan(out["median_other_at_time"]) and out["median_ref"] == 3.0


# --------------------------------------------------------------------------- the GPS floor


def test_gps_floor_recovers_a_known_frame_offset_noise_and_jumps():
    rng = np.random.default_rng(0)
    t = np.arange(0.0, 600.0, 0.05)
    # a winding drive at a varying speed (a constant one would make a clock shift and a forward
    # antenna offset indistinguishable)
    speed, turn = 3.0 + 1.5 * np.sin(2 * np.pi * t / 37.0), 0.25 * np.sin(2 * np.pi * t / 90.0) + 0.05
    phi = np.cumsum(turn) * 0.05
    xy = np.cumsum((speed * 0.05)[:, None] * np.stack([np.cos(phi), np.sin(phi)], 1), axis=0)
    pose = np.column_stack([xy, phi])  # the exact laser path in the SLAM frame
    delta, offset, lag, sigma = 1.5, np.array([0.6, -0.4]), 0.1, 0.1  # what the floor must find
    gt = np.arange(0.0, 599.0, 0.2)
    x, y, ph = (np.interp(gt - lag, t, pose[:, k]) for k in range(3))  # the GPS lags by `lag`
    ant = np.stack(
        [x + np.cos(ph) * offset[0] - np.sin(ph) * offset[1], y + np.sin(ph) * offset[0] + np.cos(ph) * offset[1]], 1
    )
    # gps.dat frame: the fixed frame (rotation -35.4 + 33 = -2.4 deg from it) is off by delta
    g = ant @ rotation_matrix(2.4 + delta).T + np.array([40.0, -7.0]) + sigma * rng.standard_normal(ant.shape)
    jumps = np.arange(200, g.shape[0], 500)
    g[jumps] += np.array([5.0, 0.0])
    # and one isolated fix 100 m off between gaps of 2.2 s and 4.4 s (as at t = 1223.3 s of the
    # real log), which no window fit scores
    m = 1800
    g[m] += np.array([0.0, 100.0])
    fixes = np.delete(np.column_stack([gt, g]), np.r_[m - 10 : m, m + 1 : m + 22], axis=0)
    f = estimate_gps_floor(fixes, t, pose, rotation_deg=-35.4)

    assert f.n_jumps == len(jumps) + 1 and f.jump_offset_median == pytest.approx(5.0, abs=0.3)
    assert f.jump_offset_max == pytest.approx(100.0, abs=1.0)
    # every fix counts in the RMSE: what the jumps alone add to an exact path's
    n = fixes.shape[0]
    assert f.n_fixes == n and f.jump_rmse == pytest.approx(math.sqrt((25.0 * len(jumps) + 100.0**2) / n), rel=0.02)
    assert f.jump_rmse < f.aligned_floor < math.hypot(f.jump_rmse, 1.0) and f.fixed_floor_low >= f.aligned_floor
    assert f.white_sigma == pytest.approx(sigma, rel=0.2)
    assert np.allclose(f.antenna_offset, offset, atol=0.05) and f.clock_offset_s == pytest.approx(-lag, abs=0.02)
    for T, d, *_ in f.frame:  # the antenna offset leaks a little into the short fits
        assert d == pytest.approx(delta, abs=0.15), T
    r = np.hypot(*(fixes[:, 1:] - fixes[0, 1:]).T)
    assert f.frame_rmse_2deg == pytest.approx(2 * math.sin(math.radians(1.0)) * np.sqrt(np.mean(r**2)), rel=1e-9)
    assert f.fixed_floor_low <= f.fixed_floor_high
    # the short-term error of clean fixes: the noise plus what the offset and lag leave in a
    # window fit, far below the jumps
    w10 = next(row for row in f.local_rms if row[0] == 10.0)
    assert sigma * math.sqrt(2) * 0.8 < w10[2] < 1.0 and w10[1] > w10[2]


# --------------------------------------------------------------------------- end to end


def _csv(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


QUICK_N = min(yaml.safe_load(STUDY.read_text())["quick"]["particles"])


@pytest.fixture(scope="module")
def quick_study(tmp_path_factory):
    """The shipped quick variant on a small simulated log, NANO-SLAM and UFastSLAM at its
    smallest particle count with 2 seeds each, run as a user runs it (a fresh process). (Each
    point compiles twice, once for its batch and once for its timing process: ~15 s each.)"""
    out = tmp_path_factory.mktemp("study") / "quick"
    argv = [
        "compare",
        str(STUDY),
        "--quick",
        "--seeds",
        "2",
        "--methods",
        "NANO-SLAM",
        "UFastSLAM",
        "--particles",
        str(QUICK_N),
        "--parallel",
        "single",
        "--out",
        str(out),
    ]  # single: no batch padded to the device count
    for s in SIM + [
        "filter.row_buckets=never"
    ]:  # row buckets: the same results (to rounding), compiled once instead of thrice
        argv += ["--set", s]
    proc = subprocess.run(
        [sys.executable, "-m", "nanoslam_jax.app.cli", *argv],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return out, argv, proc


@pytest.mark.slow
def test_quick_variant_runs_end_to_end_on_a_simulated_log(quick_study):
    out, _, proc = quick_study
    raw = yaml.safe_load(STUDY.read_text())
    q, first = raw["quick"], raw["first_seed"]
    counts = [QUICK_N]
    runs = _csv(out / "runs.csv")
    assert sorted((r["method"], int(r["particles"]), int(r["seed"])) for r in runs) == sorted(
        (m, n, s) for m in ("NANO-SLAM", "UFastSLAM") for n in counts for s in (first, first + 1)
    )
    assert all(r["status"] == "ok" for r in runs)
    # each point's medians are those of its sweep's own results.csv; seconds per log from its timing row
    timing = {r["point_id"]: r for r in _csv(out / "timing.csv")}
    summary = _csv(out / "summary.csv")
    assert len(summary) == 2 and len(timing) == 2
    for s in summary:
        pid = next(r["point_id"] for r in runs if r["method"] == s["method"] and r["particles"] == s["particles"])
        own = _csv(out / "runs" / pid / "results.csv")
        for m in ("rmse_fixed", "rmse_aligned"):
            assert float(s[f"{m}_median"]) == pytest.approx(np.median([float(r[m]) for r in own]), rel=1e-12)
            assert float(s[f"{m}_worst"]) == pytest.approx(max(float(r[m]) for r in own), rel=1e-12)
        t = timing[pid]
        assert t["status"] == "ok" and 1 <= int(t["timing_runs"]) <= q["timing"]["repeats"]
        assert float(s["seconds_per_log"]) == float(t["seconds_per_log"]) > 0
        cores = available_cores()  # the timing process splits the particles as `nanoslam run` does
        assert int(t["devices"]) == (
            particle_devices("auto", int(s["particles"]), cores * DEVICES_PER_CORE) if cores > 1 else 1
        )
        times = [float(x) for x in t["runs_s"].split(";")]
        assert float(t["seconds_per_log"]) == pytest.approx(np.median(times), abs=1e-4)
    paired = _csv(out / "paired.csv")
    assert {(int(r["particles"]), r["other"], r["metric"]) for r in paired} == {
        (n, "UFastSLAM", m) for n in counts for m in ("rmse_fixed", "rmse_aligned")
    }
    for r in paired:
        assert int(r["wins"]) + int(r["losses"]) + int(r["ties"]) == int(r["pairs"]) == 2
    assert (out / "accuracy_vs_compute.png").stat().st_size > 10_000
    assert not (out / "gps_floor.md").exists()  # a simulated log's GPS is the truth: no floor
    assert "NANO-SLAM against the others" in proc.stdout and "s/log" in proc.stdout


@pytest.mark.slow
def test_a_resumed_study_reuses_every_point(quick_study):
    out, argv, _ = quick_study
    before = {p: (out / p).read_bytes() for p in ("runs.csv", "timing.csv")}
    with pytest.raises(ConfigError, match="holds a study already"):
        from nanoslam_jax.app.study import run_study

        run_study(load_study(STUDY, tuple(SIM), quick=True), out)
    proc = subprocess.run(
        [sys.executable, "-m", "nanoslam_jax.app.cli", *argv, "--resume"], capture_output=True, text=True, cwd=ROOT
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stderr.count("runs finished before") == 2 and proc.stderr.count("measured before") == 2
    assert {p: (out / p).read_bytes() for p in ("runs.csv", "timing.csv")} == before
    # Resumed for one method: every point the directory holds stays in the tables, the paired
    # comparison included.
    before["paired.csv"] = (out / "paired.csv").read_bytes()
    one = [a for a in argv if a != "NANO-SLAM"]
    proc = subprocess.run(
        [sys.executable, "-m", "nanoslam_jax.app.cli", *one, "--resume"], capture_output=True, text=True, cwd=ROOT
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stderr.count("runs finished before") == 1
    assert {p: (out / p).read_bytes() for p in ("runs.csv", "timing.csv", "paired.csv")} == before
