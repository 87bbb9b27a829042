"""``lesmc export MODEL|SCENE --format FORMAT -o OUT``: models out.

The formats, their choices, what each takes and the help's table come from the
registry, lesmc/exporters/formats.py.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import click

from lesmc.cli.documents import emit, file_facts, run_provenance, say
from lesmc.cli.options import (
    RegistryChoice,
    distinct_files,
    parse_window,
    scene_target,
    tracker_option,
)
from lesmc.common.errors import InputError, Location, UsageError, escape_control, source_line
from lesmc.designs import registry
from lesmc.exporters import formats
from lesmc.exporters.request import chosen_property
from lesmc.language.actions import DEFAULT as DEFAULT_ACTIONS

if TYPE_CHECKING:
    import numpy as np

    from lesmc.language.properties import SpecFile
    from lesmc.model.arrays import ArrayModel
    from lesmc.model.multi import MultiModel
    from lesmc.scene import Scene


def _mdp() -> tuple[str, ...]:
    """The formats that state a property of --spec."""
    return formats.where(lambda f: f.states_property)


def _marking() -> tuple[str, ...]:
    """The formats that mark a results file's paths."""
    return formats.where(lambda f: f.marks_paths)


def _limits() -> str:
    """What --max-nodes bounds, per format."""
    return "; ".join(
        f"{f.name}: the most {f.limit[0]} [default: {f.limit[1]}]"
        for f in map(formats.get, formats.names())
        if f.limit
    )


_HELP = f"""Write MODEL (a .lts or .npz, or a SCENE) for other tools.

A SCENE is first built as lesmc build builds it, for the attack window of --window
or, with --spec, of the property exported. A multi-target model or scene (design
sort, gnn; lesmc build --design sort -o MODEL.npz) is exported in the formats that
take one: {formats.spelled(formats.where(lambda f: f.multi_writer is not None))}.

\b
{formats.help_table()}

{formats.spelled(_mdp(), "and")} write the MDP of one property of --spec (--property NAME when
it holds several): the reward `payoff` is the property's objective and the label
`violated` marks the end of every path that satisfies its constraint, so that the
minimum expected reward until `violated` is lesmc's optimum. An objective that is no
sum of rewards (dist.max) is written without the reward model, with a note saying
so (exit 0; the MDP then answers whether a path violates); --strict refuses it
(exit 2). docs/export.md.

Exit status: 0 written, 2 bad input, 4 internal error, 130 interrupted.
"""


