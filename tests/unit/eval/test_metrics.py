"""Tests of the evaluation protocol (nanoslam_jax.eval.metrics) against hand-computed truths."""

import math
import numpy as np
import pytest

from nanoslam_jax.eval.metrics import (
    GPS_DAT_ROTATION_DEG,
    error_over_time,
    evaluate,
    interpolate_at,
    jump_mask,
    landmark_errors,
    relative_gps,
    rigid_align,
    rotation_matrix,
)


def _rot(deg):
    a = math.radians(deg)
    return np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])


def _track(n=200):
    """A curvy trajectory sampled at 5 Hz: (t, xy)."""
    t = np.arange(n) / 5.0
    xy = np.stack([20 * np.sin(0.05 * t) + 0.3 * t, 15 * (1 - np.cos(0.08 * t))], axis=1)
    return t, xy


# --------------------------------------------------------------------------- rigid alignment


def test_rigid_align_recovers_known_transform():
    rng = np.random.default_rng(1)
    est = rng.normal(size=(50, 2)) * 30
    R_true, t_true = _rot(37.0), np.array([12.5, -4.0])
    ref = est @ R_true.T + t_true
    R, t, aligned = rigid_align(est, ref)
    np.testing.assert_allclose(R, R_true, atol=1e-12)
    np.testing.assert_allclose(t, t_true, atol=1e-10)
    np.testing.assert_allclose(aligned, ref, atol=1e-10)


def test_rigid_align_never_reflects():
    rng = np.random.default_rng(2)
    est = rng.normal(size=(40, 2))
    ref = est * np.array([1.0, -1.0])  # a mirror image: the best proper rotation is not exact
    R, _, _ = rigid_align(est, ref)
    assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_allclose(R @ R.T, np.eye(2), atol=1e-12)


def test_rigid_align_single_point_is_translation():
    R, t, aligned = rigid_align(np.array([[1.0, 2.0]]), np.array([[4.0, 6.0]]))
    np.testing.assert_allclose(R, np.eye(2))
    np.testing.assert_allclose(t, [3.0, 4.0])
    np.testing.assert_allclose(aligned, [[4.0, 6.0]])


def test_evaluate_aligned_rmse_zero_for_rigidly_moved_estimate():
    t, xy = _track()
    gps = np.column_stack([t, xy])
    est = xy @ _rot(-20.0).T + np.array([5.0, 7.0])  # the estimate is the truth in another frame
    m = evaluate(t, est, gps, frame="slam")
    assert m["rmse_aligned"] < 1e-9
    assert m["rmse_aligned_clean"] < 1e-9
    assert m["align_rotation_deg"] == pytest.approx(20.0, abs=1e-9)
    assert m["rmse_fixed"] > 1.0


# --------------------------------------------------------------------------- hand-computed errors


def test_constant_345_offset():
    t, xy = _track(50)
    gps = np.column_stack([t, xy])
    m = evaluate(t, xy + np.array([3.0, 4.0]), gps, frame="slam")
    for key in ("rmse_fixed", "rmse_fixed_clean", "mean_error", "max_error", "final_error"):
        assert m[key] == pytest.approx(5.0, abs=1e-12), key
    assert m["rmse_aligned"] < 1e-9
    assert m["n_fixes"] == 50 and m["n_fixes_clean"] == 50 and m["n_fixes_outside"] == 0 and m["n_gps"] == 50


def test_small_hand_example():
    # errors 0, 3, 4 along x -> rmse sqrt(25/3), mean 7/3, max 4, final 4
    gps = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 0.0], [2.0, 2.0, 0.0]])
    est_t = np.array([0.0, 1.0, 2.0])
    est_xy = np.array([[0.0, 0.0], [4.0, 0.0], [6.0, 0.0]])
    m = evaluate(est_t, est_xy, gps, frame="slam")
    assert m["rmse_fixed"] == pytest.approx(math.sqrt(25.0 / 3.0))
    assert m["mean_error"] == pytest.approx(7.0 / 3.0)
    assert m["max_error"] == pytest.approx(4.0)
    assert m["final_error"] == pytest.approx(4.0)
    t, err = error_over_time(est_t, est_xy, gps, frame="slam")
    np.testing.assert_allclose(t, [0.0, 1.0, 2.0])
    np.testing.assert_allclose(err, [0.0, 3.0, 4.0])


