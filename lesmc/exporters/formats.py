"""The formats ``lesmc export`` writes, in one registry.

Each format is declared once, at the end of this module: its name, the file
suffix, the tools that read it, a one-line summary, its writer (a function of
its own module, imported when a file is written) and what it supports: a
property of ``--spec`` (``--property``, ``--strict``), paths marked from
``--results``, a size limit (``--max-nodes``).

Everything that names export formats reads this module: the command line's
``--format`` choices, option checks and ``--help`` texts (lesmc/cli/export.py),
:func:`lesmc.api.export`, the JSON schema's enum (lesmc/schemas) and the
table of docs/export.md (:func:`docs_table`; tests/test_export_round18.py checks
that the page's table is this one). Adding a format is one module with its
writer and one :func:`register` line here (docs/architecture.md says how).
Importing this module is cheap: a writer is imported only when it writes.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lesmc.common.errors import UsageError
from lesmc.exporters.request import DOT_MAX_NODES, MDP_MAX_PREFIXES, Request

if TYPE_CHECKING:
    from lesmc.model.arrays import ArrayModel
    from lesmc.model.multi import MultiModel


@dataclass(frozen=True)
class ExportFormat:
    """One registered format.

    ``writer`` is ``module:function`` (a :data:`Writer`); ``states_property``: it writes
    one property of a spec file (needs ``--spec``; takes ``--property``, ``--strict``);
    ``marks_paths``: it marks a results file's counterexample and witness
    (``--results``); ``limit``: what ``--max-nodes`` bounds and its default, if anything;
    ``multi_writer``: its writer of a multi-target model (``lesmc build --design sort``'s;
    None: the format does not take one).
    """

    name: str
    suffix: str
    tools: str  #: the tools that read it
    summary: str  #: one line for --help and docs
    writer: str
    states_property: bool = False
    marks_paths: bool = False
    limit: tuple[str, int] | None = None
    multi_writer: str | None = None

    def write(
        self, model: ArrayModel | MultiModel, path: str | Path, request: Request
    ) -> dict[str, object]:
        """Write ``model`` to ``path``; the writer's facts."""
        from lesmc.model.multi import MultiModel

        writer = self.writer
        if isinstance(model, MultiModel):
            refuse_multi(self)
            assert self.multi_writer is not None
            writer = self.multi_writer
        module, _, func = writer.partition(":")
        write: Callable[[Any, str | Path, Request], dict[str, object]] = getattr(
            importlib.import_module(module), func
        )
        return write(model, path, request)

    def supports(self) -> str:
        """What the format takes besides the model, for the docs' table."""
        out = []
        if self.states_property:
            out.append("`--spec` (required), `--property`, `--strict`")
        if self.marks_paths:
            out.append("`--results`, `--property`")
        if self.limit:
            out.append(f"`--max-nodes` ({self.limit[0]}, default {self.limit[1]:,})")
        return "; ".join(out) or "—"


_FORMATS: dict[str, ExportFormat] = {}


def register(fmt: ExportFormat) -> ExportFormat:
    """Add ``fmt`` (replacing one of the same name); returns it."""
    _FORMATS[fmt.name] = fmt
    return fmt


def unregister(name: str) -> None:
    """Remove a format (the tests' toy format)."""
    _FORMATS.pop(name, None)


def names() -> tuple[str, ...]:
    """Every registered format, in registration order."""
    return tuple(_FORMATS)


def get(name: str) -> ExportFormat:
    """The format called ``name`` (KeyError if none)."""
    return _FORMATS[name]


def where(test: Callable[[ExportFormat], bool]) -> tuple[str, ...]:
    """The names of the formats that pass ``test`` (``lambda f: f.states_property``)."""
    return tuple(f.name for f in _FORMATS.values() if test(f))


def spelled(chosen: Sequence[str] | None = None, last: str = "or") -> str:
    """Names as prose: ``dot, graphml or json`` (every format by default)."""
    items = list(names() if chosen is None else chosen)
    return items[0] if len(items) == 1 else f"{', '.join(items[:-1])} {last} {items[-1]}"


OPTIONS = ("spec", "property", "strict", "paths", "max_nodes")  #: what refused() judges


