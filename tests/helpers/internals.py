"""Private names of one package that the unit tests of another package need, and why.

Each is an internal piece with no public name that a test compares against, drives or patches;
reaching it here, in one documented place, keeps the rule that a test imports no private module
of a package other than the one it tests (``tests/unit/test_test_layout.py``).

- ``nanoslam_jax.lib._cache``: the compile hooks the application's compile messages plug into
  (``CACHE_ENV``, ``ProgramInfo``, ``watch_compiles``, ``watched_compile``; tests/unit/app/
  test_compile_messages.py), and the folder where the cache keeps traced programs
  (``exported_dir``; tests/unit/methods/test_filter.py: a program served by a filled cache).
- ``nanoslam_jax.eval._scoring`` and ``nanoslam_jax.eval._feature_metrics``: the one scorer's map of
  lines with arcs (``with_arcs``) and the break-point errors of walls
  (``break_point_line_errors``) the indoor study's tests check (tests/unit/app/test_study_indoor.py).
- ``nanoslam_jax.app.study._runner``: the study's runner, whose timing process the scorer's test
  through the study replaces (``study_runner``; tests/unit/eval/test_scoring.py).
- ``nanoslam_jax.app.sweep._batch``: a sweep member's traced program (``sweep_batch``), the path
  test's comparison of a sweep with a single run (tests/unit/methods/test_path.py).
- ``nanoslam_jax.app._models``: the motion model a configuration builds
  (``motion_model_from_config``; tests/unit/models/test_odometry.py).
- ``nanoslam_jax.methods.maps._association``: the generic innovation and information of a
  measurement model (``innovation_information``; tests/unit/models/test_measurement_models.py).
- ``nanoslam_jax.methods._params``: the module whose ``ROW_BUCKETS_WORK`` threshold a sweep's
  plan reads for ``filter.row_buckets: auto`` (``filter_params``, patched by
  tests/unit/app/test_sweep.py).
- ``nanoslam_jax.methods.particle._prior``: one piece of the prior's unscented transform
  (``ut_piece``), the motion models' fast path against the generic one
  (tests/unit/models/test_motion_models.py).
"""

from nanoslam_jax.app._models import motion_model_from_config
from nanoslam_jax.app.study import _runner as study_runner
from nanoslam_jax.app.sweep import _batch as sweep_batch
from nanoslam_jax.eval._feature_metrics import break_point_line_errors
from nanoslam_jax.eval._scoring import with_arcs
from nanoslam_jax.lib._cache import CACHE_ENV, ProgramInfo, watch_compiles, watched_compile
from nanoslam_jax.lib._cache import _exported_dir as exported_dir
from nanoslam_jax.methods import _params as filter_params
from nanoslam_jax.methods.maps._association import innovation_information
from nanoslam_jax.methods.particle._prior import _ut_piece as ut_piece

__all__ = [
    "CACHE_ENV",
    "ProgramInfo",
    "break_point_line_errors",
    "exported_dir",
    "filter_params",
    "innovation_information",
    "motion_model_from_config",
    "study_runner",
    "sweep_batch",
    "ut_piece",
    "watch_compiles",
    "watched_compile",
    "with_arcs",
]
