"""The evaluation protocol's settings."""

from __future__ import annotations

from dataclasses import dataclass

from nanoslam_jax.lib._fields import _f

__all__ = ["MetricsConfig"]


@dataclass(frozen=True)
class MetricsConfig:
    """Evaluation protocol settings (the protocol: the docs, page method/victoria-park.md)."""

    gps_rotation_deg: float = _f(-35.4, doc="rotation of the relative-GPS frame")
    jump_speed: float = _f(8.0, lo=0.0, lo_open=True, doc="GPS fixes implying a faster jump are removed in *_clean")
    map_radius: float = _f(
        1.0,
        lo=0.0,
        lo_open=True,
        doc="a confirmed landmark within this distance (m) of a true one matches it: simulated logs' true trees "
        "(map_found_fraction, map_spurious_fraction), a real log's surveyed landmarks after the alignment "
        "(survey_found, survey_spurious)",
    )