def test_relative_frame_in_evaluate():
    # estimate = relative GPS exactly -> zero fixed error in the relative frame
    t, xy = _track(80)
    gps = np.column_stack([t, xy + np.array([100.0, -50.0])])
    est = relative_gps(gps[:, 1:], -35.4)
    m = evaluate(t, est, gps, rotation_deg=-35.4)
    assert m["rmse_fixed"] < 1e-12
    m2 = evaluate(t, est, gps, rotation_deg=-35.4 + 10.0)
    assert m2["rmse_fixed"] > 1.0 and m2["rmse_aligned"] < 1e-9


# --------------------------------------------------------------------------- interpolation


def test_interpolation_exact_on_linear_trajectory():
    est_t = np.array([0.0, 0.7, 1.1, 2.5, 4.0, 4.0, 6.0])  # irregular, with a repeated time
    est_xy = np.stack([2.0 * est_t + 1.0, -est_t + 3.0], axis=1)
    q = np.array([-1.0, 0.0, 0.33, 1.9, 3.2, 4.0, 5.5, 6.0, 7.0])
    xy, inside = interpolate_at(q, est_t, est_xy)
    np.testing.assert_array_equal(inside, [False, True, True, True, True, True, True, True, False])
    np.testing.assert_allclose(xy[inside], np.stack([2.0 * q[inside] + 1.0, -q[inside] + 3.0], axis=1), atol=1e-12)
    assert np.all(np.isnan(xy[~inside]))


def test_interpolation_rejects_decreasing_time():
    with pytest.raises(ValueError, match="non-decreasing"):
        interpolate_at([0.5], [0.0, 1.0, 0.5], np.zeros((3, 2)))


# --------------------------------------------------------------------------- relative GPS


def test_relative_gps_hand_example():
    gps = np.array([[1.0, 1.0], [1.0, 2.0], [2.0, 1.0]])
    out = relative_gps(gps, 90.0, source_rotation_deg=0.0)
    # minus first fix: (0,0), (0,1), (1,0); rotate +90 deg: (0,1) -> (-1,0), (1,0) -> (0,1)
    np.testing.assert_allclose(out, [[0.0, 0.0], [-1.0, 0.0], [0.0, 1.0]], atol=1e-12)


def test_relative_gps_from_gps_dat_matches_raw_construction():
    """gps.dat = R(-33)(Lo + 67, La + 39); the relative frame is R(-35.4)(raw - raw[0])."""
    rng = np.random.default_rng(3)
    raw = rng.normal(size=(20, 2)) * 100
    gps_dat = (raw + np.array([67.0, 39.0])) @ _rot(-33.0).T
    expected = (raw - raw[0]) @ _rot(-35.4).T
    assert GPS_DAT_ROTATION_DEG == -33.0
    np.testing.assert_allclose(relative_gps(gps_dat, -35.4), expected, atol=1e-9)
    np.testing.assert_allclose(relative_gps(raw, -35.4, source_rotation_deg=0.0), expected, atol=1e-9)
    np.testing.assert_allclose(rotation_matrix(30.0), _rot(30.0))


# --------------------------------------------------------------------------- GPS jumps


def test_jump_mask_one_jump():
    t = np.array([0.0, 1.0, 2.0, 3.0, 4.0])
    xy = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [50.0, 0.0], [4.0, 0.0]])
    np.testing.assert_array_equal(jump_mask(t, xy, 8.0), [True, True, True, False, True])


def test_jump_mask_lasting_offset_recovers():
    # t = k, x = k for k <= 1, then x = 100 + k: from the last kept fix (t=1, x=1) the implied
    # speed is (99 + k) / (k - 1) <= 8 first for k = 16.
    t = np.arange(25, dtype=float)
    x = np.where(t <= 1, t, 100.0 + t)
    keep = jump_mask(t, np.column_stack([x, np.zeros_like(x)]), 8.0)
    expected = (t <= 1) | (t >= 16)
    np.testing.assert_array_equal(keep, expected)


def test_jump_mask_duplicate_time_and_threshold():
    t = np.array([0.0, 0.0, 0.0, 1.0])
    xy = np.array([[0.0, 0.0], [0.0, 0.0], [1.0, 0.0], [8.0, 0.0]])
    # same time same place kept; same time elsewhere dropped; exactly max_speed kept
    np.testing.assert_array_equal(jump_mask(t, xy, 8.0), [True, True, False, True])


