"""Unit tests, one folder for each subpackage of nanoslam_jax; the fast tier is ``pytest tests/unit -m "not slow"``."""
