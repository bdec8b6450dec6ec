"""End-to-end tests of the ``nanoslam`` command line: result directories and the dead-reckoning baseline.

Runs go through :func:`nanoslam_jax.app.cli.main` in-process (one subprocess checks the console
script); its unit tests (help, usage and configuration errors, ``simulate``) are in
``tests/unit/app/test_cli.py``. The one NANO-SLAM run (the embedded default, cut to 30 s) is
shared by several tests so that the filter is compiled once.
"""

import json
import math
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from nanoslam_jax import __version__
from nanoslam_jax.app.cli import main
from nanoslam_jax.app.config import config_from_dict, load_config
from nanoslam_jax.data import load_victoria_park
from nanoslam_jax.app.experiment import load_log
from nanoslam_jax.eval.metrics import evaluate
from tests.helpers.cli import call as _call
from tests.helpers.cli import check_one_line_error as _check_one_line_error
from tests.helpers.paths import REPO_ROOT

ROOT = REPO_ROOT
DR_CONFIG = ROOT / "configs" / "dead_reckoning.yaml"
TRAJECTORY_HEADER = "t,x,y,phi,mean_x,mean_y,mean_phi"
PROTOCOL_METRICS = [
    "rmse_fixed",
    "rmse_aligned",
    "rmse_fixed_clean",
    "rmse_aligned_clean",
    "mean_error",
    "max_error",
    "final_error",
    "n_fixes",
]
STAMPED = re.compile(r"^(?P<name>.+)-\d{8}-\d{6}$")


def _metrics(d: Path) -> dict:
    return json.loads((d / "metrics.json").read_text())


def _trajectory(d: Path) -> np.ndarray:
    return np.loadtxt(d / "trajectory.csv", delimiter=",", skiprows=1, ndmin=2)


def _written_config(d: Path):
    text = (d / "config.yaml").read_text()
    first, rest = text.split("\n", 1)
    assert first.startswith("#")
    return first, config_from_dict(yaml.safe_load(rest))


def _check_result_dir(d: Path, cfg, *, filter_run: bool):
    names = {p.name for p in d.iterdir()}
    expected = {"config.yaml", "metrics.json", "trajectory.csv", "trajectory.png", "error.png"}
    if filter_run:
        expected |= {"map.csv", "ess.png"}
    assert expected <= names, names
    header, written = _written_config(d)
    assert __version__ in header and f"seed {cfg.seed}" in header
    assert written == cfg
    # the whole file also loads as YAML (the header is a comment)
    assert config_from_dict(yaml.safe_load((d / "config.yaml").read_text())) == cfg
    assert (d / "trajectory.csv").read_text().splitlines()[0] == TRAJECTORY_HEADER
    traj = _trajectory(d)
    assert traj.shape[1] == 7 and traj.shape[0] > 1
    assert np.all(np.diff(traj[:, 0]) >= 0)
    assert np.all(np.isfinite(traj))
    m = _metrics(d)
    for k in PROTOCOL_METRICS:
        assert k in m, k
    assert m["seed"] == cfg.seed
    assert m["method"] == cfg.filter.method
    version = m.get("version", m.get("versions", {}).get("nanoslam_jax"))
    assert version == __version__
    assert m["finite"] is True
    assert (d / "trajectory.png").stat().st_size > 0
    return m


# --------------------------------------------------------------------------- entry points


