"""The seed lists of the experiment scripts' ``--seeds`` options."""

from __future__ import annotations

import argparse


def parse_seeds(text: str) -> list[int]:
    """Seeds from ``"100-115"``, ``"1,2,5"`` or ``"0-3,200-203"`` (inclusive ranges), in that order.

    Raises:
        argparse.ArgumentTypeError: naming the item that is not a seed or a range of seeds.
    """
    out: list[int] = []
    for part in text.split(","):
        lo, sep, hi = part.strip().partition("-")
        try:
            a, b = int(lo), int(hi) if sep else int(lo)
        except ValueError:
            raise argparse.ArgumentTypeError(f"--seeds {text!r}: expected seeds like 100-115 or 1,2,5, got {part!r}")
        if a < 0 or b < a:
            raise argparse.ArgumentTypeError(f"--seeds {text!r}: {part!r} is not a range of seeds from low to high")
        out.extend(range(a, b + 1))
    return out


def format_seeds(seeds: list[int]) -> str:
    """The text :func:`parse_seeds` reads back: consecutive seeds as ``a-b``, the rest by commas."""
    parts: list[str] = []
    i = 0
    while i < len(seeds):
        j = i
        while j + 1 < len(seeds) and seeds[j + 1] == seeds[j] + 1:
            j += 1
        parts.append(f"{seeds[i]}-{seeds[j]}" if j > i else f"{seeds[i]}")
        i = j + 1
    return ",".join(parts)
