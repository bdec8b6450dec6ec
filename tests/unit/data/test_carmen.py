"""CARMEN log reader, the controls a laser log gives the filter, reference paths and their scores."""

from __future__ import annotations

import gzip
import math
from pathlib import Path

import numpy as np
import pytest

from nanoslam_jax.eval import (
    ReferencePath,
    reference_report,
    relative_motion_error,
    score_reference,
    trajectory_error,
)
from nanoslam_jax.data import LogFormatError
from nanoslam_jax.data._carmen import load_carmen, read_carmen
from nanoslam_jax.data._laser_log import laser_odom_raw, laser_poses
from nanoslam_jax.data._reference import load_reference
from tests.helpers.paths import SHARED_DATA


def flaser(ranges, laser, odom, t):
    r = " ".join(f"{v:.2f}" for v in ranges)
    p = " ".join(f"{v:.6f}" for v in (*laser, *odom))
    return f"FLASER {len(ranges)} {r} {p} {t:.6f} host {t:.6f}"


def robotlaser(ranges, laser, robot, t, start=-1.5, res=0.01, max_range=30.0):
    r = " ".join(f"{v:.2f}" for v in ranges)
    p = " ".join(f"{v:.6f}" for v in (*laser, *robot))
    head = f"ROBOTLASER1 0 {start} {res * (len(ranges) - 1)} {res} {max_range} 0.01 0"
    return f"{head} {len(ranges)} {r} 2 7 8 {p} 0.1 0.2 0.5 0.5 0.1 {t:.6f} host {t:.6f}"


def rawlaser(ranges, t, start=-1.0, res=0.5, max_range=40.0, n=1):
    r = " ".join(f"{v:.2f}" for v in ranges)
    return f"RAWLASER{n} 0 {start} {res * (len(ranges) - 1)} {res} {max_range} 0.01 0 {len(ranges)} {r} 0 {t:.6f} h {t:.6f}"


def odom(x, y, th, t):
    return f"ODOM {x:.6f} {y:.6f} {th:.6f} 0.1 0.0 0.0 {t:.6f} host {t:.6f}"


def write(path: Path, lines) -> Path:
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize("n, start, step", [(180, -90, 1.0), (181, -90, 1.0), (360, -90, 0.5), (361, -90, 0.5)])
def test_flaser_beam_conventions_no_returns_and_counts(tmp_path, n, start, step):
    rng = np.random.default_rng(n)
    r = rng.uniform(0.5, 20.0, size=(3, n)).round(2)
    r[0, 5] = 81.91
    r[1, 0] = 80.0
    lines = ["# a comment", "PARAM robot_width 0.5 1.0 h 1.0", "SYNC 1 2 3"]
    lines += [flaser(r[k], (k, 0, 0), (k, 0, 0), 10.0 + k) for k in range(3)]
    log, counts = read_carmen(write(tmp_path / "a.clf", lines))
    assert log.n_scans == 3 and log.scans.n_beams == n
    np.testing.assert_allclose(np.rad2deg(log.scans.angles), start + step * np.arange(n), atol=1e-12)
    assert log.scans.max_range == 80.0
    assert log.scans.ranges[0, 5] == 80.0 and log.scans.ranges[1, 0] == 80.0
    assert log.scans.valid.sum() == 3 * n - 2
    np.testing.assert_allclose(log.scans.ranges[2], r[2])
    np.testing.assert_allclose(log.odom[:, 0], [0, 1, 2])
    assert counts.comments == 1 and counts.skipped == {"PARAM": 1, "SYNC": 1} and counts.scans == 3


def test_overrides_of_angles_and_no_return(tmp_path):
    r = np.full(10, 5.0)
    r[3] = 49.0
    f = write(tmp_path / "a.log", [flaser(r, (0, 0, 0), (0, 0, 0), 1.0), flaser(r, (0, 0, 0), (0, 0, 0), 2.0)])
    log = load_carmen(f, laser_start_deg=-45.0, laser_step_deg=10.0, no_return=40.0)
    np.testing.assert_allclose(np.rad2deg(log.scans.angles), -45.0 + 10.0 * np.arange(10))
    assert log.scans.max_range == 40.0 and not log.scans.valid[0, 3] and log.scans.valid[0, 2]


