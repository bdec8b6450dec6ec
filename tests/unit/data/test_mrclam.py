"""UTIAS MRCLAM: the loader on files written here and on the real dataset, the map metric after a
rigid alignment against a closed form, the exact unicycle dead reckoning against the circle, and the
dead-reckoning map baseline against the dataset README's figures."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from nanoslam_jax.app.config import ConfigError, load_config, resolve_data_dir
from nanoslam_jax.data import LogFormatError, LogWarning, RawLog, dead_reckoning_map, load_mrclam, unicycle_poses
from nanoslam_jax.eval.metrics import map_alignment_metrics, rotation_matrix
from tests.helpers.paths import REPO_ROOT, SHARED_DATA

MRCLAM_DIR = SHARED_DATA / "utias_mrclam" / "MRCLAM_Dataset1"
HEADER = "# UTIAS Multi-Robot Cooperative Localization and Mapping Dataset\n# written by the test\n"
MRCLAM_CFG = ["data.kind=victoria_park", "data.format=mrclam", "model.motion=unicycle"]


def write_dataset(d: Path, measurements: str | None = None) -> Path:
    """A small dataset: robots 1-2 (barcodes 5, 14), landmarks 6-8 (barcodes 72, 27, 54)."""
    d.mkdir(parents=True, exist_ok=True)
    (d / "Barcodes.dat").write_text(
        HEADER + "# Subject #    Barcode #\n  1 \t 5\n  2 \t 14\n\n  6 \t 72\n  7 \t 27\n  8 \t 54\n"
    )
    (d / "Landmark_Groundtruth.dat").write_text(
        HEADER + "  6 \t 1.5 \t 2.0 \t 0.001 \t 0.001\n"
        "  8 \t -3.25 \t 0.5 \t 0.001 \t 0.002\n"
        "  7 \t 4.0 \t -1.0 \t 0.001 \t 0.001\n"
    )
    # times repeated (1002.0 twice: the last holds)
    (d / "Robot1_Odometry.dat").write_text(
        HEADER + "1000.5 \t 0.1 \t 0.0\n1001.0 \t 0.2 \t 0.1\n"
        "1002.0 \t 0.9 \t 0.9\n1002.0 \t 0.3 \t -0.2   # a comment\n"
        "1003.0 \t 0.0 \t 0.0\n"
    )
    if measurements is None:
        measurements = (
            "1000.25 \t 72 \t 1.0 \t 0.1\n"  # before the first odometry sample: dropped
            "1001.5 \t 27 \t 2.0 \t 0.2\n"
            "1001.5 \t 5 \t 3.0 \t 0.0\n"  # robot 1 (subject 1): dropped
            "1001.5 \t 72 \t 2.5 \t -0.3\n"
            "1001.0 \t 54 \t 4.0 \t 3.5\n"  # earlier than the rows above; bearing wrapped
            "1002.5 \t 14 \t 1.0 \t 0.0\n"  # robot 2: dropped
            "1002.5 \t 54 \t 1.25 \t -0.5\n"
        )
    (d / "Robot1_Measurement.dat").write_text(HEADER + measurements)
    return d


# --------------------------------------------------------------------------- the loader


def test_loader_maps_barcodes_sorts_and_drops(tmp_path):
    raw = load_mrclam(write_dataset(tmp_path / "ds"), robot=1)
    # odometry: t0 = 1000.5 (the first odometry time), the last of the rows at 1002.0 kept
    np.testing.assert_allclose(raw.dr, [[0.0, 0.1, 0.0], [0.5, 0.2, 0.1], [1.5, 0.3, -0.2], [2.5, 0.0, 0.0]])
    # measurements: sorted by time, equal times in file order, robots and the early row dropped
    np.testing.assert_allclose(
        raw.detections,
        [[0.5, 4.0, 3.5 - 2 * math.pi, 0.0], [1.0, 2.0, 0.2, 0.0], [1.0, 2.5, -0.3, 0.0], [2.0, 1.25, -0.5, 0.0]],
        atol=1e-12,
    )
    np.testing.assert_array_equal(raw.detection_ids, [2, 1, 0, 2])  # subjects 8, 7, 6, 8 -> ids 2, 1, 0, 2
    np.testing.assert_array_equal(raw.landmark_ids, [0, 2, 1])  # file order of Landmark_Groundtruth.dat
    np.testing.assert_allclose(raw.truth_landmarks, [[1.5, 2.0], [-3.25, 0.5], [4.0, -1.0]])
    assert raw.gps.shape == (0, 3) and raw.truth_poses is None
    assert "robot 1" in raw.source


def test_loader_unknown_barcode_dropped_or_named(tmp_path):
    rows = "1001.0 \t 27 \t 2.0 \t 0.2\n1001.5 \t 43 \t 2.0 \t 0.1\n1002.0 \t 72 \t 1.0 \t 0.0\n"
    d = write_dataset(tmp_path / "ds", rows + "1002.5 \t 43 \t 2.0 \t 0.1\n1003.0 \t 99 \t 1.0 \t 0.0\n")
    with pytest.warns(LogWarning) as record:
        raw = load_mrclam(d, 1)
    (w,) = record
    message = str(w.message)
    assert "Robot1_Measurement.dat" in message and "Barcodes.dat" in message
    assert "3 sighting(s)" in message and "43 (2x), 99 (1x)" in message
    np.testing.assert_array_equal(raw.detection_ids, [1, 0])
    with pytest.raises(LogFormatError, match=r"Robot1_Measurement\.dat line 4: barcode 43 is not listed"):
        load_mrclam(d, 1, unknown_barcodes="error")


def test_loader_refuses_odometry_out_of_time_order(tmp_path):
    d = write_dataset(tmp_path / "ds")
    (d / "Robot1_Odometry.dat").write_text(HEADER + "1000.5 0.1 0.0\n1001.0 0.2 0.1\n1000.75 0.3 0.0\n")
    # HEADER is two lines: the third data row is line 5
    with pytest.raises(LogFormatError, match=r"Robot1_Odometry\.dat line 5: odometry times must be non-decreasing"):
        load_mrclam(d, 1)


def test_loader_without_sightings(tmp_path):
    raw = load_mrclam(write_dataset(tmp_path / "ds", "# nothing seen\n"), 1)
    assert raw.detections.shape == (0, 4) and raw.detection_ids.shape == (0,)


@pytest.mark.parametrize(
    "name, text, message",
    [
        (
            "Robot1_Measurement.dat",
            "1001.0 \t 27 \t 2.0 \t 0.2\n1001.5 \t 72 \t 2.0\n",
            r"Robot1_Measurement\.dat line 4: expected 4 numeric columns \(time barcode range bearing\), got 3",
        ),
        (
            "Robot1_Measurement.dat",
            "1001.0 \t 27 \t 2.0 \t 0.2\n1001.5 \t 72 \t two \t 0.1\n",
            r"Robot1_Measurement\.dat line 4: expected 4 numeric columns .*non-numeric 'two' in column 'range'",
        ),
        (
            "Robot1_Measurement.dat",
            "1001.0 \t 27.5 \t 2.0 \t 0.2\n",
            r"Robot1_Measurement\.dat line 3: expected a whole number >= 0 in column 'barcode', got 27\.5",
        ),
        (
            "Robot1_Measurement.dat",
            "1001.0 \t 27 \t -2.0 \t 0.2\n",
            r"Robot1_Measurement\.dat line 3: expected a range >= 0",
        ),
        (
            "Robot1_Odometry.dat",
            "1000.0 \t 0.1 \t 0.0\n1001.0 \t nan \t 0.0\n",
            r"Robot1_Odometry\.dat line 4: expected finite numbers, got nan in column 'v'",
        ),
        ("Robot1_Odometry.dat", "# only comments\n", r"Robot1_Odometry\.dat: no data rows"),
        (
            "Barcodes.dat",
            "1 \t 5\n6 \t 72\n7 \t 72\n",
            r"Barcodes\.dat line 5: barcode 72 appears again \(first on line 4\)",
        ),
        (
            "Landmark_Groundtruth.dat",
            "6 \t 1.0 \t 2.0 \t 0.0 \t 0.0\n2 \t 1.0 \t 2.0 \t 0.0 \t 0.0\n",
            r"Landmark_Groundtruth\.dat line 4: expected a whole number >= 6 \(a landmark; subjects 1-5 are the robots\) "
            r"in column 'subject', got 2$",
        ),
    ],
)
def test_malformed_file_names_file_and_line(tmp_path, name, text, message):
    d = write_dataset(tmp_path / "ds")
    (d / name).write_text(HEADER + text)
    with pytest.raises(LogFormatError, match=message) as e:
        load_mrclam(d, 1)
    assert str(d / name) in str(e.value)


def test_loader_bad_arguments(tmp_path):
    d = write_dataset(tmp_path / "ds")
    with pytest.raises(ValueError, match="robot: expected one of 1, 2, 3, 4, 5, got 6"):
        load_mrclam(d, 6)
    with pytest.raises(FileNotFoundError, match=r"Robot2_Odometry\.dat: not found"):
        load_mrclam(d, 2)
    with pytest.raises(FileNotFoundError, match="MRCLAM dataset directory not found"):
        load_mrclam(tmp_path / "missing", 1)


def test_config_keys(tmp_path, monkeypatch):
    cfg = load_config(None, MRCLAM_CFG + ["data.robot=4"])
    assert cfg.data.format == "mrclam" and cfg.data.robot == 4
    for bad in ("0", "6"):
        with pytest.raises(ConfigError, match="key 'data.robot'"):
            load_config(None, MRCLAM_CFG + [f"data.robot={bad}"])
    with pytest.raises(ConfigError, match="key 'model.motion'"):
        load_config(None, ["data.kind=victoria_park", "data.format=mrclam"])
    with pytest.raises(ConfigError, match="key 'data.detections'"):
        load_config(None, MRCLAM_CFG + ["data.detections=laser"])
    d = write_dataset(tmp_path / "ds")
    monkeypatch.setenv("NANOSLAM_DATA", str(d))
    assert resolve_data_dir(cfg) == d
    with pytest.raises(FileNotFoundError, match="UTIAS MRCLAM dataset"):
        resolve_data_dir(cfg, str(tmp_path / "missing"))


# --------------------------------------------------------------------------- dead reckoning


def test_unicycle_poses_follow_the_circle():
    """Constant (v, omega) sampled at irregular times: the pose at any time is on the circle of
    radius v / omega; omega = 0 is the straight line."""
    rng = np.random.default_rng(0)
    t = np.concatenate([[2.0], 2.0 + np.cumsum(rng.uniform(0.005, 0.3, 400))])
    q = np.concatenate([[1.0], np.sort(rng.uniform(2.0, t[-1] + 5.0, 300))])  # before, inside and after
    v, w = 0.4, 0.35
    pose = unicycle_poses(np.column_stack([t, np.full_like(t, v), np.full_like(t, w)]), q, start=(1.0, -2.0, 0.5))
    tau = np.maximum(q - 2.0, 0.0)
    x = 1.0 + v / w * (np.sin(0.5 + w * tau) - math.sin(0.5))
    y = -2.0 - v / w * (np.cos(0.5 + w * tau) - math.cos(0.5))
    np.testing.assert_allclose(pose[:, 0], x, atol=1e-9)
    np.testing.assert_allclose(pose[:, 1], y, atol=1e-9)
    np.testing.assert_allclose(np.exp(1j * pose[:, 2]), np.exp(1j * (0.5 + w * tau)), atol=1e-9)
    assert np.all(np.abs(pose[:, 2]) <= math.pi)
    straight = unicycle_poses(np.column_stack([t, np.full_like(t, v), np.zeros_like(t)]), q)
    np.testing.assert_allclose(straight, np.column_stack([v * tau, 0 * tau, 0 * tau]), atol=1e-9)


def test_dead_reckoning_map_recovers_landmarks_from_exact_sightings():
    """Sightings computed from the true circle path to known landmarks project back onto them."""
    v, w = 0.3, -0.2
    t = np.arange(0.0, 40.0, 0.05)
    dr = np.column_stack([t, np.full_like(t, v), np.full_like(t, w)])
    landmarks = np.array([[2.0, 1.0], [-1.0, -3.0], [4.0, -6.0]])
    times = np.sort(np.random.default_rng(1).uniform(0.0, 45.0, 60))
    x, y, phi = v / w * np.sin(w * times), v / w * (1 - np.cos(w * times)), w * times
    ids = np.arange(times.size) % 3
    dx, dy = landmarks[ids, 0] - x, landmarks[ids, 1] - y
    det = np.column_stack(
        [times, np.hypot(dx, dy), np.angle(np.exp(1j * (np.arctan2(dy, dx) - phi))), np.zeros_like(times)]
    )
    ids[5] = -1  # unknown: left out
    det[5, 1:3] = (7.0, 1.0)
    raw = RawLog(dr=dr, detections=det, gps=np.zeros((0, 3)), detection_ids=ids)
    m = dead_reckoning_map(raw)
    np.testing.assert_array_equal(m.ids, [0, 1, 2])
    np.testing.assert_array_equal(m.counts, [20, 20, 19])
    np.testing.assert_allclose(m.xy, landmarks, atol=1e-9)
    with pytest.raises(ValueError, match="no detection_ids"):
        dead_reckoning_map(RawLog(dr=dr, detections=det, gps=np.zeros((0, 3))))


# --------------------------------------------------------------------------- the map metric


def _moved_noisy_map(rng, truth, sigma, angle_deg, shift):
    """``(estimates, rmse)``: the truth plus noise with no mean and no net rotation about the
    centroid, so the best rigid alignment of truth + noise onto the truth is the identity and the
    RMSE after it is the noise's RMS (closed form), then moved rigidly."""
    e = rng.normal(0.0, sigma, truth.shape)
    e -= e.mean(axis=0)
    c = truth - truth.mean(axis=0)
    jc = np.column_stack([-c[:, 1], c[:, 0]])  # the direction of an infinitesimal rotation
    e -= np.sum(e * jc) / np.sum(jc * jc) * jc
    return (truth + e) @ rotation_matrix(angle_deg).T + shift, float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


