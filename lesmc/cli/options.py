"""Option parsing shared by several verbs.

Every ``lesmc/cli`` module imports at module level only what its option
declarations need (click, the standard library, lesmc.common.errors): the rest is
imported inside the command, so that ``lesmc --help`` and the light verbs do
not pay for numpy, torch, cv2, matplotlib or scipy (tests/test_startup.py).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import click

from lesmc.common import fields
from lesmc.common.errors import UsageError, escape_control
from lesmc.designs import registry
from lesmc.engines import payoff_modes

if TYPE_CHECKING:
    from lesmc.common.budget import Budget
    from lesmc.scene import Scene

F = TypeVar("F", bound=Callable[..., Any])

DEFAULT_MAX_STATES = 10_000_000
"""``lesmc.engines.check.DEFAULT_MAX_STATES``, repeated so that the options' declarations
do not import the engines (tests/test_startup.py checks that the two agree)."""


class RegistryChoice(click.Choice):  # type: ignore[type-arg, unused-ignore]
    """A choice read from the design registry whenever it is shown or checked, so that a
    design registered after the command line was declared is offered too.

    click declares ``choices`` differently from release to release (a plain class in 8.1,
    ``Sequence`` in 8.4, ``tuple`` in 8.5); the ignores below cover each of them."""

    def __init__(self, names: Callable[[], tuple[str, ...]]) -> None:
        self._names = names
        super().__init__(names())

    @property  # type: ignore[override, unused-ignore]
    def choices(self) -> tuple[str, ...]:
        return self._names()

    @choices.setter
    def choices(self, _value: Any) -> None:
        """click sets the choices once; they are read from the registry instead."""


class LazyHelpOption(click.Option):
    """An option whose help is made whenever it is shown (``help_from``), so that a registry
    whose module imports numpy (the monitors') is read by ``--help`` and docs/cli-options.md
    but not imported by every verb's start."""

    def __init__(self, *args: Any, help_from: Callable[[], str], **kwargs: Any) -> None:
        self._help_from = help_from
        super().__init__(*args, **kwargs)

    @property  # type: ignore[override, unused-ignore]
    def help(self) -> str:
        return self._help_from()

    @help.setter
    def help(self, _value: Any) -> None:
        """click sets the help once; it is made from ``help_from`` instead."""


class FiniteRange(click.FloatRange):
    """``click.FloatRange`` without nan and the infinities (nan passes its comparisons)."""

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        got = super().convert(value, param, ctx)
        if not math.isfinite(got):
            self.fail(f"{got} is not a finite number", param, ctx)
        return got


#: ``-o/--output`` of the verbs that write a model.
model_output = click.option(
    "-o",
    "--output",
    required=True,
    type=click.Path(dir_okay=False),
    help="The model file to write: JSON (.lts), or the binary form when it ends in .npz "
    "(docs/lts-format.md; loads at disk speed).",
)


def file_option(flag: str, dest: str, help_text: str) -> Callable[[F], F]:
    """An optional ``FLAG FILE`` option (a path to a file, not a directory)."""
    return click.option(
        flag, dest, type=click.Path(dir_okay=False), default=None, metavar="FILE", help=help_text
    )


def design_option(help_text: str) -> Callable[[F], F]:
    """``--design TRACKER``: a tracker of the registry, overriding the one a scene names."""
    return click.option(
        "--design", type=RegistryChoice(registry.tracker_names), default=None, help=help_text
    )


#: ``--spec FILE`` (repeatable) of the verbs that check a video's designs.
spec_option = click.option(
    "--spec",
    "specs",
    multiple=True,
    type=click.Path(dir_okay=False),
    help="Property file (repeatable) [default: the bundled robustness and resilience].",
)

#: ``--nets DIR`` of the verbs that perceive a video.
nets_option = click.option(
    "--nets",
    "nets_dir",
    type=click.Path(file_okay=False),
    default=None,
    help="Trained networks [default: the shipped ones].",
)


def network_options(f: F) -> F:
    """``--detector FILE`` and ``--locator FILE``: the user's N_dr and N_lp (.pt2, .onnx)."""
    f = file_option(
        "--locator",
        "locator_file",
        "The user's N_lp (.pt2 or .onnx): (B, m+1, 45, 45) windows -> (B, 15, 15) maps "
        "(docs/own-system.md).",
    )(f)
    return file_option(
        "--detector",
        "detector_file",
        "The user's N_dr (.pt2 or .onnx): (B, m+1, 21, 21) windows -> (B, 2) logits; "
        "payoffs by its attack, certified bounds if its operations allow "
        "(docs/own-system.md). A FILE.toml or FILE.json is a detector file instead: the "
        "user's whole-frame heatmap or box detector, without the front end "
        "(docs/detectors.md; perceive, verify, campaign, replay).",
    )(f)


def frames_option(help_text: str, dest: str = "frames_dir") -> Callable[[F], F]:
    """``--frames DIR``: a video's frames, the only place images are read from."""
    return click.option(
        "--frames",
        dest,
        type=click.Path(file_okay=False, exists=True),
        default=None,
        help=help_text,
    )


def payoffs_option(before: str, after: str = "") -> Callable[[F], F]:
    """``--payoffs MODE``: the payoff modes of lesmc/engines/payoff_modes.py, their
    summaries between the verb's ``before`` and ``after`` (docs/semantics.md)."""
    return click.option(
        "--payoffs",
        type=click.Choice(payoff_modes.names()),
        default=payoff_modes.DEFAULT,
        show_default=True,
        help=before + payoff_modes.help_text() + after,
    )


def designs_option() -> Callable[[F], F]:
    """``--design NAME|SET``: the designs (lesmc/designs/registry.py) a video is verified with."""
    return click.option(
        "--design",
        type=RegistryChoice(registry.choices),
        default="paper",
        show_default=True,
        help="A design, or a set of them: "
        + "; ".join(f"{d.name}: {d.summary}" for d in map(registry.get, registry.names()))
        + "; "
        + "; ".join(f"{k} = {', '.join(v)}" for k, v in registry.SETS.items())
        + "; all = every single-target design. verify and campaign check a multi-target "
        "design (sort, gnn) alone, on specs/identity.spec by default.",
    )


def target_option(help_text: str) -> Callable[[F], F]:
    """``--target X,Y@STEP``: where the tracked vehicle starts, overriding a scene's own."""
    return click.option(
        "--target", "target_text", default=None, metavar="X,Y[@STEP]", help=help_text
    )


#: ``--target`` of the verbs that read a scene.
scene_target = target_option(
    "Track the vehicle at X,Y of frame STEP [default: the first], overriding the scene's "
    "target (needed when the scene has none). Its initial velocity comes from the nearest "
    "detection of frame STEP-1: zero at the scene's first frame (give a later STEP, or "
    "perceive with --truth); meta.target_velocity_from says which."
)


def parse_window(text: str) -> tuple[int, int]:
    """``--window L..U`` -> (L, U) (:func:`lesmc.common.fields.parse_window`)."""
    return fields.parse_window(text, "--window")


def finite_seconds(
    _ctx: click.Context, _param: click.Parameter, value: float | None
) -> float | None:
    """``--timeout`` (a :class:`FiniteRange`, so finite already): at most :data:`MAX_TIMEOUT`
    seconds, as the alarm's clock cannot be set further."""
    if value is not None and value > MAX_TIMEOUT:
        raise click.BadParameter(f"{value:g} s is more than {MAX_TIMEOUT:g} s (about 3 years)")
    return value


#: The longest ``--timeout`` (seconds): setitimer overflows past about 9e9.
MAX_TIMEOUT = 1e8


def _size(_ctx: click.Context, _param: click.Parameter, value: str | None) -> int | None:
    """``--max-memory``: a size such as 512M or 4G (default: derived from the free memory)."""
    from lesmc.common.budget import default_max_memory, parse_size

    if value is None:
        return default_max_memory()
    if value.strip().lower() in ("none", "off"):
        return None
    try:
        return parse_size(value)
    except ValueError as exc:
        raise click.BadParameter(escape_control(str(exc))) from None


def memory_option(what: str) -> Callable[[F], F]:
    """``--max-memory SIZE``; ``what`` says what happens past it."""
    return click.option(
        "--max-memory",
        default=None,
        metavar="SIZE",
        callback=_size,
        help="Memory ceiling of the process, e.g. 512M or 4G ('off': none) [default: what "
        f"it holds at start + 80% of the memory available then]; past it {what}.",
    )


def budget_options(max_states_default: int | None, what: str) -> Callable[[F], F]:
    """``--timeout``, ``--max-states`` and ``--max-memory``; ``what`` says what a budget stops."""

    def decorate(f: F) -> F:
        f = memory_option(what)(f)
        f = click.option(
            "--timeout",
            type=FiniteRange(min=0, min_open=True),
            default=None,
            callback=finite_seconds,
            help=f"Seconds for the whole command, loading included; past it {what}.",
        )(f)
        return click.option(
            "--max-states",
            type=click.IntRange(min=1),
            default=max_states_default,
            show_default=max_states_default is not None,
            help=f"Budget of states (made, or expanded per property); past it {what}.",
        )(f)

    return decorate


def budget_from(
    timeout: float | None,
    max_states: int | None,
    max_memory: int | None,
    preload: tuple[str, ...] = (),
    armed: bool = True,
) -> Budget:
    """The command's :class:`~lesmc.common.budget.Budget`; its clock starts now (call it
    first thing in the command, so that loading counts).

    With a timeout, an alarm also stops the command :data:`~lesmc.cli.signals.HARD_GRACE`
    seconds past it, should it be in work that checks no clock; it is disarmed when
    the command ends, and the process then exits without the interpreter's teardown
    (:func:`~lesmc.cli.signals.exit_fast`). Not ``armed``: the caller sets the alarm
    with :func:`arm_budget` once its usage errors are out (``check``: a slow load
    must not hide them). ``preload``: modules whose first import
    holds the interpreter in one long C call (torch): imported here, under a watchdog
    that stops the command (exit 3) even inside that call,
    :data:`~lesmc.cli.signals.IMPORT_GRACE` past the timeout
    (:func:`~lesmc.cli.signals.native_deadline`), then the deadline is looked at again.
    """
    from lesmc.cli.signals import IMPORT_GRACE, WATCHDOG_LAG, exit_fast, native_deadline
    from lesmc.common.budget import Budget

    budget = Budget(timeout, max_states, max_memory)
    if timeout is not None:
        exit_fast()
    if armed:
        arm_budget(budget)
    if preload:
        import importlib

        from lesmc.cli.budgets import stop_if_spent

        hard = None if timeout is None else budget.started + timeout + IMPORT_GRACE + WATCHDOG_LAG
        with native_deadline(hard):
            for name in preload:
                importlib.import_module(name)
        stop_if_spent(budget, None, f"importing {', '.join(preload)}")
    return budget


def arm_budget(budget: Budget) -> None:
    """Set the alarm that stops the command :data:`~lesmc.cli.signals.HARD_GRACE` seconds
    past ``budget``'s deadline (what is left of its timeout; none without one), disarmed
    when the command ends."""
    from lesmc.cli.signals import arm_deadline

    left = budget.seconds_left()
    if left is None:
        return
    disarm = arm_deadline(left)
    ctx = click.get_current_context(silent=True)
    if ctx is not None:
        ctx.call_on_close(disarm)


def load_scene_file(
    path: str, design: str | None = None, target: str | None = None, tracker: str | None = None
) -> Scene:
    """A scene file; ``target`` (``X,Y@STEP``) overrides or supplies its target, ``tracker``
    (a tracker file) replaces its tracker."""
    from lesmc.api import load_scene

    return load_scene(path, target, design, tracker)


def faults_option(extra: str = "") -> Callable[[F], F]:
    """``--faults FILE``: component failures (docs/language.md, "Faults"), for ``check``
    and ``verify``; ``extra`` ends the help text."""
    return file_option(
        "--faults",
        "faults_file",
        "Also check every property under the component failures of FILE's faults "
        "block (Kalman matrix entries, sensor outages, detector neurons stuck; "
        "docs/language.md, 'Faults'): one "
        "result per combination of at most 'budget' faults, named NAME+FAULT, the "
        "activation steps chosen by the adversary." + extra,
    )


#: ``--tracker FILE``: a tracker file replacing the scene's tracker block.
#: ``--truth FILE`` of the verbs that run a video's truth tracks (alarms, tune).
video_truth_option = file_option(
    "--truth", "truth", "truth.json of a video [default: VIDEO/truth.json]."
)

tracker_option = file_option(
    "--tracker",
    "tracker_file",
    "A tracker file (JSON, or TOML unless the name ends in .json) replacing the "
    "scene's tracker: a preset model (cv2d, ca2d) or the matrices F, H, Q, R, P0 "
    "(docs/own-system.md).",
)


def distinct_files(inputs: dict[str, str | None], outputs: dict[str, str]) -> None:
    """Refuse, before any work, an output that names one of the command's inputs or
    another output (writing it would destroy the other), or that exists and is not a
    regular file (``files.output_target``). Inputs may name the same file (``import mot
    gt.txt --gt gt.txt``). Keys: the option names shown; None: not given. Paths are
    compared with symlinks and ``..`` resolved."""
    from lesmc.common.files import output_target

    named = {Path(p).resolve(): what for what, p in inputs.items() if p is not None}
    for what, out in outputs.items():
        output_target(out)
        key = Path(out).resolve()
        if key in named:
            raise UsageError(f"{named[key]} and {what} name the same file ({escape_control(out)})")
        named[key] = what


def refuse_output_among_frames(frames_dir: str | None, output: str, what: str) -> None:
    """Refuse, before any work, an output that would be a frame of ``frames_dir`` (a file
    of a frame's extension in it, as lesmc/video/reader.py lists them): it would replace
    one of the command's input frames, or add one to the video."""
    if frames_dir is None:
        return
    from lesmc.video.reader import EXTENSIONS

    out = Path(output).resolve()
    if (
        out.parent == Path(frames_dir).resolve()
        and out.suffix.lower() in EXTENSIONS
        and not out.name.startswith(".")
    ):
        raise UsageError(
            f"{what} {escape_control(output)} would be a frame of {escape_control(frames_dir)} "
            "(the frames read): write it elsewhere"
        )
