"""``output.rerun``: a run as a Rerun recording, read back with rerun's own reader (``rerun.chunk``)."""

from __future__ import annotations

import json
import sys
from collections import defaultdict

import numpy as np
import pytest

from nanoslam_jax.app.config import ConfigError, load_config
from nanoslam_jax.app.experiment import execute, run_experiment
from nanoslam_jax.eval._rerun import RecordingOptions, RerunMap, ellipse, write_rerun

rerun_chunk = pytest.importorskip("rerun.chunk", reason="output.rerun needs rerun-sdk (the viz extra)")

# The short run of tests/unit/models/test_motion_models.py (SHORT): its NANO-SLAM program is shared.
SHORT = ["sim.duration=15", "filter.n_particles=5", "output.plots=false", "output.progress=false"]


def read_rrd(path) -> dict[str, dict[str, list]]:
    """Per entity (``/world/pose``, ...), its ``scan`` index and component columns, over all its chunks."""
    out: dict[str, dict[str, list]] = defaultdict(lambda: defaultdict(list))
    for chunk in rerun_chunk.RrdReader(path).stream():
        batch = chunk.to_record_batch()
        for name in batch.schema.names:
            if name in ("scan",) or ":" in name or name == "pose":
                out[chunk.entity_path][name].extend(batch.column(name).to_pylist())
    return out


def _synthetic(n=7, particles=4):
    rng = np.random.default_rng(3)
    t = 10.0 + 0.2 * np.arange(n)
    poses = np.c_[np.cumsum(rng.uniform(0.5, 1.0, n)), rng.normal(size=n), rng.uniform(-3, 3, n)]
    pts = [rng.normal(size=(k % 3, 2)) * 5 for k in range(n)]  # scans of 0, 1 and 2 points
    parts = poses[:, None, :] + 0.1 * rng.normal(size=(n, particles, 3))
    return t, poses, pts, parts


def test_writer_logs_every_scan_pose_scan_points_and_path(tmp_path):
    t, poses, pts, parts = _synthetic()
    cov = np.diag([4.0, 1.0, 0.1])
    lm, confirmed = np.array([[1.0, 2.0], [3.0, -4.0]]), np.array([True, False])
    path = write_rerun(
        tmp_path / "sub" / "run.rrd",
        t,
        poses,
        pts,
        particles=parts,
        pose_cov=cov,
        final_map=RerunMap(landmarks=lm, confirmed=confirmed, lines=np.array([[2.0, 0.5]])),
        options=RecordingOptions(path_points=4),
    )
    rec = read_rrd(path)
    n = len(t)
    for entity in ("/world/pose", "/world/scan", "/world/path", "/world/particles"):
        assert sorted(rec[entity]["scan"]) == list(range(n)), entity
    pose = rec["/world/pose"]
    last = int(np.argmax(pose["scan"]))
    np.testing.assert_allclose(pose["pose"][last], poses[-1], rtol=0, atol=1e-9)  # float64, exact
    for i, s in enumerate(rec["/world/scan"]["scan"]):  # the points in the world frame, from the pose
        got = np.asarray(rec["/world/scan"]["Points2D:positions"][i], dtype=float).reshape(-1, 2)
        x, y, phi = poses[s]
        rot = np.array([[np.cos(phi), -np.sin(phi)], [np.sin(phi), np.cos(phi)]])  # sensor frame -> world
        np.testing.assert_allclose(got, np.array([x, y]) + pts[s] @ rot.T, atol=1e-4)
    strips = rec["/world/path"]["LineStrips2D:strips"]
    for i, s in enumerate(rec["/world/path"]["scan"]):  # the path so far, at most 4 poses, the current last
        strip = np.asarray(strips[i][0], dtype=float)
        assert len(strip) == min(s + 1, 4)
        np.testing.assert_allclose(strip[-1], poses[s, :2], rtol=1e-6)
        np.testing.assert_allclose(strip[0], poses[0, :2], rtol=1e-6)
    ell = rec["/world/ellipse"]  # a covariance of the last scan only: its ellipse there
    assert ell["scan"] == [n - 1]
    np.testing.assert_allclose(np.asarray(ell["LineStrips2D:strips"][0][0]), ellipse(poses[-1], cov[:2, :2]), atol=1e-4)
    assert np.ptp(np.asarray(ell["LineStrips2D:strips"][0][0])[:, 0]) == pytest.approx(2 * 2 * 2.0, rel=1e-3)
    assert rec["/world/landmarks"]["scan"] == [n - 1]
    np.testing.assert_allclose(rec["/world/landmarks"]["Points2D:positions"][0], lm)
    colors = rec["/world/landmarks"]["Points2D:colors"][0]
    assert colors[0] != colors[1]  # confirmed and tentative drawn apart
    seg = np.asarray(rec["/world/lines"]["LineStrips2D:strips"][0][0])
    normal = np.array([np.cos(0.5), np.sin(0.5)])
    np.testing.assert_allclose(seg @ normal, [2.0, 2.0], atol=1e-5)  # on the line rho = 2, alpha = 0.5


