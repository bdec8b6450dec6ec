"""Tests of the Victoria Park log loader and writer."""

import os
from pathlib import Path

import numpy as np
import pytest
import scipy.io

from nanoslam_jax.data import LogFormatError, RawLog, load_victoria_park, write_victoria_park

ASCII_FILES = ("inputs.dat", "measurements.dat", "gps.dat")

INPUTS = "1.0 0.5 -0.01\n1.025 0.6 0.0\n1.05 0.7 0.02\n"
MEASUREMENTS = "1.01 10.0 1.5707963267948966 0.3\n1.01 20.0 0.0 0.2\n1.04 5.0 3.14159 0.1\n"
GPS = "0.9 1.0 2.0\n1.1 1.5 2.5\n"


def write_log(directory: Path, **files: str) -> Path:
    """Write a tiny ASCII log: the three default files, replaced or extended by ``files``."""
    contents = {"inputs.dat": INPUTS, "measurements.dat": MEASUREMENTS, "gps.dat": GPS}
    contents.update({name.replace("_dat", ".dat"): text for name, text in files.items()})
    directory.mkdir(parents=True, exist_ok=True)
    for name, text in contents.items():
        if text is not None:
            (directory / name).write_text(text)
    return directory


def link_files(src: Path, dst: Path, names) -> Path:
    """A directory holding symbolic links to some files of ``src``."""
    dst.mkdir()
    for name in names:
        os.symlink(src / name, dst / name)
    return dst


# --------------------------------------------------------------------------- the real log


@pytest.fixture(scope="module")
def real(vp_dir):
    return load_victoria_park(vp_dir)


def test_real_log_counts(real):
    """Counts of the real log as its data README gives them."""
    assert real.dr.shape == (61945, 3)
    assert real.dr[0, 0] == pytest.approx(0.973)
    assert real.dr[-1, 0] == pytest.approx(1549.573)
    assert np.allclose(np.diff(real.dr[:, 0]), 0.025, atol=1e-9)
    assert real.detections.shape == (52974, 4)
    times, counts = np.unique(real.detections[:, 0], return_counts=True)
    assert times.size == 7230 and real.scan_times.size == 7230
    assert counts.max() == 18
    assert real.gps.shape == (4466, 3)
    assert real.truth_poses is None and real.truth_landmarks is None


def test_real_bearings_in_vehicle_frame(real):
    """Bearings are file bearing - pi/2, inside (-pi, pi]; the first row is 0.88575 in the file."""
    bearing = real.detections[:, 2]
    assert np.all((bearing > -np.pi) & (bearing <= np.pi))
    assert bearing[0] == pytest.approx(0.88575 - np.pi / 2, abs=1e-12)
    assert real.detections[0, 1] == pytest.approx(20.46202)


def test_mat_matches_ascii(vp_dir, real):
    """The MATLAB files agree with the ASCII files to the ASCII files' printed precision."""
    mat = load_victoria_park(vp_dir, format="mat")
    assert mat.dr.shape == real.dr.shape and mat.gps.shape == real.gps.shape
    # inputs.dat prints time and speed with 3 decimals, steering with 4; gps.dat 3 decimals.
    assert np.allclose(mat.dr[:, 0], real.dr[:, 0], rtol=0, atol=1e-9)
    assert np.allclose(mat.dr[:, 1], real.dr[:, 1], rtol=0, atol=5e-4 + 1e-9)
    assert np.allclose(mat.dr[:, 2], real.dr[:, 2], rtol=0, atol=5e-5 + 1e-9)
    assert np.allclose(mat.gps[:, 0], real.gps[:, 0], rtol=0, atol=1e-9)
    assert np.allclose(mat.gps[:, 1:], real.gps[:, 1:], rtol=0, atol=5e-4 + 1e-9)
    assert np.array_equal(mat.detections, real.detections)


def test_auto_reads_a_directory_of_only_ascii_files(vp_dir, real, tmp_path):
    log = load_victoria_park(link_files(vp_dir, tmp_path / "log", ASCII_FILES))
    assert np.array_equal(log.dr, real.dr) and np.array_equal(log.gps, real.gps)


def test_auto_falls_back_to_mat_files(vp_dir, tmp_path):
    log = load_victoria_park(link_files(vp_dir, tmp_path / "log", ("aa3_dr.mat", "aa3_gpsx.mat", "measurements.dat")))
    assert np.array_equal(log.dr, load_victoria_park(vp_dir, format="mat").dr)


# --------------------------------------------------------------------------- tiny logs


