"""Readable tables of check results (rich) and the ``--json`` document."""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

from rich.console import Console
from rich.table import Table

from lesmc.common.errors import escape_text
from lesmc.common.numbers import fmt
from lesmc.engines.result import CheckResult, PathInfo, Stats
from lesmc.language.properties import SpecFile
from lesmc.results.document import provenance
from lesmc.results.record import DesignRun

#: The colour of each verdict word (lesmc.engines.result.STATUSES), in every table.
COLOURS = {
    "holds": "green",
    "holds (vacuous)": "cyan",
    "violated": "red",
    "violated (not replayed)": "magenta",
    "unknown": "yellow",
}


def results_json(
    results: Sequence[CheckResult], specs: Sequence[SpecFile] = (), warnings: Sequence[str] = ()
) -> str:
    """The ``--json`` output of ``lesmc check``: format ``lesmc-check`` (docs/cli.md,
    lesmc/schemas/check.json), the results, the provenance and the input's ``warnings``
    (a scene's unattacked track that does not follow its target)."""
    doc: dict[str, Any] = {
        "format": "lesmc-check",
        "version": 2,
        "provenance": provenance(specs),
        "warnings": list(warnings),
        "results": [r.to_dict() for r in results],
    }
    return json.dumps(doc, indent=1, allow_nan=False)


#: What the summary's two counts of states are (docs/cli.md, "states").
STATES_WORDS = (
    "states expanded: what each property's search expanded (a state can be expanded by "
    "more than one phase); states built: the states of the model it searched (a scene's "
    "model is unfolded on demand and shared by its properties: the count grows)"
)


def verdict_cell(r: CheckResult) -> str:
    """A result's verdict word and why, in its colour (rich markup)."""
    return f"[{COLOURS[r.status]}]{escape_text(r.verdict_text)}[/]"


class _StdoutConsole(Console):
    """A console whose closed stdout is the CLI's to report (exit 141, lesmc/cli/signals.py);
    rich's own handling exits 1, which would read as "violated"."""

    def on_broken_pipe(self) -> None:
        self.quiet = True
        raise BrokenPipeError


def optimum_cell(
    optimum: float | None, known: bool, lower: float, upper: float, interval: bool
) -> str:
    """The optimum as tables print it: the value, ``+inf`` when no path violates, or the
    proven bounds ``[lower, upper]`` when a budget stopped the search or, in interval mode,
    between the certified and the attack payoffs' optima (docs/semantics.md)."""
    if not known or (interval and lower != upper):
        return f"[{fmt(lower)}, {fmt(upper)}]"
    return fmt(optimum) if optimum is not None else "+inf"


def print_runs(console: Console, title: str, runs: Sequence[DesignRun]) -> None:
    """One row per design and property: the verdict, the optimum, the threshold, θ*."""
    table = Table(title=title, title_justify="left")
    for c in ("design", "property", "verdict", "optimum", "holds if", "θ*", "model"):
        table.add_column(
            c,
            justify="left" if c in ("design", "property", "verdict", "holds if") else "right",
            overflow="fold",
        )
    for run in runs:
        own = "-" if run.model is None else f"{run.model.n_states} states built"
        sizes = [own] * len(run.results) + ["under faults"] * len(run.fault_results)
        for r, size in zip(run.all_results, sizes, strict=True):
            known = r.optimum_known and r.stats.stopped == "finished"
            table.add_row(
                escape_text(run.label),
                escape_text(r.property),
                verdict_cell(r),
                optimum_cell(r.optimum, known, r.lower, r.upper, r.payoffs == "interval"),
                f"{r.holds_op} {r.threshold:g}",
                fmt(r.witness_value),
                size,
            )
    console.print(table)
    commands = {  # under faults: nothing to replay
        r.replay_command: None
        for run in runs
        for r in run.results
        if r.replay == "not replayed" and r.replay_command is not None
    }
    for command in commands:
        console.print(escape_text(not_replayed_text(command)))
    for run in runs:  # a diverged replay whose replayed run violates all the same
        for r in run.results:
            if r.replay == "diverged" and r.verdict == "violated" and r.notes:
                console.print(escape_text(f"{run.label}, {r.property}: {r.notes[-1]}"))


