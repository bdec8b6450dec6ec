"""Tests of the segment builder against hand-computed layouts and the real log's counts."""

import numpy as np
import pytest

from nanoslam_jax.data import RawLog, load_victoria_park, make_segments, segment_summary

HALF_PI = np.pi / 2

# DR at 1.0, 1.1, ..., 2.0 (11 samples): u_i = (i + 1, 0.01 i).
INPUTS = "".join(f"{1 + i / 10:.1f} {i + 1} {0.01 * i:.2f}\n" for i in range(11))
# File bearings (pi/2 straight ahead). Scan 0.5 is before t0; at 1.15 the 40 m detection is
# dropped; the only detection at 1.38 is dropped (empty scan); 2.3 is after the last DR sample
# and its 30 m detection is dropped (max_range is exclusive).
MEASUREMENTS = """\
0.5  10.0 1.5707963267948966 0.3
1.15  5.0 1.0 0.21
1.15 40.0 1.2 0.22
1.15  7.0 2.0 0.23
1.38 35.0 1.0 0.24
2.3  12.0 0.5 0.25
2.3  30.0 0.6 0.26
"""
GPS = "0.0 0.0 0.0\n"


@pytest.fixture
def tiny(tmp_path):
    for name, text in (("inputs.dat", INPUTS), ("measurements.dat", MEASUREMENTS), ("gps.dat", GPS)):
        (tmp_path / name).write_text(text)
    return load_victoria_park(tmp_path)


def expected_pieces(pieces_per_segment, max_pieces):
    """dt, u and dr_mask padded from per-segment lists of (DR index, dt)."""
    n = len(pieces_per_segment)
    dt, u, mask = np.zeros((n, max_pieces)), np.zeros((n, max_pieces, 2)), np.zeros((n, max_pieces), bool)
    for s, pieces in enumerate(pieces_per_segment):
        for k, (i, d) in enumerate(pieces):
            dt[s, k], u[s, k], mask[s, k] = d, (i + 1, 0.01 * i), True
    return dt, u, mask


def assert_pieces(seg, pieces_per_segment):
    dt, u, mask = expected_pieces(pieces_per_segment, seg.dt.shape[1])
    assert np.array_equal(seg.dr_mask, mask)
    assert np.allclose(seg.dt, dt, rtol=0, atol=1e-12)
    assert np.allclose(seg.u, u, rtol=0, atol=1e-12)


def test_tiny_log_split_into_extra_segments(tiny):
    """max_dr_per_segment=3: the 1.38 -> 2.3 gap (8 pieces) becomes segments ending at 1.6, 1.9, 2.3."""
    seg = make_segments(tiny, max_range=30.0, max_dr_per_segment=3)
    assert np.allclose(seg.time, [0.5, 1.15, 1.38, 1.6, 1.9, 2.3], rtol=0, atol=1e-12)
    assert_pieces(
        seg,
        [
            [],  # before t0: the pose stays at the origin
            [(0, 0.1), (1, 0.05)],  # 1.0 -> 1.15
            [(1, 0.05), (2, 0.1), (3, 0.08)],  # 1.15 -> 1.38: exactly 3 pieces, no split
            [(3, 0.02), (4, 0.1), (5, 0.1)],  # 1.38 -> 1.6 (extra)
            [(6, 0.1), (7, 0.1), (8, 0.1)],  # 1.6 -> 1.9 (extra)
            [(9, 0.1), (10, 0.3)],  # 1.9 -> 2.3: the last sample holds past 2.0
        ],
    )
    assert seg.k_max == 2
    z = np.zeros((6, 2, 2))
    z[0, 0] = (10.0, 0.0)
    z[1, 0], z[1, 1] = (5.0, 1.0 - HALF_PI), (7.0, 2.0 - HALF_PI)
    z[5, 0] = (12.0, 0.5 - HALF_PI)
    mask = np.zeros((6, 2), bool)
    mask[[0, 1, 1, 5], [0, 0, 1, 0]] = True
    assert np.array_equal(seg.z_mask, mask)
    assert np.allclose(seg.z, z, rtol=0, atol=1e-12)
    # each detection keeps its own diameter (4th column), padding 0
    diam = np.zeros((6, 2))
    diam[0, 0], diam[1, 0], diam[1, 1], diam[5, 0] = 0.3, 0.21, 0.23, 0.25
    assert np.allclose(seg.diam, diam, rtol=0, atol=1e-12)
    # the extra segments splitting the 1.38 -> 2.3 gap are not scans
    np.testing.assert_array_equal(seg.is_scan, [True, True, True, False, False, True])


def test_tiny_log_without_split(tiny):
    seg = make_segments(tiny, max_range=30.0, max_dr_per_segment=12)
    assert np.allclose(seg.time, [0.5, 1.15, 1.38, 2.3], rtol=0, atol=1e-12)
    assert_pieces(
        seg,
        [
            [],
            [(0, 0.1), (1, 0.05)],
            [(1, 0.05), (2, 0.1), (3, 0.08)],
            [(3, 0.02), (4, 0.1), (5, 0.1), (6, 0.1), (7, 0.1), (8, 0.1), (9, 0.1), (10, 0.3)],
        ],
    )
    assert seg.dt.shape == (4, 12) and seg.u.shape == (4, 12, 2)


