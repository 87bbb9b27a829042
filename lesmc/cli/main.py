"""The ``lesmc`` command line: parse options, call the pipeline, report, exit.

User mistakes (bad files, bad options) print ``FILE:LINE:COL: message`` on
stderr and exit with status 2, without a traceback and without writing output.
"""

from __future__ import annotations

import sys

import click
from rich.console import Console

from lesmc.cli.build import build_cmd, track_cmd
from lesmc.cli.check import check_cmd
from lesmc.cli.perceive import perceive_cmd
from lesmc.cli.reduce import reduce_group
from lesmc.cli.train import train_cmd
from lesmc.cli.verify import verify_cmd
from lesmc.cli.video import synth_cmd
from lesmc.errors import LesmcError
from lesmc.report.exit import EXIT_USAGE


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="lesmc")
def cli() -> None:
    """lesmc: model checking robustness and resilience of learning-enabled state estimators.

    \b
    The whole experiment (paper section 8) in one command:
      lesmc verify                           embedded synthetic video, both designs, report
      lesmc verify FRAMES/ --target X,Y      your video
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
    Exit status: 0 all hold, 1 some violated, 2 bad input, 3 some unknown.
    """


cli.add_command(check_cmd)
cli.add_command(build_cmd)
cli.add_command(track_cmd)
cli.add_command(reduce_group)
cli.add_command(synth_cmd)
cli.add_command(perceive_cmd)
cli.add_command(train_cmd)
cli.add_command(verify_cmd)


def main(argv: list[str] | None = None) -> None:
    """Console entry point: turns LesmcError into exit status 2 with a clean message."""
    try:
        cli.main(args=argv, prog_name="lesmc", standalone_mode=False)
    except click.exceptions.Abort:
        Console(stderr=True).print("aborted")
        sys.exit(130)
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
