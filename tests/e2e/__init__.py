"""End-to-end tests: the ``nanoslam`` commands and the shipped configs and documentation, run whole."""
