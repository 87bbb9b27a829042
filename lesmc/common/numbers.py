"""Numbers as every table and report shows them (docs/cli.md, "Numbers")."""

from __future__ import annotations

import math

#: The largest payoff a price may have: a scene's detection or candidate (lesmc/scene/io.py,
#: docs/scene-format.md "Limits"), an imported column or constant, an ``inject grid``'s
#: ``payoff P`` (lesmc/language/actions.py). Sums of such prices stay finite.
MAX_PAYOFF = 1e12


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