def not_replayed_text(command: str | None) -> str:
    """What a violation not replayed through the detector is, and the command that replays
    it (None: the generic one), for tables, notes and reports."""
    how = command or "lesmc verify --scene SCENE --frames VIDEO/"
    if not how.startswith("lesmc "):  # no command replays it
        return f"violated (not replayed): the counterexample was found on the model; {how}"
    return (
        "violated (not replayed): the counterexample was found on the model; replay it "
        f'through the real detector and tracker with {how} (docs/semantics.md, "Replay")'
    )


def states_built(stats: Stats) -> str:
    """The states of the model a check ran on, as the tables print them ("-": not known)."""
    n = stats.extra.get("states_built")
    return str(n) if isinstance(n, int) else "-"


def make_console() -> Console:
    """stdout console; at least 110 columns when piped so tables stay on one line."""
    console = _StdoutConsole()
    if not console.is_terminal:
        console = _StdoutConsole(width=max(console.width, 110))
    return console


def print_results(console: Console, results: Sequence[CheckResult], paths: bool = True) -> None:
    """A summary table, then each property's counterexample and witness, step by step."""
    engines = sorted({r.stats.engine for r in results})
    summary = Table(title=f"lesmc check ({', '.join(engines)})", title_justify="left")
    cols = ("property", "verdict", "optimum", "holds if", "θ*", "states expanded", "states built")
    for col in (*cols, "seconds"):
        summary.add_column(
            col,
            justify="left" if col in ("property", "verdict", "holds if") else "right",
            overflow="fold",
        )
    for r in results:
        known = r.optimum_known and r.stats.stopped == "finished"
        opt = optimum_cell(r.optimum, known, r.lower, r.upper, r.payoffs == "interval")
        summary.add_row(
            escape_text(r.property),
            verdict_cell(r),
            opt,
            f"optimum {r.holds_op} {r.threshold:g}",
            fmt(r.witness_value),
            str(r.stats.states_expanded),
            states_built(r.stats),
            f"{r.stats.seconds:.3f}",
        )
    console.print(summary)
    console.print(STATES_WORDS)
    for r in results:
        console.print(
            f"[bold]{escape_text(r.property)}[/]: minimize {escape_text(r.objective)} "
            f"subject to {escape_text(r.constraint)}"
        )
        for note in r.notes:
            console.print(f"  note: {escape_text(note)}")
        if r.replay == "not replayed":
            console.print(f"  note: {escape_text(not_replayed_text(r.replay_command))}")
        if not paths:
            continue
        if r.cheapest is not None:
            title = (
                "counterexample (cheapest violating path)"
                if r.counterexample is not None
                else "cheapest path that satisfies the constraint (not a counterexample: its "
                "objective meets the threshold"
                + (", so the property holds)" if r.verdict == "holds" else ")")
            )
            _print_path(console, title, r.cheapest)
        elif r.stats.stopped != "finished":
            console.print("  counterexample: none found before the search stopped")
        else:
            console.print("  counterexample: none (no path violates)")
        if r.witness is not None:
            _print_path(console, "witness ρ* (representative path)", r.witness)
        else:
            console.print("  witness: none")


def _print_path(console: Console, title: str, p: PathInfo) -> None:
    console.print(
        f"  {title}: objective {fmt(p.objective)}, constraint {fmt(p.constraint)}"
        + (" (the track halted)" if p.halted else "")
    )
    table = Table(show_edge=False, padding=(0, 1, 0, 1))
    for col in ("step", "state", "obs", "rank", "combined payoff", "deviation"):
        table.add_column(
            col, justify="left" if col in ("state", "obs") else "right", overflow="fold"
        )
    for s in p.steps:
        style = "bold" if s.attacked else None
        table.add_row(
            str(s.step),
            escape_text(s.state),
            escape_text(s.obs or "-"),
            "-" if s.rank is None else str(s.rank),
            fmt(s.combined_payoff),
            fmt(s.deviation),
            style=style,
        )
    console.print(table)