@pytest.mark.parametrize("with_ids", [True, False])
def test_map_alignment_metrics_closed_form(with_ids):
    rng = np.random.default_rng(3)
    truth = rng.uniform([-2.0, -6.0], [6.0, 6.0], (15, 2))
    ids = np.arange(100, 115)
    est, rmse = _moved_noisy_map(rng, truth, 0.05, 131.0, np.array([12.0, -7.0]))
    perm = rng.permutation(15)
    est = np.vstack([est[perm], np.array([[30.0, 30.0]]) @ rotation_matrix(131.0).T])  # + a spurious one
    est_ids = np.append(ids[perm], -1) if with_ids else None
    m = map_alignment_metrics(est, truth, est_ids, ids if with_ids else None, match_radius=0.5)
    assert m["rmse"] == pytest.approx(rmse, rel=1e-9)
    assert (m["n_est"], m["n_true"], m["n_pairs"], m["n_found"], m["n_spurious"]) == (16, 15, 15, 15, 1)
    assert m["found_fraction"] == 1.0
    # the alignment is the inverse of the motion applied
    assert m["align_rotation_deg"] == pytest.approx(-131.0, abs=1e-9)
    inv = -rotation_matrix(-131.0) @ np.array([12.0, -7.0])
    np.testing.assert_allclose([m["align_x"], m["align_y"]], inv, atol=1e-9)
    pairs = m["pairs"][np.argsort(m["pairs"][:, 0])]
    np.testing.assert_array_equal(pairs, np.column_stack([np.arange(15), perm]))


