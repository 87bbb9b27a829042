"""The ``lesmc`` command line: parse options, call the pipeline, report, exit.

User mistakes (bad files, bad options) print ``FILE:LINE:COL: message`` on
stderr and exit with status 2, without a traceback and without writing output.
A bug in lesmc (any other exception) exits with status 4 and one line on stderr,
never with 1, which means "violated"; Ctrl-C exits with 130.

Start-up is kept light: this module and the command modules import only click
and what option declarations need; each command imports its pipeline (numpy,
torch, cv2, ...) when it runs, inside :func:`main`'s handlers.
"""

from __future__ import annotations

import os
import sys
import traceback
from typing import NoReturn

import click

from lesmc.cli.build import build_cmd, track_cmd
from lesmc.cli.campaign import campaign_cmd
from lesmc.cli.check import check_cmd
from lesmc.cli.perceive import perceive_cmd
from lesmc.cli.reduce import reduce_group
from lesmc.cli.train import train_cmd
from lesmc.cli.verify import verify_cmd
from lesmc.cli.video import synth_cmd
from lesmc.errors import LesmcError
from lesmc.report.exit import EXIT_INTERNAL, EXIT_INTERRUPTED, EXIT_USAGE


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="lesmc")
def cli() -> None:
    """lesmc: model checking robustness and resilience of learning-enabled state estimators.

    \b
    The whole experiment (paper section 8) in one command:
      lesmc verify                           embedded synthetic video, both designs, report
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
      lesmc check ... --report DIR           ... and write the HTML report
      lesmc reduce knapsack ITEMS.csv ...    build a knapsack instance as a model
    \b
    Exit status: 0 all hold, 1 some violated, 2 bad input, 3 some unknown,
    4 internal error (a bug: please report it), 130 interrupted.
    Set LESMC_DEBUG=1 to see the traceback of an internal error.
    """


cli.add_command(check_cmd)
cli.add_command(build_cmd)
cli.add_command(track_cmd)
cli.add_command(reduce_group)
cli.add_command(synth_cmd)
cli.add_command(perceive_cmd)
cli.add_command(train_cmd)
cli.add_command(verify_cmd)
cli.add_command(campaign_cmd)


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


def main(argv: list[str] | None = None) -> None:
    """Console entry point: every way out of lesmc maps to a documented exit status.

    0/1/3 come from the commands (verdicts), 2 from LesmcError and click usage
    errors, 4 from any other exception (an internal error), 130 from Ctrl-C.
    """
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
    except click.ClickException as exc:
        exc.show()
        sys.exit(EXIT_USAGE if exc.exit_code != 0 else 0)
    except LesmcError as exc:
        sys.stderr.write(exc.render() + "\n")
        sys.exit(EXIT_USAGE)
    except click.exceptions.Exit as exc:
        sys.exit(exc.exit_code)
    except SystemExit:
        raise
    except BrokenPipeError:  # pragma: no cover - e.g. piped into head
        sys.exit(0)
    except Exception as exc:
        _internal_error(exc)
