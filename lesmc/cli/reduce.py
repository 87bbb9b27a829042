"""``lesmc reduce``: build models from classic problems (the NP-hardness reduction)."""

from __future__ import annotations

import math
from pathlib import Path

import click

from lesmc.cli.options import model_output
from lesmc.errors import UsageError
from lesmc.fileio import atomic_write_text


@click.group("reduce")
def reduce_group() -> None:
    """Reduce a classic problem to a <PO>²-LTS and a property."""


@reduce_group.command("knapsack")
@click.argument("items", type=click.Path(dir_okay=False))
@click.option("--demand", type=float, required=True, help="W: the capacity to exceed (Eq. 10).")
@click.option(
    "--budget",
    type=float,
    default=0.0,
    show_default=True,
    help="The property holds iff every selection meeting the demand costs more than this.",
)
@model_output
@click.option(
    "--spec",
    "spec_out",
    type=click.Path(dir_okay=False),
    default=None,
    help="The property file to write [default: OUTPUT with .spec].",
)
def knapsack_cmd(
    items: str, demand: float, budget: float, output: str, spec_out: str | None
) -> None:
    """Build the knapsack reduction of section 4.5 from ITEMS.csv (columns cost, capacity).

    The optimum of the written property is the minimum cost of a selection
    whose total capacity exceeds DEMAND (+inf if none does).
    """
    from lesmc.model.knapsack import knapsack_lts, knapsack_spec, read_items
    from lesmc.model.lts_format import save_lts

    if not (math.isfinite(demand) and math.isfinite(budget)):
        raise UsageError("--demand and --budget must be finite")
    parsed = read_items(items)
    spec_path = Path(spec_out) if spec_out else Path(output).with_suffix(".spec")
    model = knapsack_lts(parsed)
    text = knapsack_spec(len(parsed), demand, budget)
    save_lts(model, output)
    atomic_write_text(spec_path, text)
    click.echo(f"wrote {output} ({len(parsed)} items) and {spec_path}")