def test_map_alignment_metrics_found_and_spurious_by_radius():
    """With ids, a badly placed estimate counts in the RMSE (closed form) and is spurious; its
    landmark is not found."""
    truth = np.array([[0.0, 0.0], [4.0, 0.0], [0.0, 3.0], [4.0, 3.0], [2.0, 1.5]])
    est = truth.copy()
    est[4] += (1.0, 0.0)  # the centre one off by 1 m: shifts the fitted translation by 0.2 m
    m = map_alignment_metrics(est, truth, np.arange(5), match_radius=0.5)
    # translation-only fit (the offset of the centre point exerts no torque about the centroid)
    expected = np.sqrt((4 * 0.2**2 + 0.8**2) / 5)
    assert m["rmse"] == pytest.approx(expected, rel=1e-9)
    assert (m["n_found"], m["n_spurious"]) == (4, 1)
    assert m["align_rotation_deg"] == pytest.approx(0.0, abs=1e-9)
    none = map_alignment_metrics(np.zeros((0, 2)), truth)
    assert math.isnan(none["rmse"]) and (none["n_found"], none["n_spurious"]) == (0, 0)
    with pytest.raises(ValueError, match="true_ids given without est_ids"):
        map_alignment_metrics(est, truth, None, np.arange(5))


# --------------------------------------------------------------------------- the real dataset