def test_tiny_log_with_comments_and_truth(tmp_path):
    directory = write_log(
        tmp_path,
        inputs_dat="# time speed steering\n\n" + INPUTS + "\n",
        truth_poses_dat="1.0 0 0 0.1\n1.05 0.1 0.0 0.2  # trailing comment\n",
        truth_landmarks_dat="3 4\n5 6\n7 8\n",
        truth_diameters_dat="0.2\n0.3\n0.4\n",
    )
    log = load_victoria_park(directory)
    assert np.array_equal(log.dr, [[1.0, 0.5, -0.01], [1.025, 0.6, 0.0], [1.05, 0.7, 0.02]])
    assert np.allclose(log.detections[:, 2], [0.0, -np.pi / 2, 3.14159 - np.pi / 2], atol=1e-15)
    assert np.array_equal(log.detections[:, [0, 1, 3]], [[1.01, 10.0, 0.3], [1.01, 20.0, 0.2], [1.04, 5.0, 0.1]])
    assert np.array_equal(log.gps, [[0.9, 1.0, 2.0], [1.1, 1.5, 2.5]])
    assert np.array_equal(log.truth_poses, [[1.0, 0, 0, 0.1], [1.05, 0.1, 0.0, 0.2]])
    assert log.truth_landmarks.shape == (3, 2)
    assert np.array_equal(log.truth_diameters, [0.2, 0.3, 0.4])
    assert log.source == str(directory)


def test_bearings_outside_zero_to_pi_are_refused_naming_the_first_line(tmp_path):
    """File bearings are radians in [0, pi]: a file in degrees (or another convention) is refused
    at its first offending line; a bearing just past either edge (within 0.01) is read."""
    degrees = "# in degrees\n1.0 5.0 90.0 0.1\n1.0 6.0 1.2 0.1\n1.1 5.0 135.0 0.1\n"
    with pytest.raises(LogFormatError, match=r"measurements\.dat line 2: expected a bearing in radians in \[0, pi\]"):
        load_victoria_park(write_log(tmp_path / "deg", measurements_dat=degrees))
    below = f"1.0 5.0 1.0 0.1\n1.0 5.0 {-0.5 * np.pi!r} 0.1\n"
    with pytest.raises(LogFormatError, match=r"measurements\.dat line 2: .* got -1\.57.*\(1 of 2 rows outside"):
        load_victoria_park(write_log(tmp_path / "below", measurements_dat=below))
    edges = f"1.0 5.0 -0.005 0.1\n1.0 5.0 {np.pi + 0.005!r} 0.1\n"
    log = load_victoria_park(write_log(tmp_path / "edges", measurements_dat=edges))
    np.testing.assert_allclose(log.detections[:, 2], [-0.5 * np.pi - 0.005, 0.5 * np.pi + 0.005])


def test_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    dr = np.column_stack([0.5 + 0.025 * np.arange(50), rng.normal(3, 1, 50), rng.normal(0, 0.1, 50)])
    det_t = np.repeat(0.6 + 0.2 * np.arange(5), 3)
    det = np.column_stack([det_t, rng.uniform(1, 30, 15), rng.uniform(-1.57, 1.57, 15), rng.uniform(0.1, 1, 15)])
    gps = np.column_stack([0.2 * np.arange(8), rng.normal(0, 10, (8, 2))])
    truth_poses = np.column_stack([det_t[::3], rng.normal(0, 10, (5, 2)), rng.uniform(-3, 3, 5)])
    truth_landmarks = rng.normal(0, 50, (7, 2))
    raw = RawLog(dr=dr, detections=det, gps=gps, truth_poses=truth_poses, truth_landmarks=truth_landmarks)

    write_victoria_park(tmp_path / "log", raw)
    back = load_victoria_park(tmp_path / "log")
    for name in ("dr", "detections", "gps", "truth_poses", "truth_landmarks"):
        assert np.allclose(getattr(back, name), getattr(raw, name), rtol=0, atol=1e-9), name
    file_bearing = np.loadtxt(tmp_path / "log" / "measurements.dat")[:, 2]
    assert np.allclose(file_bearing, det[:, 2] + np.pi / 2, rtol=0, atol=1e-9)  # file convention


def test_write_rejects_wrong_shape(tmp_path):
    raw = RawLog(dr=np.zeros((3, 2)), detections=np.zeros((1, 4)), gps=np.zeros((1, 3)))
    with pytest.raises(ValueError, match=r"inputs\.dat.*\(n, 3\)"):
        write_victoria_park(tmp_path, raw)


# --------------------------------------------------------------------------- errors


def test_missing_directory(tmp_path):
    with pytest.raises(FileNotFoundError, match="nowhere.*inputs.dat.*aa3_dr.mat"):
        load_victoria_park(tmp_path / "nowhere")


def test_missing_file(tmp_path):
    directory = write_log(tmp_path, gps_dat=None)
    with pytest.raises(FileNotFoundError, match=r"gps\.dat or aa3_gpsx\.mat not found"):
        load_victoria_park(directory)
    with pytest.raises(FileNotFoundError, match=r"aa3_dr\.mat not found"):
        load_victoria_park(directory, format="mat")


def test_unknown_format(tmp_path):
    with pytest.raises(ValueError, match="format"):
        load_victoria_park(write_log(tmp_path), format="csv")


