"""What the CLI tests share: calling ``nanoslam`` in-process and checking its one-line errors, and
the files ``nanoslam simulate`` writes (tests/unit/app/test_cli.py, tests/e2e/test_cli.py)."""

from __future__ import annotations

from nanoslam_jax.app.cli import main

SIM_FILES = [
    "inputs.dat",
    "measurements.dat",
    "gps.dat",
    "truth_poses.dat",
    "truth_landmarks.dat",
    "truth_diameters.dat",
]


def call(capsys, argv):
    """``main(argv)`` -> (exit code, stdout, stderr)."""
    capsys.readouterr()
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


def check_one_line_error(rc, err, *fragments):
    """The exit code 2 and one ``nanoslam: error:`` line holding every fragment, no traceback."""
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("nanoslam: error: ")
    assert "Traceback" not in err
    for f in fragments:
        assert f in lines[0], (f, lines[0])