def refused(
    fmt: ExportFormat, given: dict[str, bool], spelling: dict[str, str]
) -> tuple[str, str] | None:
    """The first option that ``fmt`` would ignore or lacks, and why; None if they fit.

    ``given`` says which of :data:`OPTIONS` were given; ``spelling`` names them (and
    ``format``) as the caller's user writes them: ``--spec`` on the command line, ``spec``
    in :func:`lesmc.api.export`. A property beside ``paths`` names whose paths to mark.
    This is the one rule of what each format takes; both callers word errors with it.
    """
    n = spelling
    prop_alone = given["property"] and not given["paths"]
    extra = [
        k for k in ("spec", "property", "strict") if given[k] and (k != "property" or prop_alone)
    ]
    mdp = spelled(where(lambda f: f.states_property))
    if extra and not fmt.states_property:
        listed = ", ".join(n[k] for k in extra)
        why = (
            f"{listed}: {n['spec']}, {n['property']} and {n['strict']} choose what "
            f"{n['format']} {mdp} exports, not {fmt.name}"
        )
        return extra[0], why
    if fmt.states_property and not given["spec"]:
        return "spec", f"{n['format']} {fmt.name} exports a property: give {n['spec']}"
    if given["paths"] and not fmt.marks_paths:
        marking = spelled(where(lambda f: f.marks_paths), "and")
        return "paths", f"{n['paths']}: paths are marked in {marking} only"
    if given["max_nodes"] and fmt.limit is None:
        limited = spelled(where(lambda f: f.limit is not None))
        return "max_nodes", f"{n['max_nodes']} limits {limited} only"
    return None


def refuse_multi(fmt: ExportFormat) -> None:
    """A UsageError unless ``fmt`` writes multi-target models."""
    if fmt.multi_writer is None:
        takes = spelled(where(lambda f: f.multi_writer is not None))
        raise UsageError(
            f"--format {fmt.name} of a multi-target model (design sort, gnn): not supported "
            f"yet; it is exported as {takes}"
        )


def help_table(columns: int = 78) -> str:
    """Each format for ``lesmc export --help``: its name, then the tools that read it and
    its summary, wrapped to ``columns`` (click keeps the lines as they are)."""
    import textwrap

    width = max(map(len, names())) + 2
    return "\n".join(
        textwrap.fill(
            f"{f.name:<{width}}{f.tools}: {f.summary}",
            columns,
            subsequent_indent=" " * width,
            break_on_hyphens=False,
        )
        for f in _FORMATS.values()
    )


def docs_table() -> str:
    """The table of docs/export.md, from the registry."""
    rows = ["| format | suffix | for | what it holds | takes |", "|---|---|---|---|---|"]
    rows += [
        f"| `{f.name}` | `{f.suffix}` | {f.tools} | {f.summary} | {f.supports()} |"
        for f in _FORMATS.values()
    ]
    return "\n".join(rows)


register(
    ExportFormat(
        "dot",
        ".dot",
        "Graphviz",
        "states by step, transitions with rank and combined payoff; counterexample red, "
        "witness blue",
        "lesmc.exporters.graphs:write_dot",
        marks_paths=True,
        limit=("states", DOT_MAX_NODES),
    )
)
register(
    ExportFormat(
        "graphml",
        ".graphml",
        "Gephi, yEd, networkx",
        "every state and transition with their attributes, streamed (any size); attribute role",
        "lesmc.exporters.graphs:write_graphml",
        marks_paths=True,
    )
)
register(
    ExportFormat(
        "json",
        ".lts",
        "lesmc itself",
        "the .lts format (lesmc check reads it back)",
        "lesmc.exporters.lts_json:write_json",
    )
)
register(
    ExportFormat(
        "drn",
        ".drn",
        "Storm",
        'a property as an MDP, in Storm\'s explicit format: Rmin=? [F "violated"] is '
        "lesmc's optimum",
        "lesmc.exporters.drn:write_drn",
        states_property=True,
        limit=("path prefixes", MDP_MAX_PREFIXES),
        multi_writer="lesmc.exporters.multi:write_drn",
    )
)
register(
    ExportFormat(
        "prism",
        ".prism",
        "PRISM, Storm, Modest",
        'the same MDP in the PRISM language: R{"payoff"}min=? [F "violated"] is lesmc\'s optimum',
        "lesmc.exporters.prism:write_prism",
        states_property=True,
        limit=("path prefixes", MDP_MAX_PREFIXES),
        multi_writer="lesmc.exporters.multi:write_prism",
    )
)