def test_range_filter_k_max_padding_and_t_end(tiny):
    seg = make_segments(tiny, min_range=6.0, max_range=100.0, k_max=4, t_end=1.38)
    assert np.allclose(seg.time, [0.5, 1.15, 1.38], rtol=0, atol=1e-12)
    assert seg.z.shape == (3, 4, 2)
    # file order kept: 40 m before 7 m; 5 m dropped by min_range
    assert np.allclose(seg.z[1, :2, 0], [40.0, 7.0]) and np.array_equal(seg.z_mask[1], [True, True, False, False])
    assert np.allclose(seg.diam[1, :2], [0.22, 0.23]) and seg.diam.shape == (3, 4)
    assert np.array_equal(seg.z_mask.sum(axis=1), [1, 2, 1])
    assert np.all(seg.z[~seg.z_mask] == 0.0)


def test_k_max_too_small(tiny):
    with pytest.raises(ValueError, match=r"data\.k_max=1 .* t=1\.150 s has 2 detections"):
        make_segments(tiny, max_range=30.0, k_max=1)


def test_no_scan_before_t_end(tiny):
    with pytest.raises(ValueError, match="no laser scan up to t_end=0.1"):
        make_segments(tiny, t_end=0.1)


def test_scan_on_a_dr_sample_gives_no_zero_length_piece():
    dr = np.array([[0.0, 1.0, 0.0], [1.0, 2.0, 0.1], [2.0, 3.0, 0.2], [3.0, 4.0, 0.3]])
    det = np.array([[1.0, 5.0, 0.0, 0.1], [2.5, 5.0, 0.0, 0.1], [2.5, 6.0, 0.1, 0.1]])
    raw = RawLog(dr=dr, detections=det, gps=np.zeros((1, 3)))
    seg = make_segments(raw, max_dr_per_segment=3)
    assert np.allclose(seg.time, [1.0, 2.5])
    assert np.array_equal(seg.dr_mask, [[True, False, False], [True, True, False]])
    assert np.allclose(seg.dt, [[1.0, 0, 0], [1.0, 0.5, 0]])
    assert np.allclose(seg.u[..., 0], [[1.0, 0, 0], [2.0, 3.0, 0]])
    # one piece per segment: the 1.0 -> 2.5 gap is split at the DR sample 2.0
    seg = make_segments(raw, max_dr_per_segment=1)
    assert np.allclose(seg.time, [1.0, 2.0, 2.5])
    assert np.allclose(seg.dt[:, 0], [1.0, 1.0, 0.5]) and seg.dr_mask.all()
    assert np.allclose(seg.u[:, 0, 0], [1.0, 2.0, 3.0])
    assert np.array_equal(seg.z_mask.sum(axis=1), [1, 0, 2])


def test_summary(tiny):
    summary = segment_summary(make_segments(tiny, max_range=30.0, max_dr_per_segment=3))
    assert summary == dict(
        n_segments=6,
        n_detections=4,
        n_scans_with_detections=3,
        max_detections_per_scan=2,
        max_pieces=3,
        k_max=2,
        dr_per_segment=3,
    )


# --------------------------------------------------------------------------- the real log


@pytest.fixture(scope="module")
def real(vp_dir):
    return load_victoria_park(vp_dir)


def test_real_log_published_counts(real):
    """The real log with r < 30 m, 37,398 detections in 7,174 scans, at most 14."""
    seg = make_segments(real, max_range=30.0)
    summary = segment_summary(seg)
    assert summary["n_detections"] == 37398
    assert summary["n_scans_with_detections"] == 7174
    assert summary["max_detections_per_scan"] == 14 == seg.k_max
    assert summary["max_pieces"] <= 12
    # one segment per scan (all 7,230 scan times), plus extra ones for long gaps
    assert np.isin(real.scan_times, seg.time).all()
    assert summary["n_segments"] > 7230

    full = segment_summary(make_segments(real, max_range=np.inf))
    assert (full["n_detections"], full["n_scans_with_detections"], full["max_detections_per_scan"]) == (52974, 7230, 18)


def test_real_log_time_is_conserved(real):
    seg = make_segments(real, max_range=30.0)
    t0 = real.dr[0, 0]
    assert np.all(np.diff(seg.time) > 0)
    assert np.all(seg.dt[seg.dr_mask] > 0) and np.all(seg.dt[~seg.dr_mask] == 0)
    total = (seg.dt * seg.dr_mask).sum()
    assert total == pytest.approx(real.scan_times[-1] - t0, abs=1e-6)
    clipped = np.maximum(seg.time, t0)
    assert np.allclose(seg.dt.sum(axis=1), np.diff(clipped, prepend=t0), rtol=0, atol=1e-9)


def test_real_log_pieces_use_the_held_dr_sample(real):
    """Every piece's control is the DR sample whose interval contains the piece's midpoint."""
    seg = make_segments(real, max_range=30.0)
    t = real.dr[:, 0]
    start = np.maximum(np.concatenate([[t[0]], seg.time[:-1]]), t[0])
    ends = start[:, None] + np.cumsum(seg.dt, axis=1)
    mid = (ends - seg.dt / 2)[seg.dr_mask]
    held = np.searchsorted(t, mid, side="right") - 1
    assert np.array_equal(seg.u[seg.dr_mask], real.dr[held, 1:3])
    # masks are prefixes: real pieces first, then padding
    assert np.array_equal(seg.dr_mask, np.arange(12) < seg.dr_mask.sum(axis=1, keepdims=True))
    assert np.array_equal(seg.z_mask, np.arange(seg.k_max) < seg.z_mask.sum(axis=1, keepdims=True))
