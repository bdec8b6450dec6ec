"""Unit tests of ``nanoslam_jax.methods``."""
