"""The verification report, drawn from a results file alone (``lesmc report``).

For each design run of the results document the report draws the paper's
section 8: the frame crop with the original track, counterexample, witness
and ground truth (Figures 6-8), the tree of attacked paths (Figure 9c),
deviation per step against the threshold (Figure 7c-d), the covariance trace
with the monitor's alarms (Figure 10), the per-path measures (Table 3), the
verdicts (Table 4) and, with several runs, the comparison (Table 5); then the
spec text, provenance and timings. Video frames are read only from a
directory the user names (``--frames``); without one the figures have no image.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from lesmc.common.numbers import fmt
from lesmc.engines.result import verdict_words
from lesmc.language import measures
from lesmc.report import figures
from lesmc.report.figure_cache import FigureSet, PngStore
from lesmc.report.figures import COLOURS, Series, TreePath
from lesmc.report.pages import (
    Cell,
    Figure,
    Markup,
    Row,
    Table,
    Text,
    images,
    key_values,
    para,
    render_page,
    table,
)
from lesmc.report.staging import staged
from lesmc.report.text import not_replayed_text, optimum_cell
from lesmc.results.document import ATTACK_PAYOFF
from lesmc.results.read import (
    DesignSearch,
    FalseAlarms,
    HiddenEntry,
    Num,
    Perturbation,
    ResultDoc,
    ResultsDoc,
    RunDoc,
    SceneDoc,
    results_of,
)

MAX_TABLE_ROWS = 60
MAX_TREE_LEAVES = 40

ImageFor = Callable[[int], np.ndarray | None]


def write_report(
    doc: dict[str, Any],
    out_dir: str | Path,
    image_for: ImageFor | None = None,
    files: dict[str, str] | None = None,
    store: PngStore | None = None,
) -> Path:
    """Write report.html, figures/*.png, results.json (``doc``) and ``files`` (name -> text,
    e.g. the scene the results refer to) into ``out_dir``.

    Staged and moved in at the end (lesmc/report/staging.py): nothing the run did
    not create is deleted, two runs into one directory do not mix, and an interrupt
    leaves the old files or the new ones, never a mix.
    ``image_for(frame)`` returns the grey video frame with that index, when known.
    ``store``: figures drawn before, reused when drawn from the same values
    (lesmc/report/figure_cache.py). The figures may be drawn by two processes
    (lesmc/report/drawing.py).
    """
    page, figs = render(results_of(doc), image_for, store)
    with staged(out_dir) as tmp:
        for name, text in (files or {}).items():
            (tmp / name).write_text(text, encoding="utf-8")
        (tmp / "figures").mkdir()
        for name, png in figs.items():
            (tmp / "figures" / name).write_bytes(png)
        (tmp / "results.json").write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n")
        (tmp / "report.html").write_text(page, encoding="utf-8")
    return Path(out_dir) / "report.html"


def _f(x: Num | None) -> float:
    """A number of the results file ("inf" strings, None) as a float."""
    if x is None:
        return math.nan
    if isinstance(x, str):
        return float(x)  # "inf", "-inf"
    return float(x)


def verdict_of(r: ResultDoc) -> str:
    """A result's verdict word and why (lesmc.engines.result.verdict_words)."""
    replay = None if r.replay is None else r.replay.status
    return verdict_words(r.verdict, r.vacuous, list(r.original_alarms or []), replay)


def status_class(r: ResultDoc) -> str:
    """The CSS class of a result's verdict word: one colour per word."""
    return _tag(r.status)


def _opt(r: ResultDoc) -> str:
    known = r.stats.stopped == "finished" and r.optimum != "unknown"
    opt = None if r.optimum == "unknown" else _f(r.optimum)
    lower, upper = r.bounds
    return optimum_cell(opt, known, _f(lower), _f(upper), r.payoffs == "interval")


def _tag(name: str) -> str:
    return "".join(ch if ch.isalnum() else "-" for ch in name)


class _Run:
    """Accessors over one run of the results document."""

    def __init__(self, run: RunDoc) -> None:
        self.d = run
        self.name: str = run.label
        self.tag = _tag(run.design)
        self.paths = run.paths
        self.by_no = {p.no: p for p in self.paths}
        self.states = run.states
        self.props = run.properties
        self.results = run.results
        self.window = run.window
        self.comps = run.model.components
        self.original: int | None = run.original
        self.cex: tuple[int | None, ...] = run.counterexamples
        self.wit: tuple[int | None, ...] = run.witnesses

    def s(self, no: int) -> np.ndarray:
        return np.array([self.states[q].s for q in self.by_no[no].states], float)

    def tau(self, no: int) -> np.ndarray:
        return np.array([_f(self.states[q].tau) for q in self.by_no[no].states])

    def end(self) -> int:
        return self.d.model.end

    def deviations(self, i: int, role: str) -> np.ndarray:
        """Property ``i``'s dist.at(k), k = 0..end, of its counterexample or witness as the
        check computed them (inf after a halt); the original track's are 0 (Eq. 4)."""
        if role == "original":
            return np.zeros(self.end() + 1)
        r = self.results[i]
        path = r.counterexample if role == "counterexample" else r.witness
        return np.array([_f(x) for x in path or ()])

    def adversarial(self, i: int) -> int:
        """Listed tracks that break property ``i`` and that its monitor does not flag."""
        return sum(
            j.admissible and j.violates and not j.alarms for j in (p.judged[i] for p in self.paths)
        )

    def cex_role(self, i: int) -> str:
        """The role of property ``i``'s cheapest path that breaks the system (results'
        ``counterexample``): ``counterexample`` when its objective fails ``holds if``, else
        ``cheapest`` (the property holds: the cheapest such attack costs too much)."""
        r = self.results[i]
        cex = r.is_counterexample
        if cex is None:  # a results file from before lesmc said which
            cex = r.verdict != "holds"
        return "counterexample" if cex else "cheapest"

    def roles(self) -> dict[int, list[tuple[str, int | None]]]:
        """Path number -> (role, property index) pairs: original first, then per property."""
        out: dict[int, list[tuple[str, int | None]]] = {}
        if self.original is not None:
            out.setdefault(self.original, []).append(("original", None))
        for i in range(len(self.props)):
            if self.wit[i] is not None:
                out.setdefault(self.wit[i], []).append(("witness", i))  # type: ignore[arg-type]
            if self.cex[i] is not None:
                out.setdefault(self.cex[i], []).append((self.cex_role(i), i))  # type: ignore[arg-type]
        return out

    def role_text(self, no: int) -> list[str]:
        return [
            r if i is None else f"{self.props[i].name} {ROLE_WORDS.get(r, r)}"
            for r, i in self.roles().get(no, [])
        ]


#: A role as tables and legends name it after the property's name.
ROLE_WORDS = {"witness": "ρ*", "cheapest": "cheapest path (holds: not a counterexample)"}


def render(
    doc: ResultsDoc,
    image_for: ImageFor | None = None,
    store: PngStore | None = None,
) -> tuple[str, dict[str, bytes]]:
    """The report page (templates/report.html.j2; figures as data URIs) and its figures by
    file name (read from ``store`` where drawn before from the same values; drawn
    otherwise, by two processes where :func:`lesmc.report.drawing.may_fork`)."""
    runs = [_Run(r) for r in doc.runs]
    figs = FigureSet(store)
    toc: list[tuple[str, str]] = [("verdicts", "Verdicts")]
    if len(runs) > 1:
        toc.append(("designs", "Designs compared (Table 5)"))
    fa = doc.monitor_false_alarms
    if fa is not None:
        toc.append(("false-alarms", "The monitor on unattacked tracks"))
    ds = doc.design_search
    if ds is not None:
        toc.append(("design-search", "A design that holds"))
    faults = _faults_table(doc.runs)
    if faults is not None:
        toc.append(("faults", "Component failures"))
    sections = []
    for run in runs:
        toc.append((f"design-{run.tag}", f"Design: {run.name}"))
        parts = _section(run, figs, image_for, payoff_words(doc))
        sections.append({"tag": run.tag, "name": run.name, "parts": parts})
    toc += [("specs", "Properties (spec text)"), ("provenance", "Provenance and timings")]
    cheapest = any(r.cex_role(i) == "cheapest" for r in runs for i in range(len(r.props)))
    page = render_page(
        "report.html.j2",
        legend=[
            (COLOURS[role], text)
            for role, text in (
                ("original", "original (unattacked) track"),
                ("counterexample", "counterexample (dashed, hollow markers)"),
                ("cheapest", CHEAPEST_LEGEND),
                ("witness", "witness ρ*"),
                ("truth", "ground truth (dotted)"),
                ("other", "other attacked tracks"),
            )
            if role != "cheapest" or cheapest
        ],
        window_colour=COLOURS["window"],
        meta=_meta(doc),
        toc=toc,
        verdicts=_verdicts(runs),
        table5=_table5(runs) if len(runs) > 1 else None,
        false_alarms=None if fa is None else {"what": fa.what, "table": _false_alarms(fa)},
        design_search=None if ds is None else _design_search(ds),
        faults=faults,
        sections=sections,
        specs=doc.provenance.specs,
        monitored=_monitored(doc),
        provenance=_provenance(doc),
        timings=_timings(doc),
        images=images(figs.pngs, scale=2),  # drawn at 2x: shown at half the natural size, sharp
    )
    return page, figs.pngs


def _meta(doc: ResultsDoc) -> Table:
    prov = doc.provenance
    python = "?" if prov.python is None else prov.python
    rows = dict(doc.meta)
    rows |= {
        "lesmc": f"{prov.tool_version} (Python {python})",
        "date": prov.date,
        "command": " ".join(prov.command),
    }
    return key_values(list(rows.items()))


def _verdicts(runs: list[_Run]) -> list[Markup]:
    return [
        Markup("<b>{}</b> · {}: <span class='{}'>{}</span> (optimum {}, holds if {})").format(
            run.name, r.property, status_class(r), verdict_of(r), _opt(r), r.holds_if
        )
        for run in runs
        for r in run.results
    ]


def _table5(runs: list[_Run]) -> Table:
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
                Cell(_opt(r)),
                Cell(fmt(r.witness_value)),
                Cell(run.adversarial(i)),
            ]
        rows.append(Row(cells))
    return Table(head, rows)


def _sweep_curves(run: RunDoc) -> list[figures.SweepCurve]:
    """The run's sweep variants (``NAME@eps=V``, ``NAME@eps=V,p=1``) as curves: one per
    property and setting of the other parameters, over ε (else over p), in the order
    swept. A sweep of payoff sources alone has no numeric axis: no curve."""
    groups: dict[tuple[str, str, str], list[tuple[float, ResultDoc]]] = {}
    for r in run.results:
        base, _, label = r.property.partition("@")
        settings = dict(kv.split("=", 1) for kv in label.split(",") if "=" in kv)
        if not settings:
            continue
        axis = "eps" if "eps" in settings else "p" if "p" in settings else None
        if axis is None:
            continue
        rest = ",".join(f"{k}={v}" for k, v in settings.items() if k != axis)
        groups.setdefault((base, axis, rest), []).append((float(settings[axis]), r))
    curves = []
    for (base, axis, rest), rows in groups.items():
        if len(rows) < 2:
            continue
        curves.append(
            figures.SweepCurve(
                label=base + (f" ({rest})" if rest else ""),
                parameter=axis,
                values=tuple(v for v, _ in rows),
                optima=tuple(
                    math.nan if r.optimum == "unknown" else _f(r.optimum) for _, r in rows
                ),
                threshold=rows[0][1].threshold,
                verdicts=tuple(verdict_of(r) for _, r in rows),
            )
        )
    return curves


def _sweep_figure(run: _Run, figs: FigureSet) -> Figure | None:
    curves = _sweep_curves(run.d)
    if not curves:
        return None
    name = f"{run.tag}-sweep.png"
    figs.draw(name, figures.sweep, curves)
    return Figure(
        name,
        f"Sensitivity ({run.name}): the optimum of each swept property for each value "
        "(section 4.4: ε and p 'can be determined empirically'); the dashed line is the "
        "threshold, a dotted line marks where the verdict flips, a triangle at the top an "
        "optimum of +inf (no attacked path breaks the system).",
    )


def _faults_table(runs: Sequence[RunDoc]) -> Table | None:
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
                Cell(_opt(r)),
                Cell(worst.removeprefix("worst activation: ")),
            ]
        rows.append(Row(cells))
    return Table(head, rows)


def _false_alarms(fa: FalseAlarms) -> Table:
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


def _design_search(ds: DesignSearch) -> dict[str, Any]:
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


def _series_for(run: _Run, i: int) -> list[tuple[int, str, int | None]]:
    """(path number, role, property) drawn in property ``i``'s figures: original, ρ*, cex."""
    out: list[tuple[int, str, int | None]] = []
    if run.original is not None:
        out.append((run.original, "original", None))
    w, c = run.wit[i], run.cex[i]
    if w is not None:
        out.append((w, "witness", i))
    if c is not None:
        out.append((c, run.cex_role(i), i))
    return out


#: The legend's words for the cheapest path of a property that holds.
CHEAPEST_LEGEND = (
    "cheapest path that breaks the system, of a property that holds: not a counterexample "
    "(dashed, hollow markers)"
)


def _label(run: _Run, no: int, role: str, prop: int | None) -> str:
    names = {"original": "original track", "witness": "witness ρ*"}
    names["cheapest"] = "cheapest breaking path (holds)"
    name = names.get(role, role)
    if prop is not None and len(run.props) > 1:
        name = f"{run.props[prop].name}: {name}"
    return f"{name} (#{no})"


def _drawn_words(drawn: list[tuple[int, str, int | None]]) -> str:
    words = {"original": "the original track (green)", "witness": "the witness ρ* (blue)"}
    words["counterexample"] = "the counterexample (red, dashed)"
    words["cheapest"] = (
        "the cheapest path that breaks the system (purple, dashed; not a counterexample: "
        "its objective meets the threshold, the property holds)"
    )
    return ", ".join(words[r] for _, r, _ in drawn)


def _section(run: _Run, figs: FigureSet, image_for: ImageFor | None, payoffs: str) -> list[Any]:
    """One design's part of the report: model, Table 4, figures, Table 3, notes."""
    parts: list[Any] = [_model_line(run), Text("h3", "Verdicts (Table 4)"), _table4(run)]
    sweep = _sweep_figure(run, figs)
    if sweep is not None:
        parts.append(sweep)
    for i in range(len(run.props)):
        parts += _property_figures(run, i, figs, image_for)
    parts.append(_tree_figure(run, figs))
    parts.append(_tau_figure(run, figs))
    parts += _patches(run, figs, image_for, payoffs)
    parts += _table3(run)
    for r in run.results:
        for n in _notes(r):
            parts.append(para(f"{r.property}: {n}", "note"))
    return parts


def _notes(r: ResultDoc) -> list[str]:
    """A result's notes, and what its final status asks of the reader: a violation not
    replayed says how to replay it (written from the status after any replay, never
    kept from before it)."""
    rp = r.replay
    if rp is None or rp.status != "not replayed":
        return list(r.notes)
    return [*r.notes, not_replayed_text(rp.command)]


def _model_line(run: _Run) -> Text:
    m = run.d.model
    return para(
        Markup(
            "{} states built (the whole model), {} transitions, steps 0..{} (frames {}..{}), "
            "attack window {}..{}, "
            "{} attacked tracks. Model sha256 <code>{}…</code>."
        ).format(
            m.states,
            m.transitions,
            m.end,
            m.first_frame,
            m.first_frame + m.end,
            run.window[0],
            run.window[1],
            run.d.paths_total,
            m.sha256[:16],
        )
    )


def _property_figures(run: _Run, i: int, figs: FigureSet, image_for: ImageFor | None) -> list[Any]:
    """Property ``i``'s tracks in the frame (Figures 6-8) and deviations (Figure 7c-d)."""
    prop, r = run.props[i], run.results[i]
    drawn = _series_for(run, i)
    if not any(role != "original" for _, role, _ in drawn):
        return [
            para(
                f"{prop.name}: no attacked track to draw (no counterexample, no "
                "witness: the monitor excludes every path"
                + (", the unattacked track included" if r.vacuous else "")
                + ")."
            )
        ]
    scene = run.d.scene
    parts: list[Any] = []
    if scene is not None:
        parts.append(_track_figure(run, i, drawn, scene, None, figs, image_for))
    series = [
        Series(_label(run, no, role, p), role, run.deviations(i, role), p, number=no)
        for no, role, p in drawn
    ]
    on_figure = measures.plotted(prop.constraint_source)
    cumulative = (
        on_figure
        and prop.constraint_aggregate == "sum"
        and prop.constraint_range[1] > prop.constraint_range[0]
    )
    bound = prop.bound if on_figure else None
    name = f"{run.tag}-{_tag(prop.name)}-deviation.png"
    figs.draw(
        name,
        figures.deviation,
        series,
        bound,
        cumulative,
        run.window,
        f"{prop.name}: {r.constraint}",
    )
    caption = (
        f"{prop.name} ({run.name}): deviation from the original track per step"
        + (" and accumulated" if cumulative else "")
        + f" of {_drawn_words(drawn[1:]) or 'no attacked track'}"
        + (f", against the constraint's threshold {bound:g}" if bound is not None else "")
        + "."
        + _no_cex_words(run, i)
    )
    return [*parts, Figure(name, caption)]


def _no_cex_words(run: _Run, i: int) -> str:
    """The end of a figure's caption when property ``i`` has no counterexample to draw."""
    if run.cex[i] is None:
        return " No path violates: no counterexample drawn."
    if run.cex_role(i) == "cheapest":
        return " No counterexample: the cheapest path that breaks the system meets the threshold."
    return ""


def _table4(run: _Run) -> Table:
    rows = []
    for i, r in enumerate(run.results):
        check = (
            "exhaustive"
            if run.d.paths_total == len(run.paths)
            else f"over {len(run.paths)} of {run.d.paths_total} paths"
        )
        alarms = r.original_alarms
        mon = run.props[i].monitor
        monitor = (
            "-"
            if mon is None
            else ("except original; " if mon.except_original else "")
            + ("unattacked track alarms at " + ", ".join(map(str, alarms)) if alarms else "none")
        )
        rows.append(
            [
                Cell(r.property, head=True),
                Cell(verdict_of(r), status_class(r)),
                r.objective,
                r.constraint,
                _opt(r),
                r.holds_if,
                fmt(r.witness_value),
                _no(run.wit[i]),
                _cex_cell(run, i),
                monitor,
                f"{run.adversarial(i)} ({check})",
                f"{r.stats.seconds:.3f} s, {r.stats.states_expanded} states expanded",
            ]
        )
    head = ["property", "verdict", "minimise", "subject to", "optimum", "holds if", "θ*"]
    head += ["ρ* (track no.)", "counterexample (track no.)", "monitor", "adversarial tracks"]
    return table([*head, "search"], rows)


def _no(n: int | None) -> str:
    return "-" if n is None else f"#{n}"


def _cex_cell(run: _Run, i: int) -> str:
    """Table 4's counterexample: its row, or, for a property that holds, none and the row
    of the cheapest path that breaks the system."""
    n = run.cex[i]
    if n is None or run.cex_role(i) == "counterexample":
        return _no(n)
    return f"none (#{n}: the cheapest breaking path, not a counterexample)"


def _track_figure(
    run: _Run,
    i: int,
    drawn: list[tuple[int, str, int | None]],
    scene: SceneDoc,
    truth: list[list[float]] | None,
    figs: FigureSet,
    image_for: ImageFor | None,
) -> Figure:
    prop = run.props[i]
    ref = scene.ref_step
    frame = scene.first_frame + ref
    tracks = []
    for no, role, p in drawn:
        pts = np.array([run.states[q].ref for q in run.by_no[no].states], float)
        tracks.append((Series(_label(run, no, role, p), role, np.zeros(0), p, number=no), pts))
    dets = np.array([(d.x_ref, d.y_ref) for d in scene.detections[ref]], float).reshape(-1, 2)
    tr = None
    if scene.truth_ref:
        tr = np.array(
            [[np.nan, np.nan] if t is None else t for t in scene.truth_ref],
            float,
        )
    img = image_for(frame) if image_for is not None else None
    name = f"{run.tag}-{_tag(prop.name)}-tracks.png"
    figs.draw(
        name,
        figures.track_crop,
        tracks,
        ref,
        frame,
        dets,
        tr,
        img,
        f"{prop.name}: tracks in the frame of step {ref}",
    )
    return Figure(
        name,
        f"{prop.name} ({run.name}): {_drawn_words(drawn)}"
        + (", the target's ground truth (black, dotted)" if tr is not None else "")
        + f" and the detections of step {ref} (amber rings), in the pixels of frame {frame}"
        + ("" if img is not None else " (no video frames given: lesmc report --frames DIR)")
        + "."
        + _no_cex_words(run, i),
    )


def _tree_figure(run: _Run, figs: FigureSet) -> Figure:
    roles = run.roles()
    chosen = [p for p in run.paths if p.no in roles]
    for p in run.paths:
        if len(chosen) >= MAX_TREE_LEAVES:
            break
        if p.no not in roles:
            chosen.append(p)
    chosen.sort(key=lambda p: p.no)
    tps = []
    for p in chosen:
        rl = roles.get(p.no, [])
        role = rl[0][0] if rl else "other"
        for strong in ("cheapest", "counterexample"):
            if any(r == strong for r, _ in rl):
                role = strong
        if any(r == "original" for r, _ in rl):
            role = "original"
        tps.append(TreePath(p.no, p.states, p.labels, role, run.role_text(p.no)))
    name = f"{run.tag}-tree.png"
    figs.draw(name, figures.tree, tps, run.d.paths_total, run.window)
    left = run.d.paths_total - len(tps)
    return Figure(
        name,
        f"Attacked tracks ({run.name}), {len(tps)} of {run.d.paths_total} drawn"
        + (f" ({left} not drawn; all are in Table 3 and results.json)" if left else "")
        + ". A node is the detection the tracker takes at that step; each leaf carries its "
        "row number in Table 3 and its roles. Steps at which no track branches are "
        "compressed (dotted edges).",
    )


def _tau_figure(run: _Run, figs: FigureSet) -> Figure | Text:
    series = []
    seen: set[int] = set()
    for i in range(len(run.props)):
        for no, role, p in _series_for(run, i):
            if no in seen:
                continue
            seen.add(no)
            alarms = set()
            for j in range(len(run.props)):
                alarms |= set(run.by_no[no].judged[j].alarms)
            if role == "original":
                for r in run.results:
                    alarms |= set(r.original_alarms or ())
            series.append(
                Series(_label(run, no, role, p), role, run.tau(no), p, tuple(sorted(alarms)), no)
            )
    if not series or all(not np.isfinite(s.values).any() for s in series):
        return para("No covariances in this model: no uncertainty figure.")
    monitored = [p.name for p in run.props if p.monitor is not None]
    name = f"{run.tag}-uncertainty.png"
    figs.draw(name, figures.uncertainty, series, run.window)
    return Figure(
        name,
        f"Covariance trace τ ({run.name}) along "
        f"{_drawn_words([(0, s.role, None) for s in series])}; "
        + (
            f"a cross marks an alarm of the monitor of {', '.join(monitored)} (Eq. 13)."
            if monitored
            else "no property of this design is monitored: no alarms marked."
        ),
    )


def _patches(run: _Run, figs: FigureSet, image_for: ImageFor | None, payoffs: str) -> list[Any]:
    """What the counterexamples' attacks hide: a table, the replays, and the patches."""
    hidden = run.d.hidden
    if not any(hidden.values()):
        return []
    replays = {r.property: r.replay.perturbations for r in run.results if r.replay is not None}
    holding = {run.props[i].name for i in range(len(run.props)) if run.cex_role(i) == "cheapest"}
    out = [*_hidden_table(hidden, replays, holding, payoffs), *_replay_lines(run)]
    if image_for is None:
        return [
            *out,
            para(
                Markup("No frames were given (<code>--frames</code>): the patches are not drawn.")
            ),
        ]
    return [*out, *_patch_figures(run, hidden, replays, figs, image_for)]


def _hidden_table(
    hidden: Mapping[str, tuple[HiddenEntry, ...]],
    replays: Mapping[str, tuple[Perturbation, ...]],
    holding: set[str],
    payoffs: str,
) -> list[Any]:
    """One row per hidden detection: where, its payoff, its certified interval, and the
    payoff the replay recomputed. ``holding``: the properties that hold (their path is the
    cheapest that breaks the system, not a counterexample); ``payoffs``: where the
    payoffs came from (:func:`payoff_words`)."""
    rows = []
    for prop, items in hidden.items():
        recomputed = {p.obs: p for p in replays.get(prop, ())}
        name = f"{prop} (holds: cheapest breaking path)" if prop in holding else prop
        for e in items:
            h = e.hidden
            where = f"({h.x:.1f}, {h.y:.1f})" if h.placed else "-"
            lo, up = e.payoff_lower, e.payoff
            interval = "-" if lo is None else f"[{fmt(lo)}, {fmt(up)}]"
            tight = "-"
            if lo is not None and math.isfinite(_f(up)) and _f(up) > 0:
                tight = f"{_f(lo) / _f(up):.2f}"
            again = recomputed.get(h.obs)
            rec = "-" if again is None else fmt(again.payoff_recomputed)
            rows.append(
                [
                    Cell(name, head=True),
                    h.step,
                    h.frame,
                    h.obs,
                    where,
                    fmt(up),
                    interval,
                    tight,
                    rec,
                ]
            )
    head = ["property", "step", "frame", "detection", "position", "payoff", "interval"]
    title = "What the counterexamples' attacks hide" + (
        " (and the cheapest breaking paths of the properties that hold)" if holding else ""
    )
    return [
        Text("h3", title),
        para(
            Markup(
                "At each attacked step the tracker "
                "takes a detection of lower priority because the attacker hid those ranked before "
                "it (Eq. 5). Payoff: {} (see the payoff unit above). Interval: [certified lower "
                "bound, attack payoff] when the scene carries "
                "certified bounds (<code>verify --payoffs interval</code> certifies every "
                "detection a model can hide, <code>perceive --certify</code> all); tightness = "
                "lower / upper (1: exact). Replayed: the payoff of the same attack recomputed on "
                "the frames by the replay."
            ).format(payoffs)
        ),
        table([*head, "tightness", "replayed"], rows),
    ]


def payoff_words(doc: ResultsDoc) -> str:
    """Where the detections' payoffs came from, in words: the results' ``meta`` says
    (``payoff source``, lesmc/results/document.py); a results file written before it did
    is read as the attack on N_dr when its payoff unit names N_dr."""
    meta = doc.meta
    source = meta.get("payoff source")
    if isinstance(source, str) and source:
        return source
    if "N_dr" in str(meta.get("payoff unit", "")):
        return ATTACK_PAYOFF
    return "as the scene or model gives them (it does not say where they came from)"


def _patch_figures(
    run: _Run,
    hidden: Mapping[str, tuple[HiddenEntry, ...]],
    replays: Mapping[str, tuple[Perturbation, ...]],
    figs: FigureSet,
    image_for: ImageFor,
) -> list[Figure]:
    """The hidden detections' patches: with the replayed perturbation where there is one."""
    triples, singles = [], []
    crops = False
    for prop, items in hidden.items():
        perts = {p.obs: p for p in replays.get(prop, ())}
        for e in items:
            h = e.hidden
            img = image_for(h.frame) if h.placed else None
            if img is None:
                continue
            pert = perts.get(h.obs)
            if pert is None or not pert.delta:  # not replayed, or no perturbation found
                singles.append((f"{prop} step {h.step}\n{h.obs}", figures.patch(img, (h.x, h.y))))
                continue
            x0, y0 = pert.window_origin
            delta = np.asarray(pert.delta, float)[-1]  # the current frame's (the last) channel
            orig = figures.crop(img, x0, y0, delta.shape[1], delta.shape[0])
            triples.append((f"{prop}, step {h.step}, {h.obs}", orig, delta))
            crops |= delta.shape != (figures.WINDOW, figures.WINDOW)  # a detector file's crop
    if triples and crops:
        return _crop_figures(run, triples, figs)
    if triples:
        name = f"{run.tag}-perturbations.png"
        figs.draw(name, figures.perturbations, triples[:8])
        gain = max(figures.amplification(delta)[1] for _, _, delta in triples[:8])
        return [
            Figure(
                name,
                "For each detection a counterexample hides: the original 21×21 patch of the "
                "frame (its N_dr window, current frame), the perturbation the attack adds to that "
                "channel (red brighter, blue darker; each on its own colour scale spanning its "
                "largest change, given under its title in grey levels"
                + (", amplified ×k for visibility where the title says so" if gain > 1 else "")
                + "), and the attacked patch (original + perturbation, not amplified). The attack "
                "also perturbs the window's "
                "three aligned previous frames, not drawn; the payoff is the norm over all four."
                + (f" The first 8 of {len(triples)} are drawn." if len(triples) > 8 else ""),
            )
        ]
    if singles:
        name = f"{run.tag}-hidden.png"
        figs.draw(name, figures.patches, singles[:12])
        return [
            Figure(
                name,
                "The original 21×21 patches of the hidden detections (frame pixels); the "
                "perturbations are drawn once the counterexample is replayed (lesmc verify, "
                "lesmc replay).",
            )
        ]
    return []


def _crop_figures(
    run: _Run, triples: list[tuple[str, np.ndarray, np.ndarray]], figs: FigureSet
) -> list[Figure]:
    """The hidden detections' crops of a detector file's replay (docs/detectors.md)."""
    name = f"{run.tag}-perturbations.png"
    figs.draw(name, figures.perturbations, triples[:8])
    return [
        Figure(
            name,
            "For each detection a counterexample hides: the frame's crop that the detector "
            "file's attack perturbs, the perturbation (its last input channel, in the "
            "network's input units times 255; red brighter, blue darker) and the attacked "
            'crop (docs/detectors.md, "Replay").'
            + (f" The first 8 of {len(triples)} are drawn." if len(triples) > 8 else ""),
        )
    ]


def _replay_lines(run: _Run) -> list[Text]:
    """One line per replayed counterexample: confirmed, or where and why it diverged."""
    items = []
    for r in run.results:
        rp = r.replay
        if rp is None:
            continue
        how = " (repaired joint attack)" if rp.attack == "repaired" else ""
        if rp.status == "not replayed":
            text = Markup(
                "<b>not replayed</b>: the counterexample is the model's; run it through the "
                "detector with <code>{}</code>"
            ).format(rp.command or "lesmc replay RESULTS.json --frames VIDEO/")
        elif rp.status == "confirmed":
            text = Markup(
                "<b>confirmed</b>{}: the real detector and tracker take the same "
                "detections; largest position error {} px"
            ).format(how, f"{rp.max_error_px:.3g}")
        else:
            text = Markup(
                "<b>diverged</b>{} at step {}: {}; the "
                "counterexample is no proof of violation and the verdict is unknown"
            ).format(how, rp.step, rp.reason)
        items.append(Markup("{}: {}").format(r.property, text))
    if not items:
        return []
    return [
        para(
            "Replay of the counterexamples through the real detector and tracker "
            "(docs/semantics.md, “Replay”):"
        ),
        Text("ul", items=items),
    ]


def _table3(run: _Run) -> list[Any]:
    roles = run.roles()
    l, u = run.window
    shown = [p for p in run.paths if p.no in roles]
    shown += [p for p in run.paths if p.no not in roles][: max(MAX_TABLE_ROWS - len(shown), 0)]
    shown.sort(key=lambda p: p.no)
    monitored = [i for i, p in enumerate(run.props) if p.monitor is not None]
    rows = []
    for p in shown:
        cells = [
            Cell(p.no),
            Cell(" → ".join(p.labels[l : u + 1]), "obs"),
            *(Cell(fmt(x)) for x in (p.payoff, p.dist_sum, p.dist_max, p.dist_end)),
            *(Cell("yes" if j.violates else "no") for j in p.judged),
            *(Cell(", ".join(map(str, p.judged[i].alarms)) or "-") for i in monitored),
            Cell(", ".join(run.role_text(p.no))),
        ]
        rows.append(Row(cells, _row_class({r for r, _ in roles.get(p.no, [])})))
    left = run.d.paths_total - len(shown)
    note = f"{len(shown)} of {run.d.paths_total} tracks listed" + (
        f"; {left} left out (results.json lists up to {len(run.paths)})." if left else "."
    )
    head = ["no.", "observations in the window", "φ", "dist.sum", "dist.max", "dist.at(end)"]
    head += [f"breaks {p.name}" for p in run.props]
    head += [f"alarms ({run.props[i].name})" for i in monitored]
    return [
        Text("h3", "Measures of the attacked tracks (Table 3)"),
        para(
            Markup(
                "φ: combined payoff over the window (Eq. 5, 8), in payoff units; deviations of "
                "the position (x, y) from the original track in pixels: accumulated "
                "dist<sup>0,e</sup>, maximum, and at the end. 'breaks P': the path satisfies "
                "P's constraint (it is in P+). Alarms: the steps at which P's monitor counts an "
                "alarm on the path (Eq. 13). Observations along the window {}..{} as "
                "step-detection; row numbers are the tree's leaf numbers."
            ).format(l, u)
        ),
        para(note),
        Table([[Cell(h, head=True) for h in [*head, "role"]]], rows),
    ]


def _row_class(roles: set[str]) -> str:
    """A Table 3 row's shading: a counterexample (red) before the cheapest breaking path of
    a property that holds (purple) before a witness ρ* (blue) before the original track
    (green); the witness is never shaded as a counterexample."""
    for role in ("counterexample", "cheapest", "witness", "original"):
        if role in roles:
            return role
    return ""


def _monitored(doc: ResultsDoc) -> list[str]:
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


def _provenance(doc: ResultsDoc) -> Table:
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


def _timings(doc: ResultsDoc) -> Table:
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