@pytest.fixture(scope="module")
def mrclam_dir() -> Path:
    if not (MRCLAM_DIR / "Barcodes.dat").is_file():
        pytest.skip(f"UTIAS MRCLAM dataset 1 not found at {MRCLAM_DIR}; see docs/data.md, 'UTIAS MRCLAM'")
    return MRCLAM_DIR


def test_real_log_robot_1(mrclam_dir):
    raw = load_mrclam(mrclam_dir, 1)
    # 97,890 odometry rows, none repeated; 5,723 sightings of which 952 of robots
    assert raw.dr.shape == (97890, 3) and raw.dr[0, 0] == 0.0
    assert raw.dr[-1, 0] == pytest.approx(1490.478, abs=1e-3)
    assert np.all(np.diff(raw.dr[:, 0]) > 0)
    assert raw.detections.shape == (4771, 4) and raw.detection_ids.shape == (4771,)
    assert raw.detections[0, 0] == pytest.approx(3.197, abs=1e-3)
    assert raw.detections[-1, 0] == pytest.approx(1490.302, abs=1e-3)
    assert np.all(np.diff(raw.detections[:, 0]) >= 0)
    assert np.unique(raw.detections[:, 0]).size == 3518
    assert set(np.unique(raw.detection_ids)) == set(range(15))
    np.testing.assert_array_equal(raw.landmark_ids, np.arange(15))
    assert raw.truth_landmarks[0] == pytest.approx([5.70928255, 4.96404466])
    assert np.all(np.abs(raw.detections[:, 2]) < 0.6)  # a camera's field of view


