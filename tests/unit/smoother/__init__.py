"""Unit tests of ``nanoslam_jax.smoother``."""