@pytest.mark.slow
def test_console_script_help():
    exe = Path(sys.executable).with_name("nanoslam")
    exe = str(exe) if exe.exists() else shutil.which("nanoslam")
    assert exe, "the nanoslam console script is not installed next to the interpreter nor on PATH"
    r = subprocess.run([exe, "--help"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "usage: nanoslam" in r.stdout
    assert "run" in r.stdout and "simulate" in r.stdout


# --------------------------------------------------------------------------- simulated logs


@pytest.fixture(scope="module")
def sim_dir(tmp_path_factory):
    """A simulated log written by ``nanoslam simulate --seed 3``."""
    d = tmp_path_factory.mktemp("sim") / "seed3"
    assert main(["simulate", "--out", str(d), "--seed", "3"]) == 0
    return d


@pytest.mark.slow
def test_dead_reckoning_on_a_simulated_directory(sim_dir, tmp_path, capsys):
    out = tmp_path / "dr_sim"
    rc, stdout, err = _call(capsys, ["run", DR_CONFIG, "--data", sim_dir, "--out", out, "--quiet"])
    assert rc == 0, err
    assert stdout.strip().splitlines()[-1] == str(out)
    m = _check_result_dir(out, load_config(DR_CONFIG), filter_run=False)
    assert m["data"] == str(sim_dir)
    # simulated GPS is the truth in the SLAM frame: the fixed-frame error is a plain, finite number
    assert math.isfinite(m["rmse_fixed"]) and m["rmse_fixed"] > 0
    assert m["rmse_aligned"] <= m["rmse_fixed"] + 1e-9
    assert not (out / "map.csv").exists()


@pytest.mark.slow
def test_run_data_without_a_config_reads_the_directory_as_a_log(sim_dir, tmp_path, capsys):
    out = tmp_path / "dr_noconfig"
    argv = ["run", "--data", sim_dir, "--out", out, "--quiet", "--set", "filter.method=dead_reckoning"]
    rc, _, err = _call(capsys, argv + ["--set", "data.t_end=20"])
    assert rc == 0, err
    assert "data.kind victoria_park" in err
    m = _metrics(out)
    assert m["data"] == str(sim_dir)


@pytest.mark.slow
def test_run_overwrite_replaces_an_earlier_result_directory(sim_dir, tmp_path, capsys):
    out = tmp_path / "dr"
    argv = ["run", DR_CONFIG, "--data", sim_dir, "--out", out, "--quiet", "--set", "data.t_end=20"]
    assert _call(capsys, argv)[0] == 0
    (out / "stale.png").write_text("an earlier run's figure")
    rc, _, err = _call(capsys, argv)
    _check_one_line_error(rc, err, f"--out {out}", "not empty")
    rc, _, err = _call(capsys, argv + ["--overwrite"])
    assert rc == 0, err
    assert not (out / "stale.png").exists()
    assert _metrics(out)["method"] == "dead_reckoning"


@pytest.mark.slow
def test_default_out_dir_is_named_after_the_config(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    cfg_path = tmp_path / "quick_dr.yaml"
    cfg_path.write_text("data:\n  kind: simulated\n  t_end: 20\nfilter:\n  method: dead_reckoning\n")
    rc, stdout, err = _call(capsys, ["run", cfg_path, "--quiet"])
    assert rc == 0, err
    (d,) = list((tmp_path / "results").iterdir())
    match = STAMPED.match(d.name)
    assert match and match["name"] == "quick_dr"
    assert (tmp_path / stdout.strip().splitlines()[-1]).resolve() == d.resolve()
    traj = _trajectory(d)
    assert traj[-1, 0] <= 20.0
    _check_result_dir(d, load_config(cfg_path), filter_run=False)


# --------------------------------------------------------------------------- the embedded default (NANO-SLAM)

# The short run of tests/unit/models/test_motion_models.py (SHORT): its NANO-SLAM program is shared.
DEFAULT_OVERRIDES = ["sim.duration=15", "filter.n_particles=5"]


@pytest.fixture(scope="module")
def default_run(tmp_path_factory):
    """``nanoslam run --set sim.duration=15 --set filter.n_particles=5`` without --out, in an empty cwd."""
    cwd = tmp_path_factory.mktemp("default_run")
    argv = ["run", "--quiet"] + [a for o in DEFAULT_OVERRIDES for a in ("--set", o)]
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(cwd)
        import contextlib
        import io

        buf = io.StringIO()
        with contextlib.redirect_stdout(buf):
            rc = main(argv)
    assert rc == 0
    return cwd, buf.getvalue()


@pytest.mark.slow
def test_default_run_writes_results_config_name_timestamp(default_run):
    cwd, stdout = default_run
    entries = list((cwd / "results").iterdir())
    assert len(entries) == 1
    d = entries[0]
    match = STAMPED.match(d.name)
    assert match and match["name"] == "default"
    last = stdout.strip().splitlines()[-1]
    assert (cwd / last).resolve() == d.resolve()
    summary = json.loads(stdout.strip().splitlines()[-2])
    assert "rmse_fixed" in summary


@pytest.mark.slow
def test_default_run_reports_error_against_ground_truth(default_run):
    cwd, _ = default_run
    (d,) = list((cwd / "results").iterdir())
    cfg = load_config(None, DEFAULT_OVERRIDES)
    m = _check_result_dir(d, cfg, filter_run=True)
    assert m["method"] == "nano"
    assert m["data"].startswith("simulated")
    assert math.isfinite(m["rmse_fixed"])
    # The dead-reckoning baseline on the same log is in the metrics, scored by the same protocol.
    log = load_log(cfg)
    poses = np.loadtxt(d / "trajectory.csv", delimiter=",", skiprows=1)
    assert poses.shape[0] == log.segments.time.shape[0]
    from tests.helpers.baselines import dead_reckoning_metrics

    dr = dead_reckoning_metrics(cfg, log)
    assert m["dr_rmse_fixed"] == pytest.approx(dr["rmse_fixed"], rel=1e-9)
    assert m["dr_over_slam"] == pytest.approx(dr["rmse_fixed"] / m["rmse_fixed"], rel=1e-9)
    # Map figures over the confirmed landmarks against the trees the true path could see.
    assert 0 < m["map_n_true"] < cfg.sim.n_trees and m["map_n_est"] == m["n_confirmed"] <= m["n_landmarks"]
    traj = _trajectory(d)
    assert traj[-1, 0] <= 15.0
    assert (d / "map.csv").read_text().splitlines()[0] == (
        "x,y,cov_xx,cov_xy,cov_yy,hits,misses,existence,confirmed,diameter,diameter_sd"
    )


@pytest.mark.slow
def test_set_overrides_reach_the_run(default_run):
    cwd, _ = default_run
    (d,) = list((cwd / "results").iterdir())
    _, written = _written_config(d)
    assert written.filter.n_particles == 5
    assert written.sim.duration == 15.0
    assert yaml.safe_load((d / "config.yaml").read_text())["filter"]["n_particles"] == 5
    assert _metrics(d)["n_particles"] == 5


@pytest.mark.slow
def test_the_embedded_default_beats_dead_reckoning_and_maps_the_trees(tmp_path, capsys):
    """What a new user's first command runs (``nanoslam run``, the whole embedded default): the
    output states the filter's error and dead reckoning's on the same log, SLAM is at least 5x
    better, and the map holds the observable trees with little clutter.

    Measured (seed 0): RMSE 0.70 m against dead reckoning's 43.08 m (61.7x); after the
    trajectory's alignment 99 % of the observable trees have a confirmed landmark within 1 m and
    1 % of the confirmed landmarks have no tree (82 % and 18 % in the SLAM frame). Over 32 runs
    (simulated logs of sim.seed 0-7 x 4 filter seeds): RMSE median 1.01 m (IQR 0.62-1.62, worst
    5.13), dead reckoning 37-49 m, at least 7.9x better in every run; RMSE < 2 m, found >= 90 % and
    spurious <= 10 % (aligned) each hold in 27 of 32 runs (the misses are runs whose map closed the
    second lap at an offset). The bounds below are those thresholds: seed 0 clears them by 2.9x in
    RMSE and should on any CPU whose rounding leaves this run as it is here (CI's does).
    """
    out = tmp_path / "default"
    rc, stdout, _ = _call(capsys, ["run", "--quiet", "--out", out])
    assert rc == 0
    first = stdout.strip().splitlines()[0]
    assert first.startswith("nano: RMSE ") and "dead reckoning on the same log" in first
    m = _metrics(out)
    assert m["dr_rmse_fixed"] > 30.0  # the simulated odometry drifts like a real vehicle's
    assert m["dr_over_slam"] >= 5.0, m["dr_over_slam"]
    assert m["rmse_fixed"] < 2.0, m["rmse_fixed"]
    assert m["landmark_overflow"] == 0
    assert m["map_found_fraction_aligned"] >= 0.9 and m["map_spurious_fraction_aligned"] <= 0.1, m


# --------------------------------------------------------------------------- dead reckoning on the real log


@pytest.fixture(scope="module")
def dr_real(vp_dir, tmp_path_factory):
    out = tmp_path_factory.mktemp("dr_real") / "out"
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = main(["run", str(DR_CONFIG), "--data", str(vp_dir), "--out", str(out), "--quiet"])
    assert rc == 0
    return out, buf.getvalue()


@pytest.mark.slow
def test_dead_reckoning_result_directory(dr_real, vp_dir):
    out, stdout = dr_real
    assert stdout.strip().splitlines()[-1] == str(out)
    m = _check_result_dir(out, load_config(DR_CONFIG), filter_run=False)
    assert m["method"] == "dead_reckoning"
    assert m["data"] == str(vp_dir)
    assert m["n_fixes"] > 4000
    traj = _trajectory(out)
    # the reported estimate and the mean coincide for dead reckoning; it starts at the origin
    np.testing.assert_array_equal(traj[:, 1:4], traj[:, 4:7])
    np.testing.assert_allclose(traj[0, 1:4], 0.0, atol=1e-9)


@pytest.mark.slow
def test_dead_reckoning_metrics_match_the_trajectory(dr_real, vp_dir):
    out, _ = dr_real
    m, traj = _metrics(out), _trajectory(out)
    raw = load_victoria_park(vp_dir)
    e = evaluate(traj[:, 0], traj[:, 1:3], raw.gps)
    for k in ("rmse_fixed", "rmse_aligned", "max_error", "final_error"):
        assert e[k] == pytest.approx(m[k], abs=1e-3), k
    assert e["n_fixes"] == m["n_fixes"]


@pytest.mark.slow
def test_dead_reckoning_stays_near_gps_for_80_seconds(dr_real, vp_dir):
    out, _ = dr_real
    traj = _trajectory(out)
    early = traj[traj[:, 0] <= 80.0]
    raw = load_victoria_park(vp_dir)
    e = evaluate(early[:, 0], early[:, 1:3], raw.gps)
    # measured: rmse_aligned 1.51 m, rmse_fixed 2.69 m, max 4.5 m (the fixed frame's rotation is uncertain by ~2 deg)
    assert e["n_fixes"] > 200
    assert e["rmse_aligned"] < 2.5
    assert e["rmse_fixed"] < 3.5
    assert e["max_error"] < 6.0


@pytest.mark.slow
def test_dead_reckoning_drifts_to_order_150_m_over_the_run(dr_real):
    out, _ = dr_real
    m = _metrics(out)
    # measured: rmse_fixed 149.3 m
    assert 100.0 < m["rmse_fixed"] < 200.0
    assert m["max_error"] > m["rmse_fixed"]


@pytest.mark.slow
def test_nasrukf_run_writes_the_result_directory(tmp_path, capsys):
    """``nanoslam run --set filter.method=nasrukf`` on a simulated log: the same result directory,
    metrics and figures as the particle methods, without the ESS figure (no particles)."""
    out = tmp_path / "nasrukf"
    # the simulated run of tests/unit/methods/test_nasrukf.py (SIM, chunks of CHUNK segments): its program is shared
    overrides = ["sim.duration=60", "filter.method=nasrukf", "filter.capacity=256", "data.k_max=12", "output.chunk=100"]
    rc, _, err = _call(capsys, ["run", "--out", str(out), "--quiet"] + [a for o in overrides for a in ("--set", o)])
    assert rc == 0, err
    m = _check_result_dir(out, load_config(None, overrides), filter_run=False)
    assert m["method"] == "nasrukf" and m["capacity"] == 256
    assert m["rmse_fixed"] < 0.5 and m["n_landmarks"] > 10 and m["resample_count"] == 0
    assert (out / "map.csv").read_text().splitlines()[0].startswith("x,y,cov_xx,cov_xy,cov_yy,hits,")
    assert not (out / "ess.png").exists()
