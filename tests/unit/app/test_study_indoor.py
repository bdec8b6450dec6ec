"""The NASRUKF paper's study through `nanoslam compare` (a comparison over worlds, ``seed_keys``):
Table 1 of the feature map from the one scorer, Figures 5 and 6, the failed-run rule."""

from __future__ import annotations

import csv
import dataclasses
import math
from types import SimpleNamespace

import numpy as np
import pytest

from nanoslam_jax.app._compare_worlds import feature_table, wall_segments
from nanoslam_jax.sim.indoor import FeatureTruth
from nanoslam_jax.eval import MapEstimate, score_run
from tests.helpers.internals import break_point_line_errors, with_arcs
from nanoslam_jax.app.compare import MethodResult, MethodSpec, load_compare_spec, run_compare, seed_config
from nanoslam_jax.app.config import ConfigError
from tests.helpers.paths import REPO_ROOT

ROOT = REPO_ROOT

# A 6 m x 4 m room, lines (rho, alpha): x = 0, x = 6, y = 0, y = 4; a door in y = 4 between x = 2 and 3;
# a pillar of radius 0.3 at (4, 2).
ROOM = FeatureTruth(
    lines=np.array([[0.0, math.pi], [6.0, 0.0], [0.0, -math.pi / 2], [4.0, math.pi / 2]]),
    line_ids=np.arange(4),
    corners=np.array([[0, 2], [2, 1], [1, 3], [3, 0]]),
    arcs=np.array([[4.0, 2.0, 0.3]]),
    break_points=np.array([[2.0, 4.0], [3.0, 4.0]]),
)


def _log(truth: FeatureTruth):
    t = np.linspace(0.0, 1.0, 11)
    path = np.c_[t, 1.0 + t, np.full_like(t, 2.0), np.zeros_like(t)]
    raw = SimpleNamespace(gps=path[:, :3], truth_poses=path)
    return SimpleNamespace(
        segments=SimpleNamespace(time=t), raw=raw, frame="slam", map_truth=None, survey=None, feature_truth=truth
    )


def test_table1_of_the_one_scorer_gives_the_offsets_built_into_a_map_of_lines_and_arcs():
    """Walls moved by known distances and a pillar by a known centre and radius offset: the scorer's
    line, corner, break point and arc figures are those offsets (computed here by hand)."""
    # x = 0 moved to x = -0.01; x = 6 to 6.02; y = 0 unchanged; y = 4 to 4.03 (all parallel moves)
    lines = np.array([[0.01, math.pi], [6.02, 0.0], [0.0, -math.pi / 2], [4.03, math.pi / 2]])[[2, 0, 3, 1]]
    est = MapEstimate(lines, np.ones(4, bool))
    arcs = np.array([[9.0, 9.0, 1.0], [4.0 + 0.006, 2.0 - 0.008, 0.3 + 0.004]])
    lm = with_arcs(est, arcs, np.array([False, True]))
    assert lm.kinds is not None and list(lm.kinds) == ["line"] * 4 + ["circle"]
    m = score_run(_log(ROOM), np.c_[np.linspace(0, 1, 11) + 1.0, np.full(11, 2.0), np.zeros(11)], _metrics(), lm)
    assert (m["n_lines_matched"], m["n_arcs_matched"], m["n_corners_matched"], m["n_break_points_matched"]) == (
        4,
        1,
        4,
        2,
    )
    # intercepts: the horizontal walls' b moves by their shift (0, 0.03), the vertical walls' c (-0.01, 0.02)
    assert m["line_intercept_median"] == pytest.approx(np.median([0.01, 0.02, 0.0, 0.03]))
    assert m["line_intercept_worst"] == pytest.approx(0.03)
    assert m["line_slope_worst"] == pytest.approx(0.0, abs=1e-12)
    # corners move by both of their walls' shifts
    corner = [math.hypot(0.01, 0.0), math.hypot(0.02, 0.0), math.hypot(0.02, 0.03), math.hypot(0.01, 0.03)]
    assert m["corner_median"] == pytest.approx(np.median(corner))
    assert m["corner_worst"] == pytest.approx(max(corner))
    # the door's jambs lie on y = 4, estimated 3 cm off
    assert m["break_point_median"] == pytest.approx(0.03) and m["break_point_worst"] == pytest.approx(0.03)
    assert m["arc_centre_median"] == pytest.approx(0.01) and m["arc_radius_median"] == pytest.approx(0.004)
    assert m["rmse_fixed"] == pytest.approx(0.0, abs=1e-12) and m["rmse_heading_deg"] == pytest.approx(0.0)


