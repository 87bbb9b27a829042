"""The verification report's tables of the whole results document (lesmc/report/html.py):
the verdicts, Table 5 (designs compared), component failures, the monitor on unattacked
tracks, the design search, the meta, provenance and timings tables.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from lesmc.common.numbers import fmt
from lesmc.report.pages import Cell, Markup, Row, Table, key_values, table
from lesmc.report.run_view import RunView, optimum_text, status_class, verdict_of
from lesmc.results.read import DesignSearch, FalseAlarms, ResultsDoc, RunDoc


def meta_table(doc: ResultsDoc) -> Table:
    """The page's head table: the document's meta, the tool's version, the date, the command."""
    prov = doc.provenance
    python = "?" if prov.python is None else prov.python
    rows = dict(doc.meta)
    rows |= {
        "lesmc": f"{prov.tool_version} (Python {python})",
        "date": prov.date,
        "command": " ".join(prov.command),
    }
    return key_values(list(rows.items()))


def verdict_lines(runs: list[RunView]) -> list[Markup]:
    """One line per design and property: its verdict, optimum and ``holds if``."""
    return [
        Markup("<b>{}</b> · {}: <span class='{}'>{}</span> (optimum {}, holds if {})").format(
            run.name, r.property, status_class(r), verdict_of(r), optimum_text(r), r.holds_if
        )
        for run in runs
        for r in run.results
    ]


def table5(runs: list[RunView]) -> Table:
    """Table 5: the designs compared, property by property."""
    sub = ("verdict", "optimum", "θ*", "adversarial tracks")
    head = [
        [Cell("property", head=True, rows=2), *(Cell(r.name, head=True, span=4) for r in runs)],
        [Cell(h, head=True) for _ in runs for h in sub],
    ]
    rows = []
    for i, p in enumerate(p.name for p in runs[0].props):
        cells = [Cell(p, head=True)]
        for run in runs:
            if i >= len(run.results):
                cells.append(Cell("-", span=4))
                continue
            r = run.results[i]
            cells += [
                Cell(verdict_of(r), status_class(r)),
                Cell(optimum_text(r)),
                Cell(fmt(r.witness_value)),
                Cell(run.adversarial(i)),
            ]
        rows.append(Row(cells))
    return Table(head, rows)


def faults_table(runs: Sequence[RunDoc]) -> Table | None:
    """Which faults break which design: per property under each combination of faults
    (``NAME+FAULT``), each design's verdict, optimum and the worst activation."""
    names: list[str] = []
    for run in runs:
        names += [r.property for _, r in run.faults]
    if not names:
        return None
    names = list(dict.fromkeys(names))
    sub = ("verdict", "optimum", "worst activation")
    head = [
        [Cell("property + faults", head=True, rows=2)]
        + [Cell(run.label, head=True, span=3) for run in runs],
        [Cell(h, head=True) for _ in runs for h in sub],
    ]
    rows = []
    for name in names:
        cells = [Cell(name, head=True)]
        for run in runs:
            got = {r.property: r for _, r in run.faults}
            r = got.get(name)
            if r is None:
                cells.append(Cell("-", span=3))
                continue
            worst = next((n for n in r.notes if n.startswith("worst activation: ")), "")
            cells += [
                Cell(verdict_of(r), status_class(r)),
                Cell(optimum_text(r)),
                Cell(worst.removeprefix("worst activation: ")),
            ]
        rows.append(Row(cells))
    return Table(head, rows)


def false_alarms_table(fa: FalseAlarms) -> Table:
    """The monitor on unattacked tracks: per monitor its alarms per step and per track."""
    head = ["monitor", "tracks", "steps", "alarms", "per step", "tracks with an alarm"]
    rows = [
        [
            Cell(r.monitor, head=True),
            r.tracks,
            r.steps,
            r.alarms,
            _pct(r.alarms, r.steps),
            r.tracks_alarmed,
            _pct(r.tracks_alarmed, r.tracks),
        ]
        for r in fa.rows
    ]
    return table([*head, "per track"], rows)


def design_search_table(ds: DesignSearch) -> dict[str, Any]:
    """ "A design that holds": what was searched, the verdict in words (the best design
    under the budget, or that none holds, with the closest), and the table of the front."""
    chosen = ds.best if ds.best is not None else ds.closest
    pick = None if chosen is None else ds.designs[chosen]
    if ds.best is None:
        answer = f"No design of the space has at most {ds.budget:.1%} false alarms per step"
        if pick is not None:
            answer += f"; the closest is {pick.label} ({_pct(pick.alarms, pick.steps)})."
    else:
        assert pick is not None
        held = [r for r in pick.results if r.status == "holds"]
        answer = f"The best design under {ds.budget:.1%} false alarms per step: {pick.label}. "
        answer += (
            "Every property holds (non-vacuously)."
            if len(held) == len(pick.results)
            else f"{len(held)} of {len(pick.results)} properties hold: no design of the "
            "space holds every property within the budget."
        )
    props = [r.property for r in ds.designs[0].results] if ds.designs else []
    rows = [
        [
            Cell(d.label + (" (best)" if i == ds.best else ""), head=True),
            *(f"{r.status}, {fmt(r.optimum) if r.optimum is not None else 'unknown'}"
              for r in d.results),
            _pct(d.alarms, d.steps),
            "-" if d.tracking_error is None else f"{d.tracking_error:.1f} px",
            "yes" if d.front else "no",
        ]
        for i, d in enumerate(ds.designs)
    ]  # fmt: skip
    head = ["design", *props, "false alarms", "tracking error", "on the front"]
    return {"what": ds.what, "answer": answer, "table": table(head, rows)}


def _pct(a: int, b: int) -> str:
    return "-" if b == 0 else f"{100.0 * a / b:.1f} %"


def monitored(doc: ResultsDoc) -> list[str]:
    """Per design with monitored properties: which, on what, with which parameter."""
    out = []
    for run in doc.runs:
        mon = [(p.name, p.monitor) for p in run.properties if p.monitor is not None]
        if mon:
            out.append(
                f"Design {run.design}: "
                + "; ".join(
                    f"{name} monitored ({m.clause()}"
                    + (", except original" if m.except_original else "")
                    + ")"
                    for name, m in mon
                )
                + "."
            )
    return out


def provenance_table(doc: ResultsDoc) -> Table:
    """Where the results come from: the format, the tool, the date, the command, the seeds
    and each model's digest."""
    prov = doc.provenance
    rows = [
        ("format", f"{doc.format} version {doc.version}"),
        ("tool", f"{prov.tool} {prov.tool_version}"),
        ("date", prov.date),
        ("command", " ".join(prov.command)),
        ("seeds", ", ".join(f"{k} {v}" for k, v in prov.seeds.items()) or "-"),
    ]
    for design, h in prov.model_sha256.items():
        rows.append((f"model sha256 ({design})", h))
    return key_values(rows)


def timings_table(doc: ResultsDoc) -> Table:
    """How long each stage of the run took."""
    rows = [(k, f"{v:.3f} s") for k, v in doc.timings.items()]
    rows += [
        (
            f"{run.design} · {r.property}",
            f"{r.stats.seconds:.3f} s ({r.stats.engine}, "
            f"{r.stats.states_expanded} states expanded)",
        )
        for run in doc.runs
        for r in run.results
    ]
    return key_values(rows)