def test_flaser_mounting_and_gzip_and_directory(tmp_path):
    # laser 0.3 m ahead, 0.1 m left, turned 0.2 rad on a robot at various poses
    mount = np.array([0.3, 0.1, 0.2])
    lines = []
    for k, (x, y, th) in enumerate([(0, 0, 0), (1, 2, 1.0), (-3, 1, 3.1)]):
        c, s = math.cos(th), math.sin(th)
        laser = (x + c * mount[0] - s * mount[1], y + s * mount[0] + c * mount[1], th + mount[2])
        lines.append(flaser([1.0] * 5, laser, (x, y, th), float(k)))
    d = tmp_path / "log"
    d.mkdir()
    with gzip.open(d / "run.clf.gz", "wt") as fh:
        fh.write("\n".join(lines) + "\n")
    log = load_carmen(d)
    np.testing.assert_allclose(log.laser_pose, mount, atol=1e-5)
    np.testing.assert_allclose(laser_poses(log)[1], [float(v) for v in lines[1].split()[7:10]], atol=1e-5)


def test_robotlaser_geometry_and_mounting(tmp_path):
    lines = [
        robotlaser([1.0, 2.0, 31.0, 4.0], (1.0, 0.5, 0.0), (0.8, 0.5, 0.0), 5.0),
        robotlaser([1.0, 2.0, 3.0, 4.0], (0.0, 1.2, math.pi / 2), (0.0, 1.0, math.pi / 2), 6.0),
    ]
    log = load_carmen(write(tmp_path / "r.clf", lines))
    np.testing.assert_allclose(log.scans.angles, -1.5 + 0.01 * np.arange(4))
    assert log.scans.max_range == 30.0 and log.scans.ranges[0, 2] == 30.0
    np.testing.assert_allclose(log.laser_pose, [0.2, 0.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(log.odom, [[0.8, 0.5, 0.0], [0.0, 1.0, math.pi / 2]], atol=1e-6)
    # an override replaces the spacing the lines state; the start stays the line's
    log2 = load_carmen(tmp_path / "r.clf", laser_step_deg=0.5, no_return=3.5)
    np.testing.assert_allclose(log2.scans.angles, -1.5 + np.deg2rad(0.5) * np.arange(4))
    assert log2.scans.max_range == 3.5 and log2.scans.valid[1].tolist() == [True, True, True, False]
    # the laser moves on the robot: an error naming the line
    lines.append(robotlaser([1.0, 2.0, 3.0, 4.0], (0.5, 1.0, 0.0), (0.0, 1.0, 0.0), 7.0))
    with pytest.raises(LogFormatError, match=r"bad\.clf line 3: the laser's pose relative"):
        load_carmen(write(tmp_path / "bad.clf", lines))


def test_rawlaser_pose_interpolated_from_odom(tmp_path):
    # heading from 3.0 to -3.0 rad: the shorter way through pi
    lines = [
        odom(0.0, 0.0, 3.0, 10.0),
        rawlaser([1.0, 2.0, 3.0], 9.0),  # before the first ODOM: dropped
        rawlaser([1.0, 2.0, 3.0], 10.25),
        odom(1.0, 2.0, -3.0, 11.0),
        rawlaser([1.0, 2.0, 3.0], 10.75, n=2),
    ]
    log, counts = read_carmen(write(tmp_path / "o.clf", lines))
    assert counts.dropped == 1 and counts.odom == 2 and log.n_scans == 2
    arc = 2 * math.pi - 6.0
    want_th = [3.0 + 0.25 * arc, 3.0 + 0.75 * arc - 2 * math.pi]
    np.testing.assert_allclose(log.odom[:, :2], [[0.25, 0.5], [0.75, 1.5]], atol=1e-12)
    np.testing.assert_allclose(log.odom[:, 2], want_th, atol=1e-12)
    np.testing.assert_allclose(log.scans.angles, [-1.0, -0.5, 0.0])
    assert log.scans.max_range == 40.0 and np.all(log.laser_pose == 0)


def test_out_of_order_stamps_sorted_and_counted(tmp_path):
    lines = [flaser([float(t)] * 4, (t, 0, 0), (t, 0, 0), float(t)) for t in (3, 1, 2, 5, 4)]
    log = load_carmen(write(tmp_path / "s.clf", lines))
    np.testing.assert_allclose(log.scans.time, [1, 2, 3, 4, 5])
    np.testing.assert_allclose(log.scans.ranges[:, 0], [1, 2, 3, 4, 5])
    np.testing.assert_allclose(log.odom[:, 0], [1, 2, 3, 4, 5])
    assert log.out_of_order == 2


GOOD = flaser([1.0, 2.0, 3.0], (0, 0, 0), (0, 0, 0), 1.0)


@pytest.mark.parametrize(
    "bad, match",
    [
        ("FLASER 3 1.0 2.0 3.0 0 0 0 0 0", r"line 2 \(FLASER\): too few fields"),
        (
            "FLASER 3 1.0 x 3.0 0 0 0 0 0 0 2.0 h 2.0",
            r"line 2 \(FLASER, field 4, a range\): expected a finite number, got 'x'",
        ),
        ("FLASER 3 1.0 nan 3.0 0 0 0 0 0 0 2.0 h 2.0", r"line 2 .*finite number, got 'nan'"),
        ("FLASER 2 1.0 2.0 0 0 0 0 0 0 2.0 h 2.0", r"line 2 \(FLASER\): 2 readings, but line 1 has 3"),
        (
            "FLASER 3 1.0 2.0 3.0 1 0 0 1 0 0 1.0 h 1.0",
            r"line 2: a scan at time 1.0 has the same ipc_timestamp as line 1",
        ),
        ("ODOM 0 0 0 0 0", r"line 2 \(ODOM\): too few fields"),
        ("FLASER -3 1.0", r"line 2 \(FLASER, field 2\): expected the number of readings"),
    ],
)
def test_malformed_lines_name_file_and_line(tmp_path, bad, match):
    f = write(tmp_path / "m.clf", [GOOD, bad])
    with pytest.raises(LogFormatError, match=r"m\.clf " + match):
        load_carmen(f)


def test_no_scans_and_missing_files(tmp_path):
    with pytest.raises(LogFormatError, match=r"e\.clf: no laser scans"):
        load_carmen(write(tmp_path / "e.clf", ["# nothing", "PARAM a 1 h 1", odom(0, 0, 0, 1.0)]))
    with pytest.raises(LogFormatError, match=r"n\.clf line 1 \(RAWLASER1\): a scan without a pose"):
        load_carmen(write(tmp_path / "n.clf", [rawlaser([1.0], 1.0)]))
    (tmp_path / "two").mkdir()
    write(tmp_path / "two" / "a.clf", [GOOD])
    write(tmp_path / "two" / "b.log", [GOOD])
    with pytest.raises(FileNotFoundError, match="exactly one CARMEN log"):
        load_carmen(tmp_path / "two")


def _euler(dr, p0):
    """The unicycle model's first-order step (no sensor offset) over the dr rows, from pose p0."""
    p, out = np.array(p0, float), [np.array(p0, float)]
    for i in range(len(dr) - 1):
        dt = dr[i + 1, 0] - dr[i, 0]
        v, w = dr[i, 1:]
        p = p + dt * np.array([v * math.cos(p[2]), v * math.sin(p[2]), w])
        out.append(p.copy())
    return np.array(out)


def test_laser_odom_raw_unicycle_controls_reproduce_the_odometry(tmp_path):
    # a circle of radius 2 at 0.5 m/s, scans every 0.2 s, with a mounting turned by 0.1 rad
    t = 100.0 + 0.2 * np.arange(30)
    th = 0.25 * (t - t[0])
    x, y = 2 * np.sin(th), 2 * (1 - np.cos(th))
    mount = (0.0, 0.0, 0.1)
    lines = [flaser([1.0] * 4, (x[k], y[k], th[k] + 0.1), (x[k], y[k], th[k]), t[k]) for k in range(t.size)]
    log = load_carmen(write(tmp_path / "c.clf", lines))
    np.testing.assert_allclose(log.laser_pose, mount, atol=1e-5)
    raw, scans = laser_odom_raw(log)
    assert raw.dr.shape == (2 * t.size - 1, 3) and np.all(np.diff(raw.dr[:, 0]) > 0)
    np.testing.assert_allclose(raw.dr[0::2, 0], t)
    np.testing.assert_allclose(raw.dr[1:-1:2, 1], 2 * 0.5 * np.sinc(0.025 / np.pi), rtol=1e-4)  # 2 chord / dt
    np.testing.assert_allclose(raw.dr[:-1, 2], 0.25, atol=1e-4)
    poses = _euler(raw.dr, log.odom[0])[0::2]
    np.testing.assert_allclose(poses[:, :2], log.odom[:, :2], atol=1e-5)
    np.testing.assert_allclose(np.unwrap(poses[:, 2]), np.unwrap(log.odom[:, 2]), atol=1e-5)
    np.testing.assert_allclose(scans.angles, log.scans.angles + 0.1, atol=1e-5)
    with pytest.raises(ValueError, match="controls must be one of"):
        laser_odom_raw(log, controls="ackermann")


def test_reference_from_corrected_log_matches_by_ranges_in_order(tmp_path):
    rng = np.random.default_rng(0)
    r = rng.uniform(1, 10, size=(8, 6)).round(2)
    r[5] = r[2]  # the same ranges twice: the match after the previous one is taken
    r[4, 1] = 81.91
    raw = write(tmp_path / "raw.clf", [flaser(r[k], (k, 0, 0), (k, 0, 0), float(k)) for k in range(8)])
    take = [1, 2, 4, 5, 7]
    ref_pose = [(10 + k, -k, 0.1 * k) for k in take]
    corr = [flaser(r[k], p, p, 1.13486e09) for k, p in zip(take, ref_pose)]
    corr = ["PARAM x 1 h 0", "NEFF 27 0 h 0", *corr, odom(0, 0, 0, 1.13486e09)]
    with gzip.open(tmp_path / "raw-corrected.log.gz", "wt") as fh:
        fh.write("\n".join(corr) + "\n")
    log = load_carmen(raw)
    index, poses = load_reference(tmp_path / "raw-corrected.log.gz", log)
    np.testing.assert_array_equal(index, take)
    np.testing.assert_allclose(poses, ref_pose)
    # a corrected scan without a raw one
    bad = [flaser(r[1] + 0.01, (0, 0, 0), (0, 0, 0), 0.0)]
    with pytest.raises(LogFormatError, match=r"bad\.log line 1 \(FLASER\): no scan .* has the same ranges"):
        load_reference(write(tmp_path / "bad.log", bad), log)


def test_reference_from_csv_and_tum_by_time(tmp_path):
    lines = [flaser([1.0, 2.0], (k, 0, 0), (k, 0, 0), 10.0 + k) for k in range(5)]
    log = load_carmen(write(tmp_path / "a.clf", lines))
    csv = write(tmp_path / "ref.csv", ["time,x,y,theta", "11.005,1,2,0.5", "12.5,9,9,0", "13.0,3,4,-0.5"])
    index, poses = load_reference(csv, log)
    np.testing.assert_array_equal(index, [1, 3])
    np.testing.assert_allclose(poses, [[1, 2, 0.5], [3, 4, -0.5]])
    yaw = 2.5
    q = (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))
    tum = write(tmp_path / "ref.txt", ["# tum", f"14.0 5 6 0 {q[0]} {q[1]} {q[2]} {q[3]}"])
    index, poses = load_reference(tum, log)
    np.testing.assert_array_equal(index, [4])
    np.testing.assert_allclose(poses, [[5, 6, yaw]], atol=1e-12)
    with pytest.raises(LogFormatError, match=r"h\.csv line 1: expected the header"):
        load_reference(write(tmp_path / "h.csv", ["t,x,y", "1,2,3"]), log)
    with pytest.raises(LogFormatError, match=r"v\.csv line 3, value 2: expected a finite number"):
        load_reference(write(tmp_path / "v.csv", ["time,x,y,theta", "1,2,3,4", "2,a,3,4"]), log)


def test_rigid_alignment_is_recovered_exactly_and_relative_errors_closed_form():
    rng = np.random.default_rng(3)
    ref = np.column_stack([rng.normal(size=(50, 2)) * 5, rng.uniform(-3, 3, 50)])
    a, tx, ty = 0.7, 3.0, -2.0
    c, s = math.cos(a), math.sin(a)
    est = np.column_stack([c * ref[:, 0] - s * ref[:, 1] + tx, s * ref[:, 0] + c * ref[:, 1] + ty, ref[:, 2] + a])
    te = trajectory_error(est, ref)
    assert te["rmse"] < 1e-12 and te["max"] < 1e-12
    assert te["rotation_deg"] == pytest.approx(-math.degrees(a), abs=1e-9)
    assert relative_motion_error(est, ref)["translation"] < 1e-12  # a rigid motion changes no relative motion
    # a path advancing 1.1 m per step where the reference advances 1 m, turning 2 deg more each step
    n = 11
    ref = np.column_stack([np.arange(n, dtype=float), np.zeros(n), np.zeros(n)])
    th = np.deg2rad(2.0) * np.arange(n)
    est = np.zeros((n, 3))
    for i in range(1, n):
        est[i] = est[i - 1] + [1.1 * math.cos(th[i - 1]), 1.1 * math.sin(th[i - 1]), np.deg2rad(2.0)]
    rel = relative_motion_error(est, ref)
    assert rel["translation"] == pytest.approx(0.1) and rel["rotation_deg"] == pytest.approx(2.0)
    rep = reference_report(est, ref, "dr_ref_")
    assert rep["dr_ref_n"] == n and rep["dr_ref_rel_trans"] == pytest.approx(0.1)


def test_score_reference_picks_the_reference_times_and_heading_offset():
    times = np.arange(10.0)
    est = np.column_stack([times, np.zeros(10), np.zeros(10)])
    ref = ReferencePath(
        np.array([2.0, 3.0, 4.0, 20.0]), np.array([[2, 0, 0.3], [3, 0, 0.3], [4, 0, 0.3], [9, 9, 0]]), 0.3
    )
    m = score_reference(ref, times, est, est + [0, 0, 0.1])
    assert m["ref_n"] == 3 and m["ref_rmse"] < 1e-12 and m["ref_rel_rot_deg"] < 1e-12
    assert m["dr_ref_rel_rot_deg"] < 1e-12 and m["dr_ref_rmse"] < 1e-12


CSAIL = SHARED_DATA / "carmen" / "mit-csail"


@pytest.mark.data
def test_mit_csail_log_and_its_reference():
    if not (CSAIL / "mit-csail.clf").is_file():
        pytest.skip(f"{CSAIL} not available")
    log, counts = read_carmen(CSAIL / "mit-csail.clf")
    assert log.n_scans == 1988 and log.scans.n_beams == 361 and log.out_of_order == 0
    assert counts.comments == 3 and np.all(log.laser_pose == 0)
    index, poses = load_reference(CSAIL / "mit-csail-corrected.log.gz", log)
    assert index.size == 406 and index[0] == 61 and index[-1] == 1916 and np.all(np.diff(index) > 0)
    m = reference_report(laser_poses(log)[index], poses, "dr_ref_")
    assert 8.6 < m["dr_ref_rmse"] < 8.8 and 14.0 < m["dr_ref_max"] < 14.4
    assert 0.07 < m["dr_ref_rel_trans"] < 0.08 and 5.0 < m["dr_ref_rel_rot_deg"] < 5.2


def _wall_scans(tmp_path: Path) -> Path:
    """A robot driving towards a wall 6 m ahead (x = 6) with a side wall at y = 2, turning slowly."""
    ang = np.deg2rad(np.linspace(-90, 90, 181))
    lines = []
    for k in range(6):
        x, y, th = 0.2 * k, 0.0, 0.02 * k
        a = ang + th
        with np.errstate(divide="ignore"):
            r_front = np.where(np.cos(a) > 1e-9, (6.0 - x) / np.cos(a), np.inf)
            r_side = np.where(np.sin(a) > 1e-9, (2.0 - y) / np.sin(a), np.inf)
        r = np.minimum(r_front, r_side)
        r = np.where(np.isfinite(r) & (r < 30), r, 81.91)
        lines.append(flaser(r, (x, y, th), (x, y, th), 50.0 + 0.25 * k))
    return write(tmp_path / "walls.clf", lines)


@pytest.mark.slow
def test_load_log_reads_a_carmen_log_with_line_detections_and_reference(tmp_path):
    from nanoslam_jax.app.config import ConfigError, load_config
    from nanoslam_jax.app.experiment import load_log

    f = _wall_scans(tmp_path)
    ref = write(tmp_path / "ref.csv", ["time,x,y,theta", "50.25,0.2,0,0.02", "51.0,0.6,0,0.06"])
    sets = [
        "data.kind=victoria_park",
        "data.format=carmen",
        "data.detections=laser_lines",
        "model.motion=unicycle",
        "model.measurement=line",
        "data.max_range=30",
        "detector.max_range=30",
        f"data.reference={ref}",
    ]
    log = load_log(load_config(None, sets), str(f))
    assert log.frame == "relative" and log.source == str(f)
    assert log.raw.dr.shape == (11, 3) and log.raw.detections.shape[1] == 4
    # the front end finds both walls in every scan: rho 6 - x ahead, 2 to the left
    first = log.raw.detections[log.raw.detections[:, 0] == 50.0]
    assert sorted(np.round(first[:, 1], 2)) == [2.0, 6.0]
    np.testing.assert_allclose(log.reference.time, [50.25, 51.0])
    np.testing.assert_allclose(log.reference.poses, [[0.2, 0, 0.02], [0.6, 0, 0.06]])
    with pytest.raises(ValueError, match="set unicycle.sensor_x and unicycle.sensor_y"):
        load_log(load_config(None, [*sets, "unicycle.sensor_x=0.3"]), str(f))
    with pytest.raises(ConfigError, match="key 'data.detections': a CARMEN log holds laser scans"):
        load_config(None, [*sets, "data.detections=file"])
    with pytest.raises(ConfigError, match="key 'model.motion'"):
        load_config(None, [*sets, "model.motion=ackermann"])


@pytest.mark.slow
@pytest.mark.data
def test_mit_csail_dead_reckoning_run_scores_the_reference(tmp_path):
    if not (CSAIL / "mit-csail.clf").is_file():
        pytest.skip(f"{CSAIL} not available")
    import json

    from nanoslam_jax.app.config import load_config
    from nanoslam_jax.app.experiment import run_experiment

    cfg = load_config(
        None,
        [
            "data.kind=victoria_park",
            "data.format=carmen",
            "data.detections=laser_lines",
            "model.motion=unicycle",
            "model.measurement=line",
            "data.max_range=30",
            "detector.max_range=30",
            "data.k_max=40",
            "filter.method=dead_reckoning",
            f"data.reference={CSAIL / 'mit-csail-corrected.log.gz'}",
        ],
    )
    run_experiment(cfg, tmp_path, data_dir=str(CSAIL), progress=False)
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert 400 <= m["dr_ref_n"] <= 406
    assert 8.6 < m["dr_ref_rmse"] < 8.8 and 14.0 < m["dr_ref_max"] < 14.4
    assert 0.07 < m["dr_ref_rel_trans"] < 0.08 and 5.0 < m["dr_ref_rel_rot_deg"] < 5.2


@pytest.mark.slow
def test_compare_scores_every_method_against_the_reference_path(tmp_path):
    """A log without GPS and with a reference path: compare scores each row against the reference.
    The reference is the odometry moved by a rigid transform, so dead reckoning's aligned error and
    relative-motion errors are zero (closed form), and the figures are drawn from the reference."""
    import csv

    import yaml

    from nanoslam_jax.app.compare import run_compare
    from nanoslam_jax.app.compare import load_compare_spec

    f = _wall_scans(tmp_path)
    log = load_carmen(f)
    raw, _ = laser_odom_raw(log)
    path = _euler(raw.dr, log.odom[0])[0::2]  # the controls' own path, integrated here
    c, s = math.cos(0.5), math.sin(0.5)
    rows = ["time,x,y,theta"]
    for k, (x, y, th) in enumerate(path):
        rows.append(
            f"{float(log.scans.time[k])!r},{float(c * x - s * y + 5.0)!r},{float(s * x + c * y - 3.0)!r},{float(th + 0.5)!r}"
        )
    ref = write(tmp_path / "ref.csv", rows)
    spec_file = tmp_path / "cmp.yaml"
    spec_file.write_text(
        yaml.safe_dump(
            {
                "name": "walls",
                "seeds": 2,
                "set": [
                    "data.kind=victoria_park",
                    "data.format=carmen",
                    f"data.path={f}",
                    "data.detections=laser_lines",
                    "model.motion=unicycle",
                    "model.measurement=line",
                    "data.max_range=30",
                    "detector.max_range=30",
                    f"data.reference={ref}",
                    "filter.n_particles=4",
                    "filter.capacity=16",
                    "filter.window=8",
                    "output.progress=false",
                ],
                "methods": [
                    {"label": "DR", "set": ["filter.method=dead_reckoning"]},
                    {"label": "FastSLAM 2.0", "set": ["filter.method=fastslam2"]},
                ],
            }
        )
    )
    out = tmp_path / "out"
    table = run_compare(load_compare_spec(spec_file), out)
    dr, fs2 = table
    assert dr["ref_rmse_median"] < 1e-5 and dr["ref_rel_trans_median"] < 1e-5 and dr["ref_rel_rot_deg_median"] < 1e-4
    assert (
        fs2["seeds"] == 2 and math.isfinite(fs2["ref_rmse_median"]) and fs2["ref_rmse_worst"] >= fs2["ref_rmse_median"]
    )
    with open(out / "table1.csv") as fh:
        csv_rows = list(csv.DictReader(fh))
    assert float(csv_rows[0]["ref_rmse_median"]) < 1e-5
    md = (out / "table1.md").read_text()
    assert "path error [m]" in md and "| DR | 1 |" in md
    assert (out / "fig3_trajectories.png").stat().st_size > 0 and (out / "fig4_error.png").stat().st_size > 0
