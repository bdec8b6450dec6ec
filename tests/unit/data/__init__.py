"""Unit tests of ``nanoslam_jax.data``."""