def test_real_dead_reckoning_map_as_the_readme_says(mrclam_dir):
    """The dataset README: the dead-reckoning map is 2.3-3.3 m RMSE after alignment for robots 1-5
    (to its one decimal)."""
    for robot in range(1, 6):
        raw = load_mrclam(mrclam_dir, robot)
        m = dead_reckoning_map(raw)
        rmse = map_alignment_metrics(m.xy, raw.truth_landmarks, m.ids, raw.landmark_ids)["rmse"]
        assert 2.25 <= rmse < 3.35, (robot, rmse)


@pytest.mark.slow
def test_real_log_through_the_config(mrclam_dir, tmp_path):
    """data.format: mrclam through load_log and a dead-reckoning run (no GPS: no trajectory error,
    the result directory still written)."""
    from nanoslam_jax.app.experiment import load_log, run_experiment

    cfg = load_config(
        None, MRCLAM_CFG + ["data.robot=2", "data.t_end=60", "filter.method=dead_reckoning", "output.progress=false"]
    )
    log = load_log(cfg, str(mrclam_dir))
    seg = log.segments
    assert log.raw.gps.shape == (0, 3) and "robot 2" in log.source
    ids = np.asarray(seg.z_id)[np.asarray(seg.z_mask)]
    assert ids.size == np.sum(log.raw.detections[:, 0] <= 60.0) and set(ids) <= set(range(15))
    metrics = run_experiment(cfg, tmp_path / "run", str(mrclam_dir))
    assert metrics["finite"] and "rmse_fixed" not in metrics
    assert (tmp_path / "run" / "trajectory.png").is_file() and (tmp_path / "run" / "metrics.json").is_file()


