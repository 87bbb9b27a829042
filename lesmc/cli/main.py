"""The ``lesmc`` command line: parse options, call the pipeline, report, exit.

User mistakes (bad files, bad options) print ``FILE:LINE:COL: message`` on
stderr and exit with status 2, without a traceback and without writing output.
A bug in lesmc (any other exception) exits with status 4 and one line on stderr,
never with 1, which means "violated"; Ctrl-C exits with 130, SIGTERM with 143
(lesmc/cli/signals.py: both unwind, so nothing temporary is left behind).

Start-up is kept light: this module and the command modules import only click
and what option declarations need; each command imports its pipeline (numpy,
torch, cv2, ...) when it runs, inside :func:`main`'s handlers.
"""

from __future__ import annotations

import json
import os
import sys
import traceback
from typing import Any, NoReturn

import click

from lesmc.cli.alarms import alarms_cmd
from lesmc.cli.build import build_cmd, track_cmd
from lesmc.cli.campaign import campaign_cmd
from lesmc.cli.check import check_cmd
from lesmc.cli.export import export_cmd
from lesmc.cli.importing import import_group
from lesmc.cli.perceive import perceive_cmd
from lesmc.cli.reduce import reduce_group
from lesmc.cli.replay import replay_cmd
from lesmc.cli.report import report_cmd
from lesmc.cli.signals import (
    DEADLINE_DOCUMENT,
    DEADLINE_MESSAGE,
    DeadlinePassed,
    Terminated,
    handlers,
    stdout_closed,
)
from lesmc.cli.train import train_cmd
from lesmc.cli.tune import tune_cmd
from lesmc.cli.verify import verify_cmd
from lesmc.cli.video import synth_cmd
from lesmc.common.errors import BudgetError, LesmcError, Location
from lesmc.designs import registry
from lesmc.exporters import formats
from lesmc.results.exit import EXIT_INTERNAL, EXIT_INTERRUPTED, EXIT_UNKNOWN, EXIT_USAGE


class _Group(click.Group):
    """click's group, except that a closed stdout is not click's exit 1 ("violated")."""

    def make_context(
        self,
        info_name: str | None,
        args: list[str],
        parent: click.Context | None = None,
        **extra: Any,
    ) -> click.Context:
        try:  # --help and --version write while the arguments are parsed
            return super().make_context(info_name, args, parent, **extra)
        except BrokenPipeError:
            sys.exit(stdout_closed())

    def invoke(self, ctx: click.Context) -> object:
        try:
            return super().invoke(ctx)
        except BrokenPipeError:
            sys.exit(stdout_closed())


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="lesmc")
def cli() -> None:
    """lesmc: model checking robustness and resilience of learning-enabled state estimators.

    \b
    The whole experiment (paper section 8) in one command:
      lesmc verify                           embedded synthetic video, report; designs:
                                             {paper_designs}
      lesmc verify FRAMES/ --target X,Y      your video
      lesmc campaign --out DIR               many targets x the paper's 36 windows, in parallel
    \b
    Stage by stage (frames -> scene -> model -> check -> report):
      lesmc synth OUT/                       a synthetic WAMI video with truth.json
      lesmc perceive FRAMES/ --truth T       detector quality against the truth
      lesmc perceive FRAMES/ -o SCENE.json --target X,Y[@STEP]
                                             detections, payoffs, homographies: a scene
      lesmc train --out NETS/                retrain the detection CNNs
      lesmc track SCENE.json                 the unattacked track and its monitor
      lesmc build SCENE.json --window 6..8 -o MODEL.lts
                                             unfold every attacked run into a model
      lesmc check MODEL.lts SPEC.spec        check properties on a model
      lesmc check SCENE.json SPEC.spec       ... or on a scene, building on the fly
      lesmc check ... --report DIR           ... and write results.json and the HTML report
      lesmc alarms VIDEO|SCENE --design D --monitor nis 0.99
                                             a monitor's false alarms on unattacked tracks
      lesmc tune SCENE|VIDEO SPEC... --space SPACE.toml [--best-out T.toml]
                                             search designs that hold, at a false-alarm cost
      lesmc report RESULTS.json --out DIR [--frames VIDEO/]
                                             redraw the report from a results file alone
      lesmc replay RESULTS.json --frames VIDEO/
                                             counterexamples through the real detector
      lesmc reduce knapsack ITEMS.csv ...    build a knapsack instance as a model
      lesmc export MODEL.lts --format FORMAT -o OUT
                                             the model for model checkers and graph tools
      lesmc import mot DET.txt -o SCENE.json [--gt GT.txt --track ID]
                                             your detections (MOTChallenge) as a scene
      ... --tracker FILE, --detector FILE    your tracker, your networks (docs/own-system.md)
    \b
    Every verb takes --json: one versioned document on stdout, described by a
    schema in lesmc/schemas/ (docs/cli.md). Options that would be ignored are errors.
    \b
    Exit status: 0 all hold, 1 some violated, 2 bad input, 3 some unknown,
    4 internal error (a bug: please report it), 130 interrupted (SIGINT),
    143 terminated (SIGTERM), 141 stdout closed (e.g. piped into head).
    Set LESMC_DEBUG=1 to see the traceback of an internal error.
    """


def _with_designs(text: str) -> str:
    """The help text with verify's default designs (``paper``) named from the registry."""
    paper = registry.SETS["paper"]
    named = f"{', '.join(paper)} (the {len(paper)} of --design paper)"
    return text.replace("{paper_designs}", named)


cli.help = _with_designs(cli.help or "")