def test_writer_rejects_mismatched_shapes(tmp_path):
    t, poses, pts, _ = _synthetic()
    with pytest.raises(ValueError, match=r"poses must be \(S, 3\)"):
        write_rerun(tmp_path / "a.rrd", t, poses[:-1])
    with pytest.raises(ValueError, match="6 scans of points for 7 times"):
        write_rerun(tmp_path / "a.rrd", t, poses, pts[:-1])


def test_missing_rerun_is_refused_before_the_run_naming_the_key_and_the_extra(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "rerun", None)  # `import rerun` raises ImportError
    cfg = load_config(None, SHORT + ["output.rerun=run.rrd"])
    with pytest.raises(ConfigError, match=r"output\.rerun.*pip install 'nanoslam-jax\[viz\]'"):
        run_experiment(cfg, tmp_path / "out")
    assert not (tmp_path / "out").exists()


@pytest.fixture(scope="module")
def short_run(tmp_path_factory):
    cfg = load_config(None, SHORT + ["output.rerun=replay/run.rrd"])
    result = execute(cfg)
    out = result.write(tmp_path_factory.mktemp("rerun_run"))
    return result, out


@pytest.mark.slow
def test_a_run_records_every_scan_and_its_path_ends_at_the_trajectory(short_run):
    result, out = short_run
    rec = read_rrd(out / "replay" / "run.rrd")
    n = len(result.times)
    assert n > 10
    for entity in ("/world/pose", "/world/scan", "/world/path"):
        assert sorted(rec[entity]["scan"]) == list(range(n)), entity
    pose = rec["/world/pose"]
    last = np.asarray(pose["pose"][int(np.argmax(pose["scan"]))])
    np.testing.assert_allclose(last, result.trajectory[-1], rtol=0, atol=1e-9)
    csv = np.loadtxt(out / "trajectory.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(last, csv[-1, 1:4], rtol=0, atol=1e-6)  # trajectory.csv holds 6 decimals
    path = rec["/world/path"]
    strip = np.asarray(path["LineStrips2D:strips"][int(np.argmax(path["scan"]))][0])
    np.testing.assert_allclose(strip[-1], result.trajectory[-1, :2], rtol=1e-6)  # the viewer's float32
    n_det = np.asarray(result.log.segments.z_mask).sum(axis=1)  # the detections of each scan, projected
    scans = rec["/world/scan"]
    counts = [len(scans["Points2D:positions"][scans["scan"].index(i)]) for i in range(n)]
    assert counts == n_det.tolist()
    assert len(rec["/world/landmarks"]["Points2D:positions"][0]) == len(result.landmarks)
    assert "warnings" not in json.loads((out / "metrics.json").read_text())


@pytest.mark.slow
def test_a_recording_that_fails_is_a_warning_and_the_other_results_stay(short_run, tmp_path, monkeypatch):
    result, _ = short_run

    def broken(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr("nanoslam_jax.app._replay.write_rerun", broken)
    out = result.write(tmp_path / "out")
    metrics = json.loads((out / "metrics.json").read_text())
    assert any(
        w.startswith("output.rerun: no Rerun recording written (OSError: disk full)") for w in metrics["warnings"]
    )
    assert (out / "trajectory.csv").is_file() and (out / "map.csv").is_file()
    assert not (out / "replay").exists()
