"""Unit tests of ``nanoslam_jax.models``."""
