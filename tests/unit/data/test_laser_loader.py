"""Tests of the raw laser scan reader (LASER.txt, aa3_lsr2.mat)."""

import numpy as np
import pytest
import scipy.io

from nanoslam_jax.data import LaserScans, LogFormatError, load_laser
from nanoslam_jax.data._laser import NO_RETURN, write_laser
from tests.helpers.paths import SHARED_DATA

REAL = SHARED_DATA / "victoria_park"


def _scans(n_scans: int = 3, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = 0.852 + 0.2133 * np.arange(n_scans)
    r = np.round(rng.uniform(1.0, 60.0, (n_scans, 361)), 2)
    r[:, ::7] = 81.91  # no returns
    return t, r


def _text(t, r, per_line: bool) -> str:
    rows = ["\t".join([f"{ti:.3f}"] + [f"{v:.2f}" for v in ri]) for ti, ri in zip(t, r)]
    return ("\n".join(rows) + "\n") if per_line else "\t".join(rows)


@pytest.mark.parametrize("per_line", [False, True])
def test_reads_a_flat_stream_and_a_per_line_file(tmp_path, per_line):
    t, r = _scans()
    (tmp_path / "LASER.txt").write_text(_text(t, r, per_line))
    s = load_laser(tmp_path)  # the directory: finds LASER.txt
    np.testing.assert_allclose(s.time, np.round(t, 3))
    np.testing.assert_array_equal(s.ranges, r)
    assert s.ranges.shape == (3, 361)
    # vehicle frame: beam 0 at -90 deg (right), 180 straight ahead, 360 at +90 deg (left)
    np.testing.assert_allclose(s.angles[[0, 180, 360]], [-np.pi / 2, 0.0, np.pi / 2], atol=1e-12)
    np.testing.assert_allclose(np.diff(s.angles), np.deg2rad(0.5))
    assert (~s.valid).sum() == (r >= 80).sum() == 3 * 52


def test_write_laser_reads_back(tmp_path):
    t, r = _scans()
    r[0, 5] = 95.0  # beyond the scanner's range: written as no return
    write_laser(tmp_path / "LASER.txt", LaserScans(t, r, np.deg2rad(np.linspace(-90.0, 90.0, 361))))
    s = load_laser(tmp_path / "LASER.txt")
    np.testing.assert_allclose(s.time, t, atol=1e-6)
    expected = np.where(r >= 80.0, NO_RETURN, r)
    np.testing.assert_allclose(s.ranges, expected, atol=5e-4)
    assert not s.valid[0, 5]


def test_reads_a_mat_file_in_cm_and_ms(tmp_path):
    t, r = _scans()
    t_ms = np.round(t * 1000).astype(np.uint32) + 20967  # the MATLAB files' clock
    scipy.io.savemat(
        tmp_path / "aa3_lsr2.mat", {"LASER": np.round(r * 100).astype(np.uint16), "TLsr": t_ms.reshape(-1, 1)}
    )
    s = load_laser(tmp_path)
    np.testing.assert_allclose(s.time, np.round(t, 3), atol=1e-9)
    np.testing.assert_allclose(s.ranges, r, atol=1e-9)
    # ASCII preferred when both exist
    (tmp_path / "LASER.txt").write_text(_text(t[:2], r[:2], False))
    assert load_laser(tmp_path).n_scans == 2
    assert load_laser(tmp_path / "aa3_lsr2.mat").n_scans == 3


def test_wrong_count_names_the_file_and_position(tmp_path):
    t, r = _scans(2)
    text = _text(t, r, False)  # one stream: the position is a number's
    (tmp_path / "LASER.txt").write_text(text + "\n3.0 1.0 2.0\n")
    with pytest.raises(LogFormatError) as e:
        load_laser(tmp_path / "LASER.txt")
    msg = str(e.value)
    assert "LASER.txt" in msg and "multiple of 362" in msg and "got 727" in msg
    assert "number 725" in msg and "line 2" in msg


@pytest.mark.parametrize("short", [0, 2, 4])
def test_a_short_row_of_a_per_line_file_is_named_by_its_line(tmp_path, short):
    t, r = _scans(5)
    rows = _text(t, r, True).splitlines()
    rows[short] = "\t".join(rows[short].split("\t")[:300])  # the file starts with a blank line
    (tmp_path / "LASER.txt").write_text("\n" + "\n".join(rows) + "\n")
    with pytest.raises(LogFormatError, match=rf"LASER\.txt line {short + 2}: expected 362 numbers .* got 300$"):
        load_laser(tmp_path / "LASER.txt")


def test_text_in_the_stream_names_the_file_line_and_number(tmp_path):
    t, r = _scans(3)
    rows = _text(t, r, True).splitlines()
    tokens = rows[1].split("\t")
    tokens[11] = "n/a"
    rows[1] = "\t".join(tokens)
    (tmp_path / "LASER.txt").write_text("\n".join(rows) + "\n")
    with pytest.raises(LogFormatError) as e:
        load_laser(tmp_path / "LASER.txt")
    msg = str(e.value)
    assert "LASER.txt line 2" in msg and "number 374" in msg and "'n/a'" in msg and "beam 10" in msg


def test_decreasing_times_and_negative_ranges_are_errors(tmp_path):
    t, r = _scans(3)
    t[2] = t[0]
    (tmp_path / "LASER.txt").write_text(_text(t, r, True))
    with pytest.raises(LogFormatError, match=r"line 3.*non-decreasing"):
        load_laser(tmp_path)
    t, r = _scans(3)
    r[1, 5] = -1.0
    (tmp_path / "LASER.txt").write_text(_text(t, r, True))
    with pytest.raises(LogFormatError, match=r"line 2, number 369 \(scan 2, beam 5\).*>= 0"):
        load_laser(tmp_path)


def test_missing_files_and_bad_mat(tmp_path):
    with pytest.raises(FileNotFoundError, match="LASER.txt or aa3_lsr2.mat"):
        load_laser(tmp_path)
    scipy.io.savemat(tmp_path / "aa3_lsr2.mat", {"LASER": np.ones((2, 361))})
    with pytest.raises(LogFormatError, match="TLsr"):
        load_laser(tmp_path)


def test_laserscans_checks_shapes():
    with pytest.raises(ValueError, match="ranges must have shape"):
        LaserScans(np.zeros(2), np.zeros((3, 5)), np.arange(5.0))


@pytest.mark.slow
@pytest.mark.data
@pytest.mark.skipif(
    not (REAL / "LASER.txt").is_file(), reason="the Victoria Park raw scans (../shared/data) are missing"
)
def test_real_log():
    s = load_laser(REAL)
    assert s.ranges.shape == (7230, 361)
    assert s.time[0] == pytest.approx(0.852) and s.time[-1] == pytest.approx(1545.182)
    assert np.all(np.diff(s.time) > 0)