# --------------------------------------------------------------------------- SLAM on a simulated MRCLAM log


def write_simulated_dataset(d: Path, seed: int = 3) -> tuple[Path, np.ndarray]:
    """A differential-drive robot on a circle with biased, noisy odometry, seeing 8 barcoded
    landmarks with a camera (range < 9 m, +-33 deg, 2 cm / 0.5 deg noise), written in MRCLAM's
    format; the survey is in a frame of its own (the robot starts at (1.5, -0.5) facing 0.6 rad).
    Returns the directory and the surveyed positions."""
    rng = np.random.default_rng(seed)
    d.mkdir(parents=True, exist_ok=True)
    start, heading = np.array([1.5, -0.5]), 0.6
    v, w = 0.3, 0.12  # a circle of radius 2.5 m, 52 s a lap
    t = np.arange(0.0, 160.0, 0.05)
    # the truth in the robot's start frame, then moved into the survey's frame
    x, y, phi = v / w * np.sin(w * t), v / w * (1 - np.cos(w * t)), w * t
    ring = np.linspace(0, 2 * np.pi, 8, endpoint=False) + 0.3
    lm_local = np.column_stack([4.5 * np.cos(ring), v / w + 4.5 * np.sin(ring)])
    R = rotation_matrix(math.degrees(heading))
    survey = lm_local @ R.T + start
    barcodes = 60 + 3 * np.arange(8)  # subjects 6-13; subjects 1-5 are the robots
    (d / "Barcodes.dat").write_text(
        HEADER + "".join(f"{k + 1} \t {b}\n" for k, b in enumerate([5, 14, 41, 32, 23, *barcodes]))
    )
    (d / "Landmark_Groundtruth.dat").write_text(
        HEADER + "".join(f"{k + 6} \t {p[0]:.6f} \t {p[1]:.6f} \t 0.001 \t 0.001\n" for k, p in enumerate(survey))
    )
    # odometry: a 0.005 rad/s bias on the turn rate and white noise
    odo = np.column_stack([t, v + rng.normal(0, 0.01, t.size), w + 0.005 + rng.normal(0, 0.01, t.size)])
    (d / "Robot1_Odometry.dat").write_text(HEADER + "".join(f"{a:.3f} \t {b:.5f} \t {c:.5f}\n" for a, b, c in odo))
    rows = []
    for k in range(0, t.size, 4):  # 5 camera frames a second
        dx, dy = lm_local[:, 0] - x[k], lm_local[:, 1] - y[k]
        r, b = np.hypot(dx, dy), np.angle(np.exp(1j * (np.arctan2(dy, dx) - phi[k])))
        for j in np.flatnonzero((r < 9.0) & (np.abs(b) < math.radians(33))):
            rows.append(
                f"{t[k]:.3f} \t {barcodes[j]} \t {r[j] + rng.normal(0, 0.02):.5f} \t "
                f"{b[j] + rng.normal(0, math.radians(0.5)):.5f}\n"
            )
    (d / "Robot1_Measurement.dat").write_text(HEADER + "".join(rows))
    return d, survey