#: One line per verb for ``lesmc --help`` (click would cut the first sentence short).
SHORT_HELP = {
    "alarms": "A monitor's false alarms on the unattacked tracks of a video or scene.",
    "build": "Unfold a scene into a model (.lts) for one attack window.",
    "campaign": "Verify many targets x windows x designs, on Dask.",
    "check": "Check properties on a model or a scene: verdict, optimum, paths.",
    "export": f"Write a model as {formats.spelled()}.",
    "import": "Make a scene from MOTChallenge detection files (det.txt, gt.txt).",
    "perceive": "Detect vehicles in frames; price each detection; write a scene.",
    "reduce": "Reduce a classic problem (knapsack) to a model and a property.",
    "replay": "Run counterexamples through the real detector and tracker.",
    "report": "Draw the HTML report from a results file.",
    "synth": "Generate a synthetic WAMI video with its truth.",
    "track": "Run the tracker unattacked: estimates, tau and monitor alarms.",
    "train": "Train the detection CNNs on synthetic videos.",
    "tune": "Search tracker and monitor settings: verdicts against false alarms.",
    "verify": "The whole experiment on a video: perceive, check, replay, report.",
}

cli.add_command(check_cmd)
cli.add_command(build_cmd)
cli.add_command(track_cmd)
cli.add_command(alarms_cmd)
cli.add_command(tune_cmd)
cli.add_command(reduce_group)
cli.add_command(synth_cmd)
cli.add_command(perceive_cmd)
cli.add_command(train_cmd)
cli.add_command(verify_cmd)
cli.add_command(report_cmd)
cli.add_command(replay_cmd)
cli.add_command(campaign_cmd)
cli.add_command(export_cmd)
cli.add_command(import_group)
for _name, _cmd in cli.commands.items():
    _cmd.short_help = SHORT_HELP.get(_name, _cmd.short_help)


def _debug() -> bool:
    return os.environ.get("LESMC_DEBUG", "") not in ("", "0")


def _interrupted(message: str = "interrupted") -> NoReturn:
    sys.stderr.write(f"{message}\n")
    sys.exit(EXIT_INTERRUPTED)


def _internal_error(exc: BaseException) -> NoReturn:
    """Exit 4 with one line on stderr (and the traceback first if LESMC_DEBUG=1)."""
    if _debug():
        traceback.print_exception(exc)
    text = " ".join(str(exc).split())
    what = f"{type(exc).__name__}: {text}" if text else type(exc).__name__
    sys.stderr.write(f"lesmc: internal error: {what} (please report this, with the command line)\n")
    sys.exit(EXIT_INTERNAL)


def _json_error(message: str, where: Location | None, code: int) -> None:
    """With ``--json``: the error as a document on stdout too (format lesmc-error,
    lesmc/schemas/error.json), so that a caller reading stdout learns why."""
    doc = {
        "format": "lesmc-error",
        "version": 1,
        "exit": code,
        "error": {
            "message": message,
            "file": None if where is None else where.path,
            "line": None if where is None else where.line,
            "column": None if where is None else where.column,
            "item": None if where is None else where.item,
        },
    }
    try:
        sys.stdout.write(json.dumps(doc, indent=1) + "\n")
        sys.stdout.flush()
    except BrokenPipeError:
        pass


def main(argv: list[str] | None = None) -> None:
    """Console entry point: every way out of lesmc maps to a documented exit status.

    0/1/3 come from the commands (verdicts), 2 from LesmcError and click usage
    errors, 4 from any other exception (an internal error), 130 from Ctrl-C,
    128 + N from signal N (SIGTERM 143), 141 from a closed stdout.
    """
    with handlers():
        _main(argv)


def _main(argv: list[str] | None) -> None:
    as_json = "--json" in (sys.argv[1:] if argv is None else argv)
    try:
        cli.main(args=argv, prog_name="lesmc", standalone_mode=False)
    except click.exceptions.Abort as exc:
        # click turns KeyboardInterrupt and EOFError raised in a command into Abort.
        if isinstance(exc.__cause__, KeyboardInterrupt):
            _interrupted()
        if isinstance(exc.__cause__, EOFError):  # e.g. a truncated file: not the user's Ctrl-D
            _internal_error(exc.__cause__)
        _interrupted("aborted")
    except KeyboardInterrupt:
        _interrupted()
    except Terminated as exc:
        sys.stderr.write("terminated\n")
        sys.exit(exc.exit_status)
    except DeadlinePassed:
        sys.stderr.write(DEADLINE_MESSAGE)
        if as_json:
            sys.stdout.write(DEADLINE_DOCUMENT)
        sys.exit(EXIT_UNKNOWN)
    except click.ClickException as exc:
        exc.show()
        code = EXIT_USAGE if exc.exit_code != 0 else 0
        if as_json and code:
            _json_error(exc.format_message(), None, code)
        sys.exit(code)
    except BudgetError as exc:
        sys.stderr.write(exc.render() + "\n")
        if as_json:
            _json_error(exc.message, exc.location, EXIT_UNKNOWN)
        sys.exit(EXIT_UNKNOWN)
    except LesmcError as exc:
        sys.stderr.write(exc.render() + "\n")
        if as_json:
            _json_error(exc.message, exc.location, EXIT_USAGE)
        sys.exit(EXIT_USAGE)
    except click.exceptions.Exit as exc:
        sys.exit(exc.exit_code)
    except SystemExit:
        raise
    except BrokenPipeError:  # stdout closed outside a command (--help, --version)
        sys.exit(stdout_closed())
    except Exception as exc:
        _internal_error(exc)
