"""The field of a config section: its default, valid range, staticness and meaning (metadata read by
:mod:`nanoslam_jax.app.config` and :mod:`nanoslam_jax.app.config_reference`)."""

from __future__ import annotations

from dataclasses import field
from typing import Any


def _f(
    default: Any,
    *,
    lo: float | None = None,
    hi: float | None = None,
    lo_open: bool = False,
    static: bool = False,
    doc: str = "",
) -> Any:
    """A dataclass field with range and staticness metadata."""
    return field(default=default, metadata=dict(lo=lo, hi=hi, lo_open=lo_open, static=static, doc=doc))
