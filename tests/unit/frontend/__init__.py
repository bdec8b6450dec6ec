"""Unit tests of ``nanoslam_jax.frontend``."""
