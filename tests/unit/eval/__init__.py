"""Unit tests of ``nanoslam_jax.eval``."""