def test_clean_metrics_drop_outlier():
    t, xy = _track(100)
    gps = np.column_stack([t, xy])
    gps[40, 1] += 50.0  # one outlier fix
    m = evaluate(t, xy, gps, frame="slam")
    assert m["rmse_fixed"] == pytest.approx(math.sqrt(50.0**2 / 100))
    assert m["max_error"] == pytest.approx(50.0)
    assert m["rmse_fixed_clean"] < 1e-12
    assert m["rmse_aligned_clean"] < 1e-9
    assert m["n_fixes_clean"] == 99 and m["n_fixes"] == 100


# --------------------------------------------------------------------------- estimate span


def test_fixes_outside_span_are_excluded_and_counted():
    gps_t = np.arange(11, dtype=float)
    gps = np.column_stack([gps_t, gps_t, np.zeros(11)])
    est_t = np.linspace(2.0, 7.0, 26)
    est_xy = np.column_stack([est_t + 1.0, np.zeros_like(est_t)])  # 1 m ahead
    m = evaluate(est_t, est_xy, gps, frame="slam")
    assert m["n_fixes"] == 6 and m["n_fixes_outside"] == 5 and m["n_gps"] == 11
    assert m["rmse_fixed"] == pytest.approx(1.0)
    t, err = error_over_time(est_t, est_xy, gps, frame="slam")
    np.testing.assert_allclose(t, [2, 3, 4, 5, 6, 7])


def test_no_overlap_raises():
    gps = np.column_stack([np.arange(10.0), np.zeros(10), np.zeros(10)])
    with pytest.raises(ValueError, match="no GPS fix"):
        evaluate(np.array([20.0, 30.0]), np.zeros((2, 2)), gps, frame="slam")
    with pytest.raises(ValueError, match="frame"):
        evaluate(np.array([0.0, 3.0]), np.zeros((2, 2)), gps, frame="utm")


# --------------------------------------------------------------------------- landmarks


def test_landmark_errors_hand_example():
    true = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]])
    est = np.array([[0.0, 1.0], [10.0, 0.0], [50.0, 50.0]])
    out = landmark_errors(est, true, radius=2.0)
    np.testing.assert_allclose(out["est_to_true"], [1.0, 0.0, math.hypot(40.0, 50.0)])
    np.testing.assert_allclose(out["true_to_est"], [1.0, 0.0, 9.0])
    assert (out["n_est"], out["n_true"], out["n_matched"], out["n_spurious"], out["n_found"]) == (3, 3, 2, 1, 2)
    assert out["rmse_matched"] == pytest.approx(math.sqrt(0.5))
    empty = landmark_errors(np.zeros((0, 2)), true)
    assert empty["n_est"] == 0 and empty["n_found"] == 0 and math.isnan(empty["rmse_matched"])


# --------------------------------------------------------------------------- the real log (optional)


def test_relative_frame_on_real_log_matches_dead_reckoning(vp_dir):
    """Spec section 1: dead reckoning stays within about 2 m of GPS over the first 80 s.

    Checks the frame conventions of relative_gps on gps.dat: with the default
    source_rotation_deg the DR track lies within a few metres of the relative-GPS frame.
    """
    d = vp_dir
    u = np.loadtxt(d / "inputs.dat", max_rows=3400)
    gps = np.loadtxt(d / "gps.dat")
    L, H, a, b = 2.83, 0.76, 3.78, 0.50
    x = np.zeros(3)
    poses = [x.copy()]
    for k in range(u.shape[0] - 1):
        dt = u[k + 1, 0] - u[k, 0]
        ve, al = u[k, 1], u[k, 2]
        vc = ve / (1 - math.tan(al) * H / L)
        w = vc / L * math.tan(al)
        s, c = math.sin(x[2]), math.cos(x[2])
        x = x + dt * np.array([vc * c - w * (a * s + b * c), vc * s + w * (a * c - b * s), w])
        poses.append(x.copy())
    poses = np.array(poses)
    keep = u[:, 0] <= 80.0
    m = evaluate(u[keep, 0], poses[keep, :2], gps, rotation_deg=-35.4)
    assert m["rmse_fixed"] < 4.0, m
    assert m["max_error"] < 6.0, m
