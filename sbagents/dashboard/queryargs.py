"""Query values of the dashboard's JSON endpoints: integers, finite numbers and the decisions page's row filter.

A value that is not what its name needs (not a number, negative, over 2**63 - 1, NaN or infinite) answers 400 with
one sentence saying so; an absent or empty value is the default.
"""

from __future__ import annotations

import math
import re

from flask import abort, request

from sbagents.dashboard.logfilter import RowFilter

#: Largest integer a query value may be (row numbers, episodes and envs are int64 in numpy).
MAX_INT = (1 << 63) - 1
_INT = re.compile(r"\+?[0-9]{1,19}")


def int_arg(name: str, default: int) -> int:
    """Query value ``name`` as an integer 0..:data:`MAX_INT` (``default`` when absent or empty)."""
    value = optional_int(name)
    return default if value is None else value


def optional_int(name: str) -> int | None:
    """Query value ``name`` as an integer 0..:data:`MAX_INT`, None when absent or empty."""
    value = request.args.get(name, "").strip()
    if value == "":
        return None
    if not _INT.fullmatch(value) or int(value) > MAX_INT:
        abort(400, f"{name} must be an integer from 0 to {MAX_INT}, got {value[:40]!r}")
    return int(value)


def float_arg(name: str) -> float | None:
    """Query value ``name`` as a finite number, None when absent or empty."""
    value = request.args.get(name, "").strip()
    if value == "":
        return None
    try:
        number = float(value)
    except ValueError:
        number = math.nan
    if not math.isfinite(number):
        abort(400, f"{name} must be a finite number, got {value[:40]!r}")
    return number


def row_filter() -> RowFilter:
    """The decisions filter of the query (``episode``, ``env``, ``agent``, ``step_min``, ``step_max``,
    ``reward_min``, ``reward_max``, ``violations=1``); step bounds are rounded inwards to whole steps."""
    step_min, step_max = float_arg("step_min"), float_arg("step_max")
    return RowFilter(
        episode=optional_int("episode"),
        env=optional_int("env"),
        agent=request.args.get("agent") or None,
        step_min=math.ceil(step_min) if step_min is not None else None,
        step_max=math.floor(step_max) if step_max is not None else None,
        reward_min=float_arg("reward_min"),
        reward_max=float_arg("reward_max"),
        violations_only=request.args.get("violations") == "1",
    )
