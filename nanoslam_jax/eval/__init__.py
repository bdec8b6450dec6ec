"""Evaluation on the host: metrics against GPS, truth or a survey (:mod:`.metrics`), the feature
errors of line and arc maps, the figures of a run (:mod:`.plotting`) and the GPS floor
(:mod:`.gps_floor`)."""

__all__: list[str] = []
