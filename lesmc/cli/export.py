"""``lesmc export MODEL|SCENE --format dot|graphml|json|drn|prism -o OUT``: models out."""

from __future__ import annotations

from typing import TYPE_CHECKING

import click

from lesmc.cli.documents import emit, file_facts, run_provenance, say
from lesmc.cli.options import (
    RegistryChoice,
    distinct_files,
    parse_window,
    refuse_multi,
    scene_target,
    tracker_option,
)
from lesmc.common.errors import InputError, Location, UsageError, escape_control
from lesmc.designs import registry

if TYPE_CHECKING:
    from lesmc.model.arrays import ArrayModel

FORMATS = ("dot", "graphml", "json", "drn", "prism")


@click.command("export")
@click.argument("model", metavar="MODEL|SCENE", type=click.Path(dir_okay=False))
@click.option("--format", "fmt", type=click.Choice(FORMATS), required=True, help="The file format.")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="The file.")
@click.option(
    "--window",
    "window_text",
    default=None,
    metavar="L..U",
    help="For a scene: the attack window of the model built from it (as lesmc build).",
)
@click.option(
    "--design",
    type=RegistryChoice(registry.tracker_names),
    default=None,
    help="For a scene: override the tracker design it names.",
)
@scene_target
@tracker_option
@click.option(
    "--spec",
    "spec_path",
    type=click.Path(dir_okay=False),
    default=None,
    help="drn, prism: the property file whose property is exported as a reward and a label.",
)
@click.option(
    "--property", "prop", default=None, metavar="NAME", help="drn, prism: which property."
)
@click.option(
    "--results",
    "results_path",
    type=click.Path(dir_okay=False),
    default=None,
    help="dot, graphml: mark the counterexample and witness of this results file (lesmc "
    "check --json, or results.json) [with --property: that property's].",
)
@click.option(
    "--max-nodes",
    type=click.IntRange(min=1),
    default=None,
    help="dot: refuse models with more states than this [default: 5000]; drn, prism: the "
    "most path prefixes to unfold [default: 200000].",
)
@click.option(
    "--strict",
    is_flag=True,
    help="drn, prism: refuse a property whose objective is not a sum of rewards (dist.max) "
    "instead of writing the MDP without its reward model.",
)
@click.option("--json", "as_json", is_flag=True, help="Print what was written as JSON.")
def export_cmd(
    model: str,
    fmt: str,
    output: str,
    window_text: str | None,
    design: str | None,
    target_text: str | None,
    tracker_file: str | None,
    spec_path: str | None,
    prop: str | None,
    results_path: str | None,
    max_nodes: int | None,
    strict: bool,
    as_json: bool,
) -> None:
    """Write MODEL (a .lts or .npz, or a SCENE built with --window) for other tools.

    \b
    dot      Graphviz (steps as ranks; counterexample red, witness blue)
    graphml  Gephi, yEd, networkx (streamed: any size; attribute `role`)
    json     the .lts format itself (lesmc check reads it back)
    drn      Storm's explicit format: an MDP whose reward `payoff` is the combined
             payoff (Eq. 5) of each attacker choice and whose label `violated` marks
             the end of every path that satisfies the property's constraint, so that
             Storm's Rmin=? [F "violated"] is lesmc's optimum (needs --spec; payoff
             objectives only: other properties are refused, with the reason)
    prism    the same MDP in the PRISM language (PRISM, Storm):
             R{"payoff"}min=? [F "violated"] is lesmc's optimum
    Exit status: 0 written, 2 bad input, 4 internal error, 130 interrupted.
    """
    from lesmc.api import export_model, load_spec

    _refuse_mismatched(fmt, spec_path, strict, prop, results_path)
    inputs = {"MODEL": model, "--spec": spec_path, "--results": results_path}
    distinct_files(inputs | {"--tracker": tracker_file}, {"-o/--output": output})
    cm = _model(model, target_text, design, window_text, tracker_file)
    roles = _roles(cm, results_path, prop) if results_path else None
    spec = load_spec(spec_path) if spec_path else None
    facts = export_model(cm, output, fmt, spec, prop, strict, roles, max_nodes)
    if facts.get("not_exported"):
        click.echo(f"note: {facts['not_exported']}", err=True)
    say(f"wrote {escape_control(output)} ({fmt}, {cm.n_states} states)", as_json)
    if as_json:
        emit(
            {
                "format": "lesmc-export",
                "version": 1,
                "provenance": run_provenance(),
                "model": model,
                "file": file_facts(output),
                "states": cm.n_states,
                "transitions": cm.n_transitions,
            }
            | facts
        )


def _refuse_mismatched(
    fmt: str, spec_path: str | None, strict: bool, prop: str | None, results_path: str | None
) -> None:
    """Options that the format would ignore are errors."""
    mdp = fmt in ("drn", "prism")
    if not mdp and (spec_path or strict or (prop and not results_path)):
        raise UsageError(
            "--spec, --property and --strict choose what --format drn or prism exports"
        )
    if mdp and spec_path is None:
        raise UsageError(f"--format {fmt} exports a property: give --spec (and --property)")
    if results_path is not None and fmt not in ("dot", "graphml"):
        raise UsageError("--results marks paths in dot and graphml only")


def _model(
    model: str,
    target_text: str | None,
    design: str | None,
    window_text: str | None,
    tracker_file: str | None,
) -> ArrayModel:
    """The .lts model, or the scene built for ``--window`` as lesmc build builds it."""
    from lesmc.api import load_model_or_scene
    from lesmc.build.unfold import build_model
    from lesmc.scene import Scene, UnpricedPayoff

    source = load_model_or_scene(model, target_text, design, tracker_file)
    if isinstance(source, Scene):
        refuse_multi(source, model, design)
        if window_text is None:
            raise UsageError("a scene is built for one attack window: give --window L..U")
        try:
            return build_model(source, parse_window(window_text))
        except UnpricedPayoff as exc:  # a verify scene's payoff that nobody priced
            raise exc.at(model) from None
    if window_text is not None:
        raise UsageError("--window builds a scene; a .lts model has its window already")
    return source


def _roles(cm: ArrayModel, path: str, prop: str | None) -> dict[str, list[int]]:
    """The counterexample and witness paths of a results file, as model rows."""
    from lesmc.common.files import read_json

    doc = read_json(path, InputError)
    results = []
    if isinstance(doc, dict) and isinstance(doc.get("results"), list):
        results = doc["results"]  # lesmc check --json
    elif isinstance(doc, dict) and isinstance(doc.get("runs"), list):
        results = [r for run in doc["runs"] for r in run.get("results", [])]
    else:
        raise InputError("not a results file (lesmc check --json or results.json)", Location(path))
    chosen = [
        r for r in results if isinstance(r, dict) and (prop is None or r.get("property") == prop)
    ]
    if not chosen:
        what = "no result" if prop is None else f"no result for property '{prop}'"
        raise InputError(what, Location(path))
    roles: dict[str, list[int]] = {"original": cm.original.tolist()}
    for role in ("witness", "counterexample"):
        got = chosen[0].get(role)
        states = got.get("states") if isinstance(got, dict) else None
        if states is not None and not (
            isinstance(states, list) and all(isinstance(s, str) for s in states)
        ):
            raise InputError("must be a list of state ids", Location(path, item=f"{role}.states"))
        if states:
            try:
                roles[role] = [cm.index(s) for s in states]
            except KeyError as exc:
                raise InputError(
                    f"{role} state {exc} is not in this model (results of another model?)",
                    Location(path, item=f"{role}.states"),
                ) from None
    return roles
