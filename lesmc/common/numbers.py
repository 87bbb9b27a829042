"""Numbers as every table and report shows them (docs/cli.md, "Numbers")."""

from __future__ import annotations

import math


def fmt(x: float | str | None, digits: int = 4) -> str:
    """A number for a table or a report: ``digits`` significant digits (full precision
    stays in the JSON), '-' for None, '+inf' for infinity (also the JSON's "inf")."""
    if x is None:
        return "-"
    if isinstance(x, str):
        x = float(x)  # "inf", "-inf": the JSON's infinity
    if math.isinf(x):
        return "+inf" if x > 0 else "-inf"
    return f"{x:.{digits}g}"
