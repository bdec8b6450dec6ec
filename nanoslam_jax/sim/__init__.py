"""Simulators with ground truth: the Victoria Park-like park (:mod:`.park`), its raw laser scans
(:mod:`.laser`) and the indoor rooms with walls, arcs and raw scans (:mod:`.indoor`)."""

__all__: list[str] = []
