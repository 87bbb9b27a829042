"""``lesmc check MODEL SPEC...``: verdicts, optimum, counterexample and witness."""

from __future__ import annotations

import sys
import time
from collections.abc import Iterable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import click

from lesmc.cli.documents import given, print_warnings, unattacked_warnings
from lesmc.cli.options import (
    DEFAULT_MAX_STATES,
    RegistryChoice,
    arm_budget,
    budget_from,
    budget_options,
    faults_option,
    frames_option,
    payoffs_option,
    scene_target,
    tracker_option,
)
from lesmc.cli.signals import polite_stop
from lesmc.common.errors import UsageError
from lesmc.designs import registry
from lesmc.engines import registry as engines

if TYPE_CHECKING:
    from lesmc.common.budget import Budget
    from lesmc.language.properties import FaultSet, SpecFile
    from lesmc.results.record import Results


@click.command("check")
@click.argument("model", metavar="MODEL|SCENE", type=click.Path(dir_okay=False))
@click.argument("specs", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option(
    "--engine",
    type=click.Choice(engines.names()),
    default=engines.DEFAULT,
    show_default=True,
    help=engines.help_text(),
)
@click.option("--json", "as_json", is_flag=True, help="Print the results as JSON on stdout.")
@budget_options(
    DEFAULT_MAX_STATES,
    "the remaining properties are 'unknown' with the bounds found so far",
)
@click.option(
    "--property",
    "only",
    multiple=True,
    metavar="NAME",
    help="Check only the named properties (repeatable).",
)
@click.option(
    "--sweep",
    "sweep_texts",
    multiple=True,
    metavar="PARAM=VALUES",
    help="Check every property for each value of a parameter, on one model: eps=LO..HI:STEP "
    "or eps=V1,V2 (the constraint's bound), p=1,2,inf (the norm), payoffs=deepfool,certified "
    "(the payoff source, scenes only: the attack's payoffs, named attack or by the "
    "algorithm that made them, certified lower bounds, or interval); repeatable (every "
    "combination). Variants are named NAME@eps=V.",
)
@faults_option(" Scenes only; neuron faults need lesmc verify on the video.")
@click.option("--no-paths", is_flag=True, help="Table output: omit the step-by-step paths.")
@click.option(
    "--report",
    "report_dir",
    type=click.Path(file_okay=False),
    default=None,
    help="Also write DIR/results.json, DIR/report.html and DIR/figures/ (a scene is then "
    "checked once, on its built model).",
)
@frames_option(
    "With --report: the video's frames, for the report's images (read from nowhere else)."
)
@payoffs_option("For a scene (a model's payoffs are built in): ")
@click.option(
    "--design",
    type=RegistryChoice(registry.names),
    default=None,
    help="For a scene: check it with this design (lesmc/designs/registry.py) instead of "
    "the tracker it names; a monitored design filters every property by the runtime "
    "monitor (Eq. 12-13); a multi-target design (sort, gnn) checks switches, lost and "
    "dist properties (docs/trackers.md); single and the multi-target designs also take "
    "an attacker who injects (attack window L..U allow hide, inject; docs/language.md).",
)
@tracker_option
@scene_target
def check_cmd(
    model: str,
    specs: tuple[str, ...],
    engine: str,
    as_json: bool,
    max_states: int,
    timeout: float | None,
    only: tuple[str, ...],
    sweep_texts: tuple[str, ...],
    faults_file: str | None,
    no_paths: bool,
    report_dir: str | None,
    frames_dir: str | None,
    payoffs: str,
    design: str | None,
    tracker_file: str | None,
    max_memory: int | None,
    target_text: str | None,
) -> None:
    """Check the properties in SPEC files on MODEL (.lts, or .npz) or on a SCENE (.json).

    A scene's model is unfolded on the fly, once per tracker and payoff set (levels and
    bnb unfold only the states they visit, enumerate every state its paths
    reach); a budget stops every engine with 'unknown' and the bounds found.

    For each property: the verdict (holds iff optimum > threshold), the optimum,
    the counterexample (cheapest path that breaks the system) and the witness
    (the paper's representative path ρ* and value θ*).
    Exit status: 0 all hold, 1 some violated, 2 bad input, 3 some unknown,
    4 internal error, 130 interrupted.
    """
    budget = budget_from(timeout, max_states, max_memory, armed=False)  # armed once valid
    _refuse_mismatched(frames_dir, report_dir, no_paths, as_json, payoffs)
    from lesmc.api import check_job  # imported when the verb runs: --help stays light
    from lesmc.common.progress import Reporter
    from lesmc.pipeline.job import Job

    parsed, source, is_scene = _inputs(model, specs, target_text, design, tracker_file)
    report = _report_to(report_dir, frames_dir, model, source if is_scene else None)
    _check_multi(source, parsed, is_scene, budget, report)  # multi-target: checked there (exits)
    parsed, only = _swept(parsed, sweep_texts, only, source.meta if is_scene else None)
    job = Job(
        parsed,
        scene=source if is_scene else None,
        model=None if is_scene else source,
        payoffs=payoffs,
        engine=engine,
        budget=budget,
        only=only,
        designs=(design,) if design else (),
        full_models=report_dir is not None,
        faults=_faults(faults_file, parsed, is_scene),
        source=model,
    )
    arm_budget(budget)
    warnings = unattacked_warnings(source, design) if is_scene else []
    with Reporter("check") as rep, polite_stop():
        results = check_job(replace(job, on_stage=rep.stage))
    _report(report, results, parsed, budget.started, warnings)  # --report DIR: nothing without
    _finish(results, parsed, as_json, no_paths, warnings)


def _finish(
    results: Results,
    parsed: tuple[SpecFile, ...],
    as_json: bool,
    no_paths: bool,
    warnings: list[str],
) -> None:
    """The results on stdout, then the exit status (130/143 after a polite SIGINT/SIGTERM:
    the partial results are out)."""
    from lesmc.cli.signals import exit_if_stopped
    from lesmc.results.exit import exit_status

    _print(results, parsed, as_json, no_paths, warnings)
    exit_if_stopped()
    sys.exit(exit_status(results.results))


def _swept(
    parsed: tuple[SpecFile, ...],
    sweep_texts: tuple[str, ...],
    only: tuple[str, ...],
    scene_meta: dict[str, Any] | None,
) -> tuple[tuple[SpecFile, ...], tuple[str, ...]]:
    """``--sweep``: the specs with ``--property`` applied, then each property's sweep
    variants (and nothing left for the pipeline to select); unchanged without a sweep.
    ``scene_meta``: the scene's (None: a model file), which names the attack that made
    its payoffs."""
    if not sweep_texts:
        return parsed, only
    from dataclasses import replace as with_

    from lesmc.language.sweep import distinct_variants, parse_sweep, swept
    from lesmc.pipeline.check import known_names

    sweeps = tuple(parse_sweep(t) for t in sweep_texts)
    for sw, text in zip(sweeps, sweep_texts, strict=True):
        distinct_variants(sw, text)
    for sw in sweeps:
        if sw.parameter == "payoffs":
            _check_sources(sw.values, scene_meta)
    if only:
        known_names(only, {p.name for s in parsed for p in s.properties})
        parsed = tuple(
            with_(s, properties=tuple(p for p in s.properties if p.name in only)) for s in parsed
        )
    return tuple(swept(s, sweeps) for s in parsed), ()


def _check_sources(sources: tuple[float | str, ...], scene_meta: dict[str, Any] | None) -> None:
    """A payoff-source sweep names sources the input has: a model file has its attack's
    payoffs only, and ``deepfool``/``pgd`` must be the algorithm that made the scene's."""
    from lesmc.language.sweep import payoff_mode

    if scene_meta is None:
        if any(payoff_mode(str(s)) != "attack" for s in sources):
            raise UsageError(
                "--sweep payoffs: a model file has its attack's payoffs only; certified "
                "payoffs need a scene"
            )
        return
    attack = scene_meta.get("attack")
    method = attack.get("method") if isinstance(attack, dict) else None
    for s in sources:
        if s in ("deepfool", "pgd") and s != method:
            made = f"by {method}" if method else "by an attack the scene does not name"
            raise UsageError(
                f"--sweep payoffs={s}: the scene's attack payoffs were made {made} "
                f"(meta.attack.method); `lesmc perceive --attack {s}` makes a scene of {s} "
                "payoffs, or sweep payoffs=attack"
            )


def _faults(path: str | None, parsed: tuple[SpecFile, ...], is_scene: bool) -> FaultSet | None:
    """The faults block of ``--faults FILE``, or of a spec file (at most one in all)."""
    from lesmc.language.parser import load_faults

    blocks = [(s.path, s.faults) for s in parsed if s.faults is not None]
    if path is not None:
        blocks.insert(0, (path, load_faults(path)))
    if len(blocks) > 1:
        raise UsageError(
            f"faults are declared in {blocks[0][0]} and in {blocks[1][0]}: give one faults block"
        )
    if blocks and not is_scene:
        raise UsageError("faults change the tracker: they need a scene, not a model file")
    return blocks[0][1] if blocks else None


def _print(
    results: Results,
    parsed: tuple[SpecFile, ...],
    as_json: bool,
    no_paths: bool,
    warnings: list[str],
) -> None:
    """The results on stdout: the versioned JSON document, or the tables and paths followed
    by the warnings."""
    from lesmc.report.text import make_console, print_results, results_json

    if as_json:
        click.echo(results_json(results.results, parsed, warnings))
    else:
        print_results(make_console(), results.results, paths=not no_paths)
        print_warnings(warnings)


@dataclass(frozen=True)
class _ReportTo:
    """``--report DIR``: where the results file and the report go, the frames for its
    images (``--frames``), the model or scene file checked and, for a scene, the results'
    ``perception`` (None: a model file, which has none)."""

    dir: str
    frames_dir: str | None
    path: str
    perception: dict[str, Any] | None


def _report_to(
    report_dir: str | None, frames_dir: str | None, path: str, scene: Any
) -> _ReportTo | None:
    """What ``--report`` writes (None: not asked). A scene's ``perception`` is the front
    end's and the attack's settings its meta records, which ``lesmc replay`` reruns the
    detector with (lesmc.perception.attack_settings ``scene_perception``, as ``lesmc
    verify`` records them); read before the check, so that a bad ``meta.frontend`` is an
    error (at its field in ``path``) before the check's time is spent."""
    if report_dir is None:
        return None
    perception = None
    if scene is not None:
        from lesmc.perception.attack_settings import scene_perception

        perception = scene_perception(dict(scene.meta), path)
    return _ReportTo(report_dir, frames_dir, path, perception)


def _report(
    to: _ReportTo | None,
    results: Results,
    parsed: tuple[SpecFile, ...],
    started: float,
    warnings: list[str],
) -> None:
    """With ``--report`` (``to``), write the results file and draw the report from it
    (lesmc/report/publish.py); the warnings are a line of its meta table. Nothing
    without it."""
    if to is None:
        return
    from lesmc.report.publish import frames_reader, publish
    from lesmc.results.document import provenance

    meta = {"model" if to.perception is None else "scene": to.path}
    if warnings:
        meta["warning"] = " ".join(f"{w}." for w in warnings)
    timings = {"load, build and check": time.monotonic() - started}
    extra = None if to.perception is None else {"perception": to.perception}
    out, _ = publish(
        results.runs,
        to.dir,
        meta,
        provenance(parsed),
        frames_reader(to.frames_dir),
        timings,
        extra=extra,
    )
    click.echo(f"report: {out}", err=True)


def _inputs(
    model: str,
    specs: tuple[str, ...],
    target_text: str | None,
    design: str | None,
    tracker_file: str | None,
) -> tuple[tuple[SpecFile, ...], Any, bool]:
    """The property files, the model or scene, and whether it is a scene."""
    from lesmc.api import load_model_or_scene, load_spec
    from lesmc.scene import Scene, load_tracker

    _hint_swapped(model, specs)
    parsed = tuple(load_spec(s) for s in specs)
    # --design's needs of the file's keys (gnn: M <= N) are the tracker file's errors
    named = design if design in registry.tracker_names() else None
    cfg = None if tracker_file is None else load_tracker(tracker_file, named)
    source = load_model_or_scene(model, target_text, tracker=cfg)
    is_scene = isinstance(source, Scene)
    if design is not None and not is_scene:
        raise UsageError("--design applies to scenes, not to built models (.lts, .npz)")
    return parsed, source, is_scene


#: ``check``'s options of the command line alone that the multi-target search does not read
#: (lesmc/cli/multi_check.py); those the API has too are lesmc/pipeline/multi.py's
#: ``DESIGN_IGNORES`` and ``MODEL_IGNORES``.
_MULTI_CLI_IGNORED = ("no_paths", "max_memory")


def _given_flags(names: Iterable[str]) -> list[str]:
    """The options among ``names`` (Python names) given on the command line, as spelled there."""
    return [f"--{n.replace('_', '-')}" for n in names if given(n)]


def _check_multi(
    source: Any,
    parsed: tuple[SpecFile, ...],
    is_scene: bool,
    budget: Budget,
    report: _ReportTo | None,
) -> None:
    """A scene of a multi-target design (``--design`` or the scene's): checked by
    lesmc/cli/multi_check.py with the command's options within ``budget`` (its alarm set
    once the options are known to be valid), which exits (``--report DIR``, ``report``:
    lesmc/report/multi.py draws its results, which record the scene's perception read
    there); sweeps and faults are not supported for it yet. Nothing happens otherwise."""
    from lesmc.model.multi_format import is_multi
    from lesmc.pipeline.multi import DESIGN_IGNORES, preload

    p = click.get_current_context().params
    design = p["design"]
    if is_multi(source):
        _check_multi_model(source, parsed, p, budget)
    if not is_scene or not registry.get(design or source.tracker.design).multi:
        return
    if p["sweep_texts"] or p["faults_file"] or any(s.faults for s in parsed):
        raise UsageError(
            "--sweep and faults with a multi-target design: not supported yet (issue 58)"
        )
    if p["payoffs"] == "interval":
        raise UsageError("--payoffs interval with a multi-target design: not supported yet")
    ignored = _given_flags((*DESIGN_IGNORES, *_MULTI_CLI_IGNORED))
    if ignored:  # options that would be ignored are errors
        raise UsageError(
            f"{', '.join(ignored)} with a multi-target design: not supported yet (its exact "
            "search has one engine, bounded by --max-states and --timeout)"
        )
    from lesmc.cli.multi_check import MultiReport, check_multi_scene

    sc = source if design is None else source.with_tracker(design=design)
    path = p["model"]
    sc = sc.priced(p["payoffs"], path)
    to = None
    if report is not None and report.perception is not None:  # a scene's: always
        to = MultiReport(report.dir, report.frames_dir, report.perception)
    preload()
    arm_budget(budget)
    check_multi_scene(sc, path, parsed, p["only"], p["as_json"], p["max_states"], to, budget)


def _check_multi_model(
    model: Any, parsed: tuple[SpecFile, ...], p: dict[str, Any], budget: Budget
) -> None:
    """A built multi-target model (lesmc build --design sort|gnn): checked by
    lesmc/cli/multi_check.py, which exits; the options its check does not read are
    refused."""
    from lesmc.pipeline.multi import MODEL_IGNORES

    if p["sweep_texts"] or p["faults_file"] or p["report_dir"] or any(s.faults for s in parsed):
        raise UsageError(
            "--sweep, --report and faults with a multi-target model: not supported yet (issue 58)"
        )
    ignored = _given_flags((*MODEL_IGNORES, *_MULTI_CLI_IGNORED))
    if ignored:
        raise UsageError(
            f"{', '.join(ignored)} with a multi-target model: not supported yet (its exact "
            "search has one engine, on the model as built, with the payoffs it was built with)"
        )
    from lesmc.cli.multi_check import check_multi_file
    from lesmc.pipeline.multi import preload

    preload()
    arm_budget(budget)
    check_multi_file(model, parsed, p["only"], p["as_json"], budget)


def _refuse_mismatched(
    frames_dir: str | None, report_dir: str | None, no_paths: bool, as_json: bool, payoffs: str
) -> None:
    """Options that would be ignored, or that contradict each other, are errors."""
    if frames_dir is not None and report_dir is None:
        raise UsageError("--frames gives the report's images: it needs --report DIR")
    if no_paths and as_json:
        raise UsageError("--no-paths shortens the table: --json always carries the paths")
    if payoffs != "attack" and report_dir is not None:
        raise UsageError("--report draws the attack payoffs' model: use --payoffs attack")


def _hint_swapped(model: str, specs: tuple[str, ...]) -> None:
    """``lesmc check SPEC MODEL``: say so before either file is read."""
    if model.endswith(".spec") and any(s.endswith((".lts", ".npz", ".json")) for s in specs):
        raise UsageError(
            f"MODEL '{model}' looks like a spec and a SPEC like a model: the order is "
            "lesmc check MODEL|SCENE SPEC..."
        )