def _metrics():
    return SimpleNamespace(gps_rotation_deg=0.0, jump_speed=1e9, map_radius=1.0)


def test_break_point_errors_follow_their_own_wall_and_leave_an_unmapped_wall_out():
    lines = ROOM.lines.copy()
    lines[3, 0] += 0.05  # y = 4 estimated at 4.05
    match = np.array([0, 1, 2, -1])
    pts = np.array([[2.0, 4.0], [0.0, 1.5], [6.0, 3.0], [3.0, 2.0]])  # on y = 4, x = 0, x = 6, on no wall
    err = break_point_line_errors(lines, ROOM.lines, np.arange(4), pts)
    np.testing.assert_array_equal(err["line"], [3, 0, 1, -1])
    np.testing.assert_allclose(err["error"][:3], [0.05, 0.0, 0.0], atol=1e-12)
    assert np.isnan(err["error"][3])
    unmatched = break_point_line_errors(lines, ROOM.lines, match, pts)
    assert np.isnan(unmatched["error"][0]) and unmatched["n_matched"] == 2


def test_wall_segments_run_between_corners_and_break_points_and_move_onto_the_estimates():
    est = np.array([[6.02, 0.0], [0.0, -math.pi / 2], [20.0, 0.7]])  # x = 6.02, y = 0, one far from every wall
    walls, drawn = wall_segments(ROOM, est)
    ends = [sorted(map(tuple, np.round(w.reshape(2, 2), 9))) for w in walls]
    assert ends[0] == [(0.0, 0.0), (0.0, 4.0)] and ends[1] == [(6.0, 0.0), (6.0, 4.0)]
    assert ends[3] == [(0.0, 4.0), (6.0, 4.0)]  # the door's jambs lie between the corners
    np.testing.assert_allclose(sorted(drawn[0].reshape(2, 2)[:, 1]), [0.0, 4.0], atol=1e-12)
    np.testing.assert_allclose(drawn[0].reshape(2, 2)[:, 0], 6.02, atol=1e-12)
    assert np.all(np.isnan(drawn[2]))  # x cos 0.7 + y sin 0.7 = 20 misses the room's box


def test_feature_table_counts_a_failed_run_and_an_unmapped_pillar_as_the_worst():
    ok = {"status": "ok", "rmse_fixed": 0.01, "rmse_heading_deg": 0.1, "arc_centre_median": 0.02, "n_arcs": 1}
    rows = [
        {**ok, "seed": 1},
        {**ok, "seed": 2, "rmse_fixed": 0.03, "arc_centre_median": math.nan},  # the pillar not mapped
        {"seed": 3, "status": "failed", "reason": "non-finite"},
    ]
    other = [{**ok, "seed": s, "rmse_fixed": 0.02, "rmse_heading_deg": 0.2} for s in (1, 2, 3)]
    res = [MethodResult(MethodSpec("A", ()), "nasrukf", rows), MethodResult(MethodSpec("B", ()), "nasrukf", other)]
    text = feature_table(res)
    row_a = next(line for line in text.splitlines() if line.startswith("| A |"))
    cells = [c.strip() for c in row_a.split("|")[1:-1]]
    assert cells[2] == "3.00 (2.00-inf), worst inf, 1 failed"  # position RMSE (cm)
    assert cells[6] == "inf (inf-inf), worst inf, 2 failed"  # arc centre (cm): 1 failed run, 1 unmapped pillar
    # no world's pillar mapped: every run fails the column; a column no world has (break points) is n/a
    unmapped = MethodResult(MethodSpec("C", ()), "nasrukf", [{**r, "arc_centre_median": math.nan} for r in rows[:2]])
    row_c = next(line for line in feature_table([unmapped]).splitlines() if line.startswith("| C |"))
    cells_c = [c.strip() for c in row_c.split("|")[1:-1]]
    assert cells_c[6] == "inf (inf-inf), worst inf, 2 failed" and cells_c[9] == "n/a"
    assert "A against B, paired over the worlds: the smaller position RMSE in 1 of 3" in text
    assert "the smaller heading RMSE in 2 of 3" in text


