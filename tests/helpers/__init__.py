"""The test suite's documented testing helpers, imported as ``tests.helpers.<module>``.

- :mod:`tests.helpers.paths`: the repository's root, its configs and docs, and the shared
  datasets (``../shared/data``), so that no test counts parent directories of its own file.
- :mod:`tests.helpers.baselines`: the dead-reckoning baseline every end-to-end accuracy test
  measures itself against.
- :mod:`tests.helpers.gaussian_slam_checks`: checks shared by the tests of EKF-SLAM and NASRUKF;
  it drives the scan driver's private chunk step (``nanoslam_jax.methods._scan``) to check that
  padding segments leave the state as it was.
- :mod:`tests.helpers.internals`: the private names of one package that the unit tests of another
  need (a piece they compare against, drive or patch), each with why.
- :mod:`tests.helpers.ukf_reference`: a dense unscented Kalman filter in NumPy, the reference of
  the square-root filter's tests.

A test module imports no private module (``nanoslam_jax.<package>._name``) of a package other
than the one it tests, and an end-to-end test (``tests/e2e``) none at all, except through a
helper here that says why (``tests/unit/test_test_layout.py`` checks it).
"""

__all__: list[str] = []
