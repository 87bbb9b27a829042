"""The 0-1 minimisation knapsack as a <PO>²-LTS (paper section 4.5, Eq. 10-12).

Item i becomes step i with two states: ``i:0`` (not taken, the original path)
and ``i:1`` (taken). Two corrections to the paper's construction, explained in
docs/semantics.md:

* transitions leave *both* states of step i−1 (the paper only lets ρ^1_{i−1}
  continue, which would leave ρ^0_{i−1} a dead end);
* the item's cost v_i sits on the default transition ``→ i:0`` (rank 0), not on
  ``→ i:1`` (rank 1): the combined payoff of Eq. 5 sums the payoffs of the
  transitions strictly before the one taken, so taking item i costs exactly v_i
  and skipping it costs 0.

The state vector is the item's capacity when taken and 0 otherwise, so
dist.sum(0..end) = Σ g_i c_i (Eq. 12).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lesmc.common.errors import InputError, Location
from lesmc.model.arrays import ArrayModel
from lesmc.model.validate import Parts, build


@dataclass(frozen=True)
class Item:
    """One knapsack item: its cost v_i and capacity g_i."""

    cost: float
    capacity: float


def read_items(path: str | Path) -> list[Item]:
    """Read a CSV with a header naming the columns ``cost`` and ``capacity``."""
    p = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read items: {exc}", Location(p)) from None
    rows = list(csv.reader(text.splitlines()))
    if not rows:
        raise InputError("empty file; expected a header 'cost,capacity'", Location(p, 1, 1))
    header = [h.strip().lower() for h in rows[0]]
    for col in ("cost", "capacity"):
        if col not in header:
            raise InputError(
                f"the header lacks a '{col}' column", Location(p, 1, 1, text.splitlines()[0])
            )
    ci, gi = header.index("cost"), header.index("capacity")
    items = []
    for n, row in enumerate(rows[1:], start=2):
        if not any(cell.strip() for cell in row):
            continue
        src = text.splitlines()[n - 1]
        if len(row) != len(header):
            raise InputError(
                f"{len(row)} fields, the header has {len(header)}", Location(p, n, 1, src)
            )
        values = []
        for idx in (ci, gi):
            cell = row[idx].strip()
            column = src.find(row[idx]) + 1 if row[idx] else 1
            try:
                v = float(cell)
            except ValueError:
                raise InputError(f"'{cell}' is not a number", Location(p, n, column, src)) from None
            if not math.isfinite(v) or v < 0:
                raise InputError(
                    f"{header[idx]} must be finite and >= 0, got {cell}",
                    Location(p, n, column, src),
                )
            values.append(v)
        items.append(Item(values[0], values[1]))
    if not items:
        raise InputError("no items", Location(p, 1, 1))
    return items


def knapsack_lts(items: list[Item]) -> ArrayModel:
    """The reduction: a layered DAG of 2 states per item, 4 transitions per layer."""
    n = len(items)
    ids = ["0:1"]
    cap = [0.0]
    src: list[str] = []
    dst: list[str] = []
    payoff: list[float] = []
    obs: list[str | None] = []
    prev = ["0:1"]
    for i, item in enumerate(items, start=1):
        off, on = f"{i}:0", f"{i}:1"
        ids += [off, on]
        cap += [0.0, item.capacity]
        for p in prev:
            src += [p, p]
            dst += [off, on]
            payoff += [item.cost, 0.0]
            obs += [f"skip{i}", f"take{i}"]
        prev = [off, on]
    m = len(src)
    parts = Parts(
        ids=ids,
        step=np.array([0, *(k for k in range(1, n + 1) for _ in range(2))], dtype=np.int64),
        s_len=np.ones(len(ids), dtype=np.int64),
        s_flat=np.array(cap, dtype=np.float64),
        P_shape=np.full((len(ids), 2), -1, dtype=np.int64),
        P_flat=np.zeros(0),
        halted=np.zeros(len(ids), dtype=bool),
        labels={},
        src=src,
        dst=dst,
        payoff=np.array(payoff, dtype=np.float64).reshape(m),
        rank=np.tile(np.array([0, 1], dtype=np.int64), m // 2),
        obs=obs,
        initial="0:1",
        original=["0:1"] + [f"{i}:0" for i in range(1, n + 1)],
        components=["capacity"],
    )
    return build(parts, "<knapsack>")


def knapsack_spec(n: int, demand: float, budget: float, name: str = "knapsack") -> str:
    """The matching property (Eq. 11): holds iff meeting the demand costs more than ``budget``."""
    return (
        f"# 0-1 minimisation knapsack with {n} items (paper Eq. 10-12): the cheapest\n"
        f"# selection whose total capacity exceeds the demand {demand:g}.\n"
        f"property {name} {{\n"
        f"    attack window 1..end\n"
        f"    minimize payoff\n"
        f"    subject to dist.sum(0..end) > {demand!r}\n"
        f"    holds if optimum > {budget!r}\n"
        f"}}\n"
    )
