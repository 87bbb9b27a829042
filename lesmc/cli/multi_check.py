"""``lesmc check SCENE SPEC --design sort`` (or ``gnn``): the exact cheapest identity attack on a
multi-target design (docs/trackers.md, "Checking a multi-target design").

The check itself is lesmc/pipeline/multi.py's (the Python API returns the same results:
``lesmc.check(..., designs="sort")``); this module prints them. Objectives: ``payoff``, ``count``,
``count.frames`` or a ``dist`` measure; constraints: ``switches(a..b)``, ``lost(a..b)`` or
a ``dist`` measure (the track of the target's id against its reference, on the box's
x, y, w, h); anything else is an error (exit status 2), as are the options a
multi-target check does not take yet. ``--timeout`` bounds each property's check (the
model's unfolding included): past it the property is ``unknown`` (exit status 3) with
the bounds and the best attack found. ``--report DIR`` writes the results file and
its report (lesmc/report/multi.py); the results record what ``lesmc replay`` reruns, as
``lesmc verify --design sort|gnn`` records it: the scene's ``perception`` (the front end's
and the attack's settings, lesmc.perception.attack_settings ``scene_perception``) and the
``meta`` that places the check's target on the scene file and names its property files
(lesmc/experiment/multi_verify.py ``replay_meta``).
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from lesmc.language.properties import SpecFile
from lesmc.model.multi import MultiModel
from lesmc.pipeline.multi import check_multi_design, multi_document, multi_results
from lesmc.scene import Scene

if TYPE_CHECKING:
    from lesmc.common.budget import Budget

__all__ = [
    "MultiReport",
    "check_multi_file",
    "check_multi_scene",
    "multi_exit_status",
    "multi_results",
]


@dataclass(frozen=True)
class MultiReport:
    """``--report DIR`` of a multi-target check: where the results file and the report go,
    the frames for its images (``--frames``) and the scene's ``perception``, read before
    the check (lesmc/cli/check.py ``_report_to``: a bad ``meta.frontend`` is an error
    before the check's time is spent and before anything is written)."""

    dir: str
    frames_dir: str | None
    perception: dict[str, Any]


def check_multi_scene(
    scene: Scene,
    path: str,
    specs: tuple[SpecFile, ...],
    only: tuple[str, ...],
    as_json: bool,
    max_states: int | None = None,
    report: MultiReport | None = None,
    budget: Budget | None = None,
) -> None:
    """Check every property (or those named in ``only``) of ``specs`` on the multi-target
    design of ``scene`` (read from ``path``) within ``budget``; print the results; with
    ``report`` (``--report DIR``, ``--frames``) write the results file, with what
    ``lesmc replay`` reruns, and draw its report there; exit with
    :func:`multi_exit_status`."""
    from lesmc.unfold.multi import composed

    draw = report is not None
    out = check_multi_design(scene, path, specs, only, max_states, draw, budget)
    kind = composed(scene, path).reference_kind()
    if report is None:
        doc = multi_document(scene.tracker.design, kind, out)
    else:
        from lesmc.experiment.multi_verify import replay_meta
        from lesmc.report.multi import write_multi_report
        from lesmc.report.publish import frames_reader

        meta = replay_meta(scene, path, [Path(s.path) for s in specs], None)
        doc = multi_document(scene.tracker.design, kind, out, meta)
        doc["perception"] = report.perception  # as verify's (lesmc/experiment/multi_verify.py)
        page = write_multi_report(doc, report.dir, frames_reader(report.frames_dir))
        click.echo(f"report: {page}", err=True)
    print_multi(doc, as_json)
    sys.exit(multi_exit_status(doc))


def check_multi_file(
    model: MultiModel,
    specs: tuple[SpecFile, ...],
    only: tuple[str, ...],
    as_json: bool,
    budget: Budget | None = None,
) -> None:
    """Check every property (or those named in ``only``) of ``specs`` on a built
    multi-target model (``lesmc check MODEL.npz SPEC``) within ``budget``; print the
    results as :func:`check_multi_scene` prints them; exit with :func:`multi_exit_status`."""
    from lesmc.pipeline.multi import check_multi_model

    out = check_multi_model(model, specs, only, budget)
    design, reference = str(model.meta["design"]), str(model.meta["reference"])
    doc = multi_document(design, reference, out)
    print_multi(doc, as_json)
    sys.exit(multi_exit_status(doc))


def multi_exit_status(doc: dict[str, Any]) -> int:
    """The exit status of a ``lesmc-multi-check`` document (``check`` and ``verify`` with a
    multi-target design; lesmc/results/exit.py's contract): 1 when some property is
    violated with its counterexample confirmed by the replay (or not replayed), else 3
    when some is unknown (a budget stopped its check) or every violation's replay
    diverged (no proof), else 0."""
    from lesmc.results.exit import EXIT_HOLDS, EXIT_UNKNOWN, EXIT_VIOLATED

    results = doc["results"]
    bad = [r for r in results if r["verdict"] == "violated"]
    if any((r.get("replay") or {}).get("status") != "diverged" for r in bad):
        return EXIT_VIOLATED
    if bad or any(r["verdict"] == "unknown" for r in results):
        return EXIT_UNKNOWN
    return EXIT_HOLDS


def print_multi(doc: dict[str, Any], as_json: bool) -> None:
    """A ``lesmc-multi-check`` document on stdout: as JSON, or a line per property and
    per counterexample step (``lesmc verify --design sort`` prints the same)."""
    from lesmc.report.multi import replay_text

    if as_json:
        click.echo(json.dumps(doc, indent=1))
        return
    for r in doc["results"]:
        opt = r["optimum"]
        opt = "inf" if opt is None else opt if isinstance(opt, str) else f"{opt:g}"
        click.echo(
            f"{r['property']}: {r['verdict']}, optimum {opt} "
            f"({r['states']} states, {r['transitions']} transitions)" + replay_text(r.get("replay"))
        )
        for note in r.get("notes", ()):
            click.echo(f"  note: {note}")
        for s in r["counterexample"] or []:
            hid = ", ".join(s["hidden"]) or "-"
            inj = f"; injected {', '.join(s['injected'])}" if s["injected"] else ""
            tid = "-" if s["target_id"] is None else s["target_id"]  # -: no target's track
            click.echo(f"  step {s['step']} frame {s['frame']}: hidden {hid}{inj}; target {tid}")
