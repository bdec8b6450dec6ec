"""Tests of the ``nanoslam`` command line that run no filter: help, usage and configuration errors
(one line each), ``nanoslam simulate``.

Runs go through :func:`nanoslam_jax.app.cli.main` in-process. The end-to-end runs of the command
(result directories, the embedded default, dead reckoning on the real log) are in
``tests/e2e/test_cli.py``.
"""

import shutil

import pytest

from nanoslam_jax.app.cli import main
from nanoslam_jax.app.config import load_config
from nanoslam_jax.data import load_victoria_park
from tests.helpers.cli import SIM_FILES
from tests.helpers.cli import call as _call
from tests.helpers.cli import check_one_line_error as _check_one_line_error
from tests.helpers.paths import REPO_ROOT

ROOT = REPO_ROOT
DR_CONFIG = ROOT / "configs" / "dead_reckoning.yaml"


# --------------------------------------------------------------------------- entry points


@pytest.mark.parametrize(
    "command, options", [("run", ["--out", "--data", "--set"]), ("simulate", ["--out", "--seed", "--set"])]
)
def test_subcommand_help(capsys, command, options):
    with pytest.raises(SystemExit) as e:
        main([command, "--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert f"usage: nanoslam {command}" in out
    for opt in options:
        assert opt in out


def test_missing_or_unknown_command_is_a_usage_error(capsys):
    for argv in ([], ["fly"], ["run", "--bogus"]):
        with pytest.raises(SystemExit) as e:
            main(argv)
        assert e.value.code == 2
    assert "usage: nanoslam" in capsys.readouterr().err


# --------------------------------------------------------------------------- errors, one line each


@pytest.mark.parametrize(
    "argv, fragments",
    [
        (["run", "--set", "filter.n_partcles=3"], ["filter.n_partcles"]),
        (["run", "--set", "filter.n_particles=0"], ["filter.n_particles"]),
        (["run", "--set", "filter.n_particles=2.5"], ["filter.n_particles", "integer"]),
        (["run", "--set", "filter.method=foo"], ["filter.method", "'nano'", "'dead_reckoning'"]),
        (["run", "--set", "filter.n_particles"], ["key=value"]),
        (["run", "no_such_config.yaml"], ["no_such_config.yaml"]),
        (["simulate", "--out", "sim", "--set", "sim.n_tres=3"], ["sim.n_tres"]),
        (["simulate", "--out", "sim", "--seed", "-1"], ["sim.seed"]),
    ],
)
def test_config_errors_exit_2_with_one_line(capsys, tmp_path, monkeypatch, argv, fragments):
    monkeypatch.chdir(tmp_path)
    rc, out, err = _call(capsys, argv)
    _check_one_line_error(rc, err, *fragments)
    assert not (tmp_path / "sim").exists()


def test_invalid_yaml_through_the_cli(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    bad = tmp_path / "bad.yaml"
    bad.write_text("filter:\n  n_particles: 3\n   method: nano\n")
    rc, _, err = _call(capsys, ["run", bad])
    _check_one_line_error(rc, err, "bad.yaml", "line 3")


def test_missing_data_dir_exits_2_and_says_how_to_get_the_log(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    rc, _, err = _call(capsys, ["run", DR_CONFIG, "--data", "/nonexistent", "--out", tmp_path / "out", "--quiet"])
    _check_one_line_error(rc, err, "/nonexistent", "Victoria Park", "--data", "NANOSLAM_DATA")


@pytest.mark.parametrize(
    "files, fragments",
    [
        ((), ["--data", "no known log", "data.kind", "data.format"]),
        (("Barcodes.dat",), ["--data", "MRCLAM", "data.format: mrclam", "configs/mrclam.yaml"]),
        (("inputs.dat", "truth_walls.csv"), ["--data", "indoor", "data.kind: indoor"]),
    ],
)
def test_run_data_without_a_config_refuses_a_directory_it_cannot_read(capsys, tmp_path, files, fragments):
    log = tmp_path / "log"
    log.mkdir()
    for name in files:
        (log / name).write_text("")
    rc, _, err = _call(capsys, ["run", "--data", log, "--out", tmp_path / "out", "--quiet"])
    _check_one_line_error(rc, err, str(log), *fragments)
    assert not (tmp_path / "out").exists()


def test_run_data_with_a_simulated_config_is_refused(capsys, tmp_path):
    cfg = tmp_path / "sim.yaml"
    cfg.write_text("data:\n  kind: simulated\n")
    rc, _, err = _call(capsys, ["run", cfg, "--data", tmp_path, "--out", tmp_path / "out", "--quiet"])
    _check_one_line_error(rc, err, f"--data {tmp_path}", "sim.yaml", "data.kind simulated")
    # no config, data.format given but not data.kind: the embedded default's kind is refused, not guessed
    rc, _, err = _call(capsys, ["run", "--data", tmp_path, "--set", "data.format=mrclam", "--quiet"])
    _check_one_line_error(rc, err, f"--data {tmp_path}", "data.kind simulated", "--set data.kind=victoria_park")


def test_run_out_in_the_way_is_refused_before_the_run(capsys, tmp_path):
    blocker = tmp_path / "blocker"
    blocker.write_text("keep me")
    # the --out check comes first: the missing log is not even looked for
    argv = ["run", DR_CONFIG, "--data", "/nonexistent", "--quiet"]
    rc, _, err = _call(capsys, argv + ["--out", blocker])
    _check_one_line_error(rc, err, f"--out {blocker}", "a file of that name exists")
    assert blocker.read_text() == "keep me"
    used = tmp_path / "used"
    used.mkdir()
    (used / "notes.txt").write_text("mine")
    rc, _, err = _call(capsys, argv + ["--out", used])
    _check_one_line_error(rc, err, f"--out {used}", "not empty", "--overwrite")
    rc, _, err = _call(capsys, argv + ["--out", used, "--overwrite"])
    _check_one_line_error(rc, err, f"--out {used}", "--overwrite", "not one")
    assert {p.name for p in used.iterdir()} == {"notes.txt"}


@pytest.fixture(scope="module")
def sim_dir(tmp_path_factory):
    """A simulated log written by ``nanoslam simulate --seed 3``."""
    d = tmp_path_factory.mktemp("sim") / "seed3"
    assert main(["simulate", "--out", str(d), "--seed", "3"]) == 0
    return d


def test_corrupted_measurements_exit_2_naming_file_and_line(capsys, tmp_path, sim_dir):
    bad = tmp_path / "bad_log"
    shutil.copytree(sim_dir, bad)
    lines = (bad / "measurements.dat").read_text().splitlines(keepends=True)
    lines[2] = " ".join(lines[2].split()[:3]) + "\n"  # line 3: three columns instead of four
    (bad / "measurements.dat").write_text("".join(lines))
    rc, _, err = _call(capsys, ["run", DR_CONFIG, "--data", bad, "--out", tmp_path / "out", "--quiet"])
    _check_one_line_error(rc, err, "measurements.dat", "line 3")


# --------------------------------------------------------------------------- simulate


def test_simulate_writes_a_loadable_log(sim_dir, capsys):
    for name in SIM_FILES:
        assert (sim_dir / name).is_file() and (sim_dir / name).stat().st_size > 0, name
    raw = load_victoria_park(sim_dir)
    assert raw.dr.shape[1] == 3 and raw.dr.shape[0] > 100
    assert raw.detections.shape[1] == 4 and raw.detections.shape[0] > 100
    assert raw.gps.shape[1] == 3 and raw.gps.shape[0] > 10
    assert raw.truth_poses is not None and raw.truth_landmarks is not None
    assert raw.truth_landmarks.shape == (load_config().sim.n_trees, 2)


def test_simulate_is_reproducible_and_seeded(sim_dir, tmp_path, capsys):
    rc, out, _ = _call(capsys, ["simulate", "--out", tmp_path / "again", "--seed", "3"])
    assert rc == 0 and "seed 3" in out
    for name in SIM_FILES:
        assert (tmp_path / "again" / name).read_bytes() == (sim_dir / name).read_bytes(), name
    rc, out, _ = _call(capsys, ["simulate", "--out", tmp_path / "other", "--seed", "4"])
    assert rc == 0 and "seed 4" in out
    assert (tmp_path / "other" / "measurements.dat").read_bytes() != (sim_dir / "measurements.dat").read_bytes()


def test_simulate_set_overrides_reach_the_simulator(tmp_path, capsys):
    rc, _, _ = _call(
        capsys, ["simulate", "--out", tmp_path / "s", "--set", "sim.n_trees=40", "--set", "sim.duration=30"]
    )
    assert rc == 0
    raw = load_victoria_park(tmp_path / "s")
    assert raw.truth_landmarks.shape == (40, 2)
    assert raw.dr[-1, 0] - raw.dr[0, 0] <= 31.0
