"""float64 in the library (``nanoslam_jax.lib._precision``): the entry points compute in float64
and the builders refuse float32 (moved from tests/unit/test_architecture.py)."""

import pytest


def test_entry_points_compute_in_float64_and_builders_refuse_float32():
    import jax
    import jax.numpy as jnp

    from nanoslam_jax import float64
    from nanoslam_jax.lib._precision import in_float64, require_float64

    with jax.enable_x64(False):
        assert jnp.zeros(1).dtype == jnp.float32
        with pytest.raises(RuntimeError, match=r"build computes in float64.*nanoslam_jax.float64"):
            require_float64("build")
        with float64():
            assert jnp.zeros(1).dtype == jnp.float64
            require_float64("build")
        assert in_float64(lambda: jnp.zeros(1).dtype)() == jnp.float64
        assert jnp.zeros(1).dtype == jnp.float32
