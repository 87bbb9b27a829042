"""``lesmc reduce``: build models from classic problems (the NP-hardness reduction)."""

from __future__ import annotations

import math
from pathlib import Path

import click

from lesmc.cli.documents import emit, file_facts, run_provenance, say
from lesmc.cli.options import distinct_files, model_output
from lesmc.common.errors import UsageError, escape_control
from lesmc.common.files import atomic_write_text


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
@click.option(
    "--json",
    "as_json",
    is_flag=True,
    help="Print what was written as JSON on stdout (format lesmc-reduce, schema "
    "lesmc/schemas/reduce.json).",
)
def knapsack_cmd(
    items: str, demand: float, budget: float, output: str, spec_out: str | None, as_json: bool
) -> None:
    """Build the knapsack reduction of section 4.5 from ITEMS.csv (columns cost, capacity).

    The optimum of the written property is the minimum cost of a selection
    whose total capacity exceeds DEMAND (+inf if none does).
    Exit status: 0 written, 2 bad input, 4 internal error, 130 interrupted.
    """
    from lesmc.model.knapsack import knapsack_lts, knapsack_spec, read_items
    from lesmc.model.lts_format import save_lts

    if not (math.isfinite(demand) and math.isfinite(budget)):
        raise UsageError("--demand and --budget must be finite")
    spec_path = Path(spec_out) if spec_out else Path(output).with_suffix(".spec")
    distinct_files({"ITEMS": items}, {"-o/--output": output, "--spec": str(spec_path)})
    parsed = read_items(items)
    model = knapsack_lts(parsed)
    text = knapsack_spec(len(parsed), demand, budget)
    save_lts(model, output)
    atomic_write_text(spec_path, text)
    say(
        f"wrote {escape_control(output)} ({len(parsed)} items) and "
        f"{escape_control(str(spec_path))}",
        as_json,
    )
    if as_json:
        from lesmc.results.document import model_hash

        emit(
            {
                "format": "lesmc-reduce",
                "version": 1,
                "provenance": run_provenance(),
                "problem": "knapsack",
                "input": items,
                "items": len(parsed),
                "demand": demand,
                "budget": budget,
                "model": file_facts(output),
                "spec": file_facts(spec_path),
                "model_sha256": model_hash(model),
                "states": model.n_states,
                "transitions": model.n_transitions,
            }
        )