@click.command("export", help=_HELP)
@click.argument("model", metavar="MODEL|SCENE", type=click.Path(dir_okay=False))
@click.option(
    "--format",
    "fmt",
    type=RegistryChoice(formats.names),
    required=True,
    help="The file format.",
)
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="The file.")
@click.option(
    "--window",
    "window_text",
    default=None,
    metavar="L..U",
    help="For a scene: the attack window of the model built from it (as lesmc build) "
    "[default, with --spec: the property's window; a different one is refused].",
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
    help=f"{formats.spelled(_mdp())}: the property file whose property is exported as a "
    "reward and a label.",
)
@click.option(
    "--property",
    "prop",
    default=None,
    metavar="NAME",
    help=f"{formats.spelled(_mdp())}: which property; {formats.spelled(_marking())}: whose "
    "paths --results marks.",
)
@click.option(
    "--results",
    "results_path",
    type=click.Path(dir_okay=False),
    default=None,
    help=f"{formats.spelled(_marking())}: mark the counterexample and witness of this results "
    "file (lesmc check --json, or results.json) [with --property: that property's].",
)
@click.option(
    "--max-nodes",
    type=click.IntRange(min=1),
    default=None,
    help=f"{_limits()}.",
)
@click.option(
    "--strict",
    is_flag=True,
    help=f"{formats.spelled(_mdp())}: refuse a property whose objective is not a sum of "
    "rewards (dist.max) instead of writing the MDP without its reward model.",
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
    from lesmc.api import export_model, load_spec
    from lesmc.model.multi import MultiModel

    _refuse_mismatched(formats.get(fmt), spec_path, strict, prop, results_path, max_nodes)
    inputs = {"MODEL": model, "--spec": spec_path, "--results": results_path}
    distinct_files(inputs | {"--tracker": tracker_file}, {"-o/--output": output})
    spec = load_spec(spec_path) if spec_path else None
    cm = _model(model, target_text, design, window_text, tracker_file, spec, prop, fmt)
    roles = None
    if results_path:  # the formats that mark paths take no multi-target model (refused)
        assert not isinstance(cm, MultiModel)
        roles = _roles(cm, results_path, prop)
    facts = export_model(cm, output, fmt, spec, prop, strict, roles, max_nodes)
    if facts.get("not_exported"):
        click.echo(f"note: {facts['not_exported']}", err=True)
    say(f"wrote {escape_control(output)} ({fmt}, {_states(facts, fmt, cm)})", as_json)
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


def _states(facts: dict[str, object], fmt: str, cm: ArrayModel | MultiModel) -> str:
    """The states the file holds: a property's MDP has its own (its header's number)."""
    mdp = facts.get(fmt)
    if isinstance(mdp, dict) and "states" in mdp:
        name = facts.get("property")
        return f"{mdp['states']} states: the MDP of property '{name}' on {cm.n_states} model states"
    return f"{cm.n_states} states"


def _refuse_mismatched(
    fmt: formats.ExportFormat,
    spec_path: str | None,
    strict: bool,
    prop: str | None,
    results_path: str | None,
    max_nodes: int | None,
) -> None:
    """Options that the format would ignore are errors (the one rule:
    :func:`lesmc.exporters.formats.refused`)."""
    given = {
        "spec": spec_path is not None,
        "property": prop is not None,
        "strict": strict,
        "paths": results_path is not None,
        "max_nodes": max_nodes is not None,
    }
    spelling = {
        "spec": "--spec",
        "property": "--property",
        "strict": "--strict",
        "paths": "--results",
        "max_nodes": "--max-nodes",
        "format": "--format",
    }
    why = formats.refused(fmt, given, spelling)
    if why is not None:
        raise UsageError(why[1])


def _model(
    model: str,
    target_text: str | None,
    design: str | None,
    window_text: str | None,
    tracker_file: str | None,
    spec: SpecFile | None,
    prop: str | None,
    fmt: str,
) -> ArrayModel | MultiModel:
    """The .lts model, or the scene built for its window (``--window``, or the exported
    property's) as lesmc build builds it; a multi-target model or scene (design sort,
    gnn) for a format that takes one (``--spec``'s property: its window)."""
    from lesmc.api import load_model_or_scene
    from lesmc.model.multi import MultiModel
    from lesmc.scene import Scene, UnpricedPayoff
    from lesmc.unfold.unfold import build_model

    source = load_model_or_scene(model, target_text, design, tracker_file)
    multi = isinstance(source, MultiModel)
    if isinstance(source, Scene) and registry.get(source.tracker.design).multi:
        multi = True
    if multi:
        formats.refuse_multi(formats.get(fmt))
    if isinstance(source, Scene) and multi:
        return _multi_scene(source, model, window_text, spec, prop)
    if isinstance(source, Scene):
        window, actions, grid = _scene_window(source, window_text, spec, prop)
        try:
            return build_model(
                source, window, inject="inject" in actions, hide="hide" in actions, grid=grid
            )
        except UnpricedPayoff as exc:  # a verify scene's payoff that nobody priced
            raise exc.at(model) from None
    if window_text is not None:
        raise UsageError("--window builds a scene; a .lts model has its window already")
    return source


def _multi_scene(
    scene: Scene, path: str, window_text: str | None, spec: SpecFile | None, prop: str | None
) -> MultiModel:
    """A multi-target scene's model for the exported property (as ``lesmc build --spec``
    builds it); a ``--window`` must be the property's."""
    from lesmc.pipeline.multi import build_for, property_key

    assert spec is not None  # the formats that take a multi-target model state a property
    key = property_key(scene, spec, prop)
    window = parse_window(window_text) if window_text is not None else None
    if window is not None and window != key[:2]:
        raise UsageError(
            f"--window {window[0]}..{window[1]} contradicts the property's attack window "
            f"{key[0]}..{key[1]}: leave --window out (the property's is used)"
        )
    return build_for(scene, path, key)


def _scene_window(
    scene: Scene, window_text: str | None, spec: SpecFile | None, prop: str | None
) -> tuple[tuple[int, int], tuple[str, ...], tuple[np.ndarray, float] | None]:
    """The attack window a scene is built for: ``--window``, else the exported property's;
    both given, they must agree (refused at the property's window clause). And the
    attacker's actions: the property's (``allow``), hide only without one, and its
    ``inject grid`` (the points the tracker takes)."""
    window = parse_window(window_text) if window_text is not None else None
    if spec is None:
        if window is None:
            raise UsageError("a scene is built for one attack window: give --window L..U")
        return window, DEFAULT_ACTIONS, None
    from lesmc.pipeline.check import bind_scene, grid_points

    bp = chosen_property(bind_scene(scene, [spec]), spec.path, prop)
    own = (bp.l, bp.u)
    if window is not None and window != own:
        pos = bp.prop.clause_pos.get("window", bp.prop.pos)
        raise UsageError(
            f"--window {window[0]}..{window[1]} contradicts the attack window {own[0]}..{own[1]} "
            f"of property '{bp.name}': leave --window out (the property's is used) or give "
            f"{own[0]}..{own[1]}",
            Location(spec.path, pos.line, pos.column, source_line(spec.text, pos.line)),
        )
    return own, bp.prop.actions, grid_points(bp.prop.grid)


def _roles(cm: ArrayModel, path: str, prop: str | None) -> dict[str, list[int]]:
    """The counterexample and witness paths of a results file, as model rows; a bad one
    is refused at its ``FILE:LINE:COL``."""
    from lesmc.common.files import parse_json, read_text
    from lesmc.common.locations import json_location

    text = read_text(path)
    doc = parse_json(text, path)
    chosen = [
        (at, r)
        for at, r in _results(doc, path)
        if isinstance(r, dict) and (prop is None or r.get("property") == prop)
    ]
    if not chosen:
        what = "no result" if prop is None else f"no result for property '{prop}'"
        raise InputError(what, Location(path))
    at, first = chosen[0]
    roles: dict[str, list[int]] = {"original": cm.original.tolist()}
    for role in ("witness", "counterexample"):
        got = first.get(role)
        states = got.get("states") if isinstance(got, dict) else None
        item = f"{at}.{role}.states"
        if states is not None and not (
            isinstance(states, list) and all(isinstance(s, str) for s in states)
        ):
            raise InputError(
                f"{item}: must be a list of state ids", json_location(path, text, item)
            )
        if states:
            try:
                roles[role] = [cm.index(s) for s in states]
            except KeyError as exc:
                raise InputError(
                    f"{item}: {role} state {exc} is not in this model (results of another model?)",
                    json_location(path, text, item),
                ) from None
    return roles


def _results(doc: Any, path: str) -> list[tuple[str, Any]]:
    """Each result of ``lesmc check --json`` (``results``) or of a results file (``runs``),
    with its JSON path."""
    if isinstance(doc, dict) and isinstance(doc.get("results"), list):
        return [(f"results[{i}]", r) for i, r in enumerate(doc["results"])]
    if isinstance(doc, dict) and isinstance(doc.get("runs"), list):
        return [
            (f"runs[{k}].results[{i}]", r)
            for k, run in enumerate(doc["runs"])
            if isinstance(run, dict)
            for i, r in enumerate(run.get("results", []))
        ]
    raise InputError("not a results file (lesmc check --json or results.json)", Location(path))