def test_seed_keys_are_checked_and_a_log_directory_is_refused(tmp_path):
    base = ROOT / "configs" / "nasrukf_indoor.yaml"
    f = tmp_path / "study.yaml"
    f.write_text(f"base: {base}\nseed_keys: [indoor.seeed]\nmethods: [{{label: a, set: [filter.method=nasrukf]}}]\n")
    with pytest.raises(ConfigError, match="indoor.seeed"):
        load_compare_spec(f)
    f.write_text(f"base: {base}\nseed_keys: 3\nmethods: [{{label: a, set: [filter.method=nasrukf]}}]\n")
    with pytest.raises(ConfigError, match="seed_keys"):
        load_compare_spec(f)
    spec = load_compare_spec(ROOT / "configs" / "nasrukf_indoor_study.yaml")
    assert spec.seed_keys == ("indoor.seed",) and spec.seeds == 16
    cfgs = [seed_config(spec, m, 104) for m in spec.methods]
    assert all(c.seed == c.indoor.seed == 104 for c in cfgs)
    assert len({(c.indoor, c.detector) for c in cfgs}) == 1  # every row on the same worlds
    assert all(c.unicycle.sigma_v == pytest.approx(0.01 / 3) for c in cfgs)
    with pytest.raises(ConfigError, match="--data"):
        run_compare(spec, tmp_path / "out", data_dir=str(tmp_path))


@pytest.mark.slow
def test_the_study_on_two_tiny_worlds_writes_figures_and_a_table_of_the_plain_runs_metrics(tmp_path):
    from nanoslam_jax.app.experiment import execute

    study = load_compare_spec(
        ROOT / "configs" / "nasrukf_indoor_study.yaml", ("indoor.duration=2.5", "nasrukf.static_scans=10"), seeds=2
    )
    spec = dataclasses.replace(study, methods=(study.methods[0], study.methods[2]))  # NASRUKF and EKF-SLAM
    out = tmp_path / "study"
    rows = run_compare(spec, out, plots=True)
    assert [r["method"] for r in rows] == ["NASRUKF adaptive", "EKF-SLAM line+circle"]
    for name in ("fig5_pose_error.png", "fig6_map.png", "table1.md", "runs.csv", "summary.json"):
        assert (out / name).stat().st_size > 0, name
    text = (out / "table1.md").read_text()
    assert "the second paper's Table 1" in text and "| NASRUKF adaptive | 2 |" in text
    runs = list(csv.DictReader((out / "runs.csv").open()))
    assert sorted((r["method"], r["seed"]) for r in runs) == sorted(
        (m.label, str(s)) for m in spec.methods for s in (100, 101)
    )
    keys = ("rmse_fixed", "rmse_heading_deg", "line_intercept_median", "line_slope_median", "corner_median", "n_lines")
    for r in runs:
        m = next(m for m in spec.methods if m.label == r["method"])
        plain = execute(seed_config(spec, m, int(r["seed"])), progress=False).metrics
        assert r["status"] == "ok", r
        for k in keys + tuple(k for k in plain if k.startswith(("arc_", "break_point_"))):
            want = plain.get(k)
            if want is None or (isinstance(want, float) and math.isnan(want)):
                assert r.get(k, "") in ("", "nan"), (k, r.get(k))
            else:
                assert float(r[k]) == pytest.approx(float(want), rel=1e-9, abs=1e-12), (r["method"], k)
    summary = {r["method"]: r for r in rows}
    nas = [float(r["rmse_fixed"]) for r in runs if r["method"] == "NASRUKF adaptive"]
    assert summary["NASRUKF adaptive"]["rmse_fixed_median"] == pytest.approx(np.median(nas))
