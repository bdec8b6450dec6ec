"""Unit tests of ``nanoslam_jax.sim``."""
