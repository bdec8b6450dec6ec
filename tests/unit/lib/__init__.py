"""Unit tests of ``nanoslam_jax.lib``."""