@pytest.mark.slow
def test_the_cli_reports_dropped_sightings(tmp_path, capsys):
    from nanoslam_jax.app.cli import main

    d, _ = write_simulated_dataset(tmp_path / "ds")
    with open(d / "Robot1_Measurement.dat", "a") as f:
        f.write("10.0 \t 43 \t 2.0 \t 0.1\n")  # a misread barcode
    sets = [a for o in MRCLAM_CFG + ["data.t_end=20", "filter.method=dead_reckoning"] for a in ("--set", o)]
    assert main(["run", "--data", str(d), "--out", str(tmp_path / "out"), "--quiet", *sets]) == 0
    err = capsys.readouterr().err
    (line,) = [x for x in err.splitlines() if x.startswith("nanoslam: warning:")]
    assert "Robot1_Measurement.dat" in line and "1 sighting(s)" in line and "barcode 43 (1x)" in line


@pytest.mark.slow
def test_slam_on_a_simulated_mrclam_log_scores_its_map(tmp_path):
    """configs/mrclam.yaml on a simulated log in MRCLAM's format: the map scored against the survey
    after a rigid alignment; SLAM at least 5x better than the dead-reckoning map; with known
    association every landmark found and paired by its barcode; the sweep scores the same run the
    same way (one scorer)."""
    import csv

    import nanoslam_jax as ns
    from nanoslam_jax.app.sweep import run_sweep, sweep_from_dict

    d, survey = write_simulated_dataset(tmp_path / "ds")
    config = REPO_ROOT / "configs" / "mrclam.yaml"
    common = [
        "output.progress=false",
        "output.plots=false",
        "unicycle.sigma_v=0.02",
        "unicycle.sigma_omega_deg=3",
        "noise.sigma_r=0.05",
        "noise.sigma_beta_deg=1",
    ]
    results = {}
    for method in ("ekf_slam", "fastslam1"):
        for assoc in ("known", "nearest"):
            r = ns.run(
                config,
                data=str(d),
                seed=16,
                overrides=common + [f"filter.method={method}", f"filter.association={assoc}"],
            )
            m = r.metrics
            results[method, assoc] = m
            assert m["survey_landmarks"] == 8 and m["survey_found"] == 8 and m["survey_spurious"] == 0, (method, assoc)
            assert m["survey_rmse"] < 0.05 and m["survey_dr_over_slam"] >= 5.0, (method, assoc, m["survey_rmse"])
            assert m["dr_survey_rmse"] > 0.2  # the biased turn rate bends the dead-reckoned path
            if assoc == "known":  # the ids of the map are the barcodes' landmarks: pairing by id agrees
                assert m["survey_found_by_id"] == 8 and m["survey_rmse_by_id"] == pytest.approx(
                    m["survey_rmse"], rel=1e-3
                )
                assert r.landmarks.shape[1] == 12 and set(r.landmarks[:, -1].astype(int)) == set(range(8))
            else:
                assert "survey_rmse_by_id" not in m
    raw = {
        "base": str(config),
        "set": common + ["filter.method=ekf_slam"],
        "seeds": [16],
        "plots": False,
        "metric": "survey_rmse",
        "shapes": {"filter.association": ["known", "nearest"]},
        "run": {"compile_cache": False},
    }
    run_sweep(sweep_from_dict(raw, source="test"), tmp_path / "sweep", data_dir=str(d), progress=False)
    with open(tmp_path / "sweep" / "results.csv") as f:
        rows = {row["filter.association"]: row for row in csv.DictReader(f)}
    for assoc in ("known", "nearest"):
        assert rows[assoc]["status"] == "ok", rows[assoc]["reason"]
        assert rows[assoc].get("rmse_fixed", "") == ""  # no GPS: no trajectory error
        assert float(rows[assoc]["survey_rmse"]) == pytest.approx(results["ekf_slam", assoc]["survey_rmse"], rel=1e-6)
