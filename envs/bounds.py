"""Bounds that the book's envs check their constructor arguments against.

A typo such as ``max_steps:123456789012345678901234567`` or ``size:100000`` is then a :class:`ValueError` that
names what is accepted (the CLIs print it as one line), not an integer overflow deep in a numba kernel or a
hundreds-of-GiB allocation.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

#: The longest episode an env takes (``max_steps``, ``max_cycles``): far above any budget, well inside int64.
MAX_EPISODE_STEPS = 1_000_000_000
#: The longest grid side (GridWorld, HazardGridWorld, TreasureHunt): 65,536 cells, whose one-hot observations and
#: rendered frames (32 pixels a cell) still fit in memory.
MAX_GRID_SIDE = 256


def show(value: Any) -> str:
    """``repr(value)`` for a message, shortened for huge integers and long texts."""
    if isinstance(value, int | np.integer) and not isinstance(value, bool) and abs(int(value)) >= 10**30:
        return f"an integer of about {int(abs(int(value)).bit_length() * math.log10(2)) + 1:,} digits"
    text = repr(value)
    return text if len(text) <= 60 else f"{text[:40]}... ({len(text):,} characters)"


def check_int(value: Any, what: str, low: int, high: int) -> int:
    """``value`` as an int if it is an integer (not a bool) in ``low..high``, else :class:`ValueError`."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or not low <= value <= high:
        raise ValueError(f"{what} must be an integer in {low:,}..{high:,}, got {show(value)}")
    return int(value)


def check_number(value: Any, what: str, low: float = -math.inf, high: float = math.inf) -> float:
    """``value`` as a float if it is a finite real number (not a bool) in ``[low, high]``, else :class:`ValueError`."""
    ok = isinstance(value, int | float | np.integer | np.floating) and not isinstance(value, bool)
    if not ok or not math.isfinite(float(value)) or not low <= float(value) <= high:
        span = (f">= {low:g}" if math.isinf(high) else f"<= {high:g}" if math.isinf(low)
                else f"in [{low:g}, {high:g}]")
        span = "" if math.isinf(low) and math.isinf(high) else f" {span}"
        raise ValueError(f"{what} must be a finite number{span}, got {show(value)}")
    return float(value)
