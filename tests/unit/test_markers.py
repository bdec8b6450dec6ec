"""The test tiers and the test session's shape checks.

``-m "not slow"`` (the fast tier) must leave out the end-to-end tests and keep the unit tests;
``data`` must be set on the tests that read the real log; a test that starts a subprocess is
end-to-end. The jaxtyping annotations of the public models hold under beartype.
"""

import inspect
import os
import re
import subprocess
import sys

import jax.numpy as jnp
import jaxtyping
import numpy as np
import pytest
from tests.helpers.paths import REPO_ROOT

ROOT = REPO_ROOT

# whole-log and end-to-end tests: never in the fast tier
SLOW = (
    "tests/e2e/test_cli.py::test_the_embedded_default_beats_dead_reckoning_and_maps_the_trees",
    "tests/e2e/test_cli.py::test_console_script_help",
    "tests/e2e/test_cli.py::test_dead_reckoning_drifts_to_order_150_m_over_the_run",
    "tests/unit/methods/test_filter.py::test_victoria_park_paper_setting",
    "tests/unit/methods/test_filter.py::test_tracks_truth_and_maps_trees",
    "tests/unit/app/test_sweep.py::test_cli_end_to_end",
    "tests/unit/app/test_study.py::test_quick_variant_runs_end_to_end_on_a_simulated_log",
)
# unit tests: always in the fast tier
FAST = (
    "tests/unit/app/test_cli.py::test_missing_or_unknown_command_is_a_usage_error",
    "tests/unit/methods/test_filter.py::test_scan_prefix_is_the_scan_of_the_prefix",
    "tests/unit/app/test_sweep_spec.py::test_grid_expansion_is_the_cartesian_product_with_seeds",
    "tests/unit/app/test_study.py::test_summary_medians_quartiles_and_worst_seed_by_hand",
)


def _collect(*args: str) -> list[str]:
    files = sorted({node.split("::")[0] for node in SLOW + FAST})
    proc = subprocess.run(
        [sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider", *args, *files],
        check=False,
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=600,
        env={**os.environ, "NANOSLAM_TYPECHECK": "0"},
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return [line.split("[")[0] for line in proc.stdout.splitlines() if "::" in line]


@pytest.mark.slow
def test_fast_tier_leaves_out_the_end_to_end_tests():
    fast = set(_collect("-m", "not slow"))
    assert not fast & set(SLOW), sorted(fast & set(SLOW))
    assert set(FAST) <= fast, sorted(set(FAST) - fast)


def test_every_test_that_starts_a_subprocess_is_slow(request):
    """Over the tests collected in this session (the slow ones are deselected by the fast tier),
    but this module's: its subprocess is the collection above."""
    unmarked = []
    for item in request.session.items:
        fn = getattr(item, "function", None)
        if fn is None or fn.__module__ == __name__ or item.get_closest_marker("slow"):
            continue
        if "subprocess." in inspect.getsource(fn):
            unmarked.append(item.nodeid)
    assert not unmarked, f"start a subprocess but are not marked slow: {unmarked}"


def test_tests_that_read_a_real_dataset_are_marked_data(request):
    """Through the dataset fixtures or the path of ../shared/data (``REAL``) in the test itself."""
    unmarked = []
    for item in request.session.items:
        fn = getattr(item, "function", None)
        if fn is None or fn.__module__ == __name__ or item.get_closest_marker("data"):
            continue
        fixtures = set(getattr(item, "fixturenames", ()))
        if fixtures & {"vp_dir", "mrclam_dir"} or re.search(r"\bREAL\b", inspect.getsource(fn)):
            unmarked.append(item.nodeid)
    assert not unmarked, f"read a real dataset but are not marked data: {unmarked}"


@pytest.mark.slow
def test_shapes_of_the_public_models_are_checked():
    """Under jaxtyping with beartype, the public measurement model takes a pose of 3 components
    and a landmark of 2 (``Float[ArrayLike, "3"]``, ``Float[ArrayLike, "2"]``) and refuses others
    before any computation; the same check the whole session's import hook applies (tests/conftest.py)."""
    from beartype import beartype

    from nanoslam_jax.models import range_bearing, range_bearing_jacobians

    checked = jaxtyping.jaxtyped(typechecker=beartype)(range_bearing)
    np.testing.assert_allclose(checked(jnp.zeros(3), jnp.array([3.0, 4.0])), [5.0, np.arctan2(4.0, 3.0)])
    with pytest.raises(jaxtyping.TypeCheckError):
        checked(jnp.zeros(4), jnp.ones(2))
    with pytest.raises(jaxtyping.TypeCheckError):
        checked(jnp.zeros(3), jnp.ones(3))
    jacobians = jaxtyping.jaxtyped(typechecker=beartype)(range_bearing_jacobians)
    hx, hm = jacobians(jnp.zeros(3), jnp.array([3.0, 4.0]))
    assert hx.shape == (2, 3) and hm.shape == (2, 2)