@pytest.mark.parametrize(
    "files, pattern",
    [
        # wrong column count; the comment and blank line still count as lines
        (
            dict(measurements_dat="# header\n\n1.0 5.0 1.0 0.1\n1.1 5.0 1.0\n"),
            r"measurements\.dat line 4: expected 4 numeric columns \(time range bearing diameter\), got 3",
        ),
        (
            dict(inputs_dat="1.0 0.5 0.1 7\n1.1 0.5 0.1 7\n"),
            r"inputs\.dat line 1: expected 3 numeric columns \(time speed steering\), got 4",
        ),
        (
            dict(gps_dat="0.9 1.0 2.0\n1.0 1.0 abc\n"),
            r"gps\.dat line 2: expected 3 numeric columns .* non-numeric 'abc' in column 'y'",
        ),
        (
            dict(inputs_dat="1.0 0.5 0.1\n1.1 nan 0.1\n"),
            r"inputs\.dat line 2: expected finite numbers, got nan in column 'speed'",
        ),
        (
            dict(measurements_dat="1.0 5.0 1.0 0.1\n\n1.1 inf 1.0 0.1\n"),
            r"measurements\.dat line 3: expected finite numbers, got inf in column 'range'",
        ),
        (
            dict(inputs_dat="1.0 0.5 0.1\n1.1 0.5 0.1\n1.05 0.5 0.1\n"),
            r"inputs\.dat line 3: dead-reckoning times must be strictly increasing, got 1\.05 after 1\.1 \(line 2\)",
        ),
        (
            dict(inputs_dat="1.0 0.5 0.1\n1.0 0.5 0.1\n"),
            r"inputs\.dat line 2: dead-reckoning times must be strictly increasing",
        ),
        (
            dict(measurements_dat="1.0 5.0 1.0 0.1\n1.0 6.0 1.0 0.1\n0.9 5.0 1.0 0.1\n"),
            r"measurements\.dat line 3: detection times must be non-decreasing",
        ),
        (dict(gps_dat="0.9 1.0 2.0\n0.9 1.0 2.0\n"), r"gps\.dat line 2: GPS times must be strictly increasing"),
        (
            dict(measurements_dat="1.0 5.0 1.0 0.1\n1.0 -0.5 1.0 0.1\n"),
            r"measurements\.dat line 2: expected a range >= 0, got -0\.5",
        ),
        (
            dict(measurements_dat="# only a comment\n\n"),
            r"measurements\.dat: no data rows; expected lines of time range bearing diameter",
        ),
        (dict(gps_dat=""), r"gps\.dat: no data rows"),
        (dict(truth_landmarks_dat="1 2\n3\n"), r"truth_landmarks\.dat line 2: expected 2 numeric columns"),
    ],
)
def test_format_errors_name_file_and_line(tmp_path, files, pattern):
    with pytest.raises(LogFormatError, match=pattern):
        load_victoria_park(write_log(tmp_path, **files))


def test_binary_file(tmp_path):
    directory = write_log(tmp_path)
    (directory / "inputs.dat").write_bytes(b"\xff\xfe\x00\x81")
    with pytest.raises(LogFormatError, match=r"inputs\.dat: not a text file"):
        load_victoria_park(directory)


def test_mat_errors(tmp_path):
    directory = write_log(tmp_path)
    gps = dict(timeGps=[[20967], [21967]], La_m=[[0.0], [1.0]], Lo_m=[[0.0], [1.0]])
    scipy.io.savemat(directory / "aa3_gpsx.mat", gps)
    dr = dict(time=[[1000], [900]], speed=[[0.0], [1.0]])
    scipy.io.savemat(directory / "aa3_dr.mat", dr)
    with pytest.raises(LogFormatError, match=r"aa3_dr\.mat: expected variables time, speed, steering; missing steer"):
        load_victoria_park(directory, format="mat")
    scipy.io.savemat(directory / "aa3_dr.mat", dict(dr, steering=[[0.0], [0.1]]))
    with pytest.raises(LogFormatError, match=r"aa3_dr\.mat row 2: dead-reckoning times must be strictly increasing"):
        load_victoria_park(directory, format="mat")
    (directory / "aa3_dr.mat").write_text("not a mat file")
    with pytest.raises(LogFormatError, match=r"aa3_dr\.mat: not a readable MATLAB file"):
        load_victoria_park(directory, format="mat")


def test_mat_gps_conversion(tmp_path):
    """(x, y) = R(-33 deg) (Lo_m + 67, La_m + 39) and t = (t_ms - 20967) / 1000."""
    directory = write_log(tmp_path)
    scipy.io.savemat(
        directory / "aa3_gpsx.mat", dict(timeGps=[[20967], [21968]], Lo_m=[[-66.0], [-67.0]], La_m=[[-39.0], [-38.0]])
    )
    (directory / "gps.dat").unlink()
    gps = load_victoria_park(directory).gps
    c, s = np.cos(np.radians(33)), np.sin(np.radians(33))
    assert np.allclose(gps, [[0.0, c, -s], [1.001, s, c]], atol=1e-12)
