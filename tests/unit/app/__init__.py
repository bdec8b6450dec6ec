"""Unit tests of ``nanoslam_jax.app``."""
