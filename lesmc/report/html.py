"""The verification report: one self-contained report.html, the figures as PNG, results.json.

For each design run (a model, its properties and their check results) the
report draws the paper's section 8: the frame crop with the original track,
counterexample and witness (Figures 6-8), the tree of attacked paths (Figure
9c), deviation per step against the threshold (Figure 7c-d), the covariance
trace with the monitor's alarms (Figure 10), the per-path measures (Table 3),
the verdicts (Table 4) and, with two runs, the comparison (Table 5).
"""

from __future__ import annotations

import base64
import html
import json
import math
import shutil
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lesmc.engines.result import CheckResult, PathInfo
from lesmc.language.semantics import BoundProperty
from lesmc.model.lts import LTS
from lesmc.report import figures
from lesmc.report.figures import ORIGINAL, PALETTE, Drawn
from lesmc.report.paths import PathSet, TrackPath, deviations, enumerate_tracks, judge
from lesmc.report.text import fmt
from lesmc.tracking.scene import Scene

MAX_TABLE_ROWS = 60
MAX_PATHS = 20000


@dataclass
class DesignRun:
    """One design's model, its bound properties and their results (same order)."""

    name: str
    model: LTS
    bound: list[BoundProperty]
    results: list[CheckResult]
    scene: Scene | None = None


@dataclass
class _Analysed:
    run: DesignRun
    window: tuple[int, int]
    paths: PathSet
    number: dict[tuple[str, ...], int]  # path states -> row number (1-based, tree order)
    cex: list[TrackPath | None] = field(default_factory=list)
    wit: list[TrackPath | None] = field(default_factory=list)
    original: TrackPath | None = None
    adversarial: list[int] = field(default_factory=list)  # per property: P+ paths not monitored out
    brute: list[float] = field(default_factory=list)  # per property: min objective over P+


def complete(model: LTS, states: tuple[str, ...]) -> tuple[str, ...]:
    """Extend a path that stops at a property's end with unattacked steps to the model's end."""
    out = list(states)
    while True:
        nxt = model.out(out[-1])
        if not nxt:
            return tuple(out)
        out.append(nxt[0].dst)


def window_of(bound: list[BoundProperty]) -> tuple[int, int]:
    return min(bp.l for bp in bound), max(bp.u for bp in bound)


def _analyse(run: DesignRun) -> _Analysed:
    model = run.model
    win = window_of(run.bound)
    wanted: list[tuple[str, ...]] = [tuple(model.original)]
    for r in run.results:
        for p in (r.counterexample, r.witness):
            if p is not None:
                wanted.append(complete(model, p.states))
    ps = enumerate_tracks(model, win, MAX_PATHS, first=wanted)
    by_states = {p.states: p for p in ps.paths}
    a = _Analysed(run, win, ps, {p.states: i + 1 for i, p in enumerate(ps.paths)})
    a.original = by_states.get(tuple(model.original))

    def find(p: PathInfo | None) -> TrackPath | None:
        return None if p is None else by_states.get(complete(model, p.states))

    for bp, r in zip(run.bound, run.results, strict=True):
        a.cex.append(find(r.counterexample))
        a.wit.append(find(r.witness))
        judged = [judge(model, p, bp) for p in ps.paths]
        bad = [j for j in judged if j.admissible and j.violates and not j.alarmed]
        a.adversarial.append(len(bad))
        a.brute.append(min((j.objective for j in bad), default=math.inf))
    return a


def _drawn(a: _Analysed, i: int) -> list[Drawn]:
    """Original (green), counterexample (red, dashed), witness (blue) of property ``i``."""
    out = []
    if a.original is not None:
        out.append(Drawn(a.original, "original track", ORIGINAL))
    if a.wit[i] is not None:
        out.append(Drawn(a.wit[i], "witness ρ*", PALETTE[1]))  # type: ignore[arg-type]
    if a.cex[i] is not None:  # last, so that it is drawn on top
        out.append(Drawn(a.cex[i], "counterexample", PALETTE[0], dashed=True))  # type: ignore[arg-type]
    return out


def _tree_highlight(a: _Analysed) -> list[Drawn]:
    """Original, and per property its witness ρ* (paper: red robustness, blue resilience)."""
    out = [Drawn(a.original, "original", ORIGINAL)] if a.original is not None else []
    for i, (bp, wit, cex) in enumerate(zip(a.run.bound, a.wit, a.cex, strict=True)):
        colour = PALETTE[i % len(PALETTE)]
        if wit is not None:
            out.append(Drawn(wit, f"{bp.name}: witness ρ*", colour))
        if cex is not None and (wit is None or cex.states != wit.states):
            out.append(Drawn(cex, f"{bp.name}: counterexample", colour, dashed=True))
    return out


def write_report(
    runs: list[DesignRun],
    out_dir: str | Path,
    image_for: Callable[[int], np.ndarray | None] | None = None,
    meta: dict[str, Any] | None = None,
) -> Path:
    """Write report.html, figures/*.png and results.json into ``out_dir`` (atomically).

    ``image_for(frame)`` returns the grey video frame with that index, when known.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".report.", dir=out))
    try:
        (tmp / "figures").mkdir()
        analysed = [_analyse(r) for r in runs]
        body: list[str] = []
        figs: dict[str, bytes] = {}
        body.append(_header(analysed, meta or {}))
        if len(analysed) > 1:
            body.append(_table5(analysed))
        for a in analysed:
            body.append(_section(a, figs, image_for))
        for name, png in figs.items():
            (tmp / "figures" / name).write_bytes(png)
        (tmp / "results.json").write_text(
            json.dumps(_results_json(analysed, meta or {}), indent=1, allow_nan=False) + "\n"
        )
        (tmp / "report.html").write_text(_page(body, figs), encoding="utf-8")
        dest_fig = out / "figures"
        if dest_fig.exists():
            shutil.rmtree(dest_fig)
        (tmp / "figures").rename(dest_fig)
        for name in ("results.json", "report.html"):
            (tmp / name).replace(out / name)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return out / "report.html"


# -- pieces -----------------------------------------------------------------------------


def _e(x: object) -> str:
    return html.escape(str(x))


def _header(analysed: list[_Analysed], meta: dict[str, Any]) -> str:
    rows = "".join(f"<tr><th>{_e(k)}</th><td>{_e(v)}</td></tr>" for k, v in meta.items())
    verdicts = []
    for a in analysed:
        for r in a.run.results:
            verdicts.append(
                f"<li><b>{_e(a.run.name)}</b> · {_e(r.property)}: "
                f"<span class='{r.verdict}'>{r.verdict}</span> "
                f"(optimum {_e(_opt(r))}, holds if {_e(r.holds_op)} {r.threshold:g})</li>"
            )
    return (
        "<h1>lesmc verification report</h1>"
        "<p>Robustness and resilience of a learning-enabled state estimator, checked exactly on "
        "its &lt;PO&gt;²-LTS (every attacked track of the attack window). In the track and "
        f"deviation figures: <span style='color:{ORIGINAL}'>original track</span>, "
        f"<span style='color:{PALETTE[0]}'>counterexample</span> (dashed), "
        f"<span style='color:{PALETTE[1]}'>witness ρ*</span>; in the tree and uncertainty "
        "figures each property has its own colour.</p>"
        f"<table class='meta'>{rows}</table><h2>Verdicts</h2><ul>{''.join(verdicts)}</ul>"
    )


def _opt(r: CheckResult) -> str:
    if r.stats.stopped != "finished":
        return f"[{fmt(r.lower)}, {fmt(r.upper)}]"
    return fmt(r.optimum) if r.optimum is not None else "+inf"


def _table5(analysed: list[_Analysed]) -> str:
    names = [a.run.name for a in analysed]
    head = "".join(f"<th colspan=4>{_e(n)}</th>" for n in names)
    sub = "<th>verdict</th><th>optimum</th><th>θ*</th><th>adversarial tracks</th>" * len(names)
    props = [bp.name for bp in analysed[0].run.bound]
    rows = []
    for i, p in enumerate(props):
        cells = []
        for a in analysed:
            if i >= len(a.run.results):
                cells.append("<td colspan=4>-</td>")
                continue
            r = a.run.results[i]
            cells.append(
                f"<td class='{r.verdict}'>{r.verdict}</td><td>{_e(_opt(r))}</td>"
                f"<td>{_e(fmt(r.witness_value))}</td><td>{a.adversarial[i]}</td>"
            )
        rows.append(f"<tr><th>{_e(p)}</th>{''.join(cells)}</tr>")
    return (
        "<h2>Designs compared (Table 5)</h2><p>Adversarial tracks: attacked paths that break "
        "the system (the constraint holds) and that the runtime monitor, where the design "
        "has one, does not flag.</p>"
        f"<table><tr><th rowspan=2>property</th>{head}</tr><tr>{sub}</tr>{''.join(rows)}</table>"
    )


def _img(name: str, caption: str) -> str:
    return (
        f"<figure><img src='@@{name}@@' alt='{_e(caption)}'>"
        f"<figcaption>{_e(caption)}</figcaption></figure>"
    )


def _section(
    a: _Analysed, figs: dict[str, bytes], image_for: Callable[[int], np.ndarray | None] | None
) -> str:
    run, model = a.run, a.run.model
    tag = "".join(ch if ch.isalnum() else "-" for ch in run.name)
    parts = [
        f"<h2>Design: {_e(run.name)}</h2>",
        f"<p>{model.graph.number_of_nodes()} states, {model.graph.number_of_edges()} "
        f"transitions, steps 0..{model.end}, attack window {a.window[0]}..{a.window[1]}, "
        f"{a.paths.total} attacked paths.</p>",
    ]
    # Table 4: verdicts
    rows = []
    for i, r in enumerate(run.results):
        cex, wit = a.cex[i], a.wit[i]
        check = (
            "exhaustive"
            if a.paths.left_out == 0
            else f"over {len(a.paths.paths)} of {a.paths.total} paths"
        )
        rows.append(
            f"<tr><th>{_e(r.property)}</th><td class='{r.verdict}'>{r.verdict}</td>"
            f"<td>{_e(r.objective)}</td><td>{_e(r.constraint)}</td><td>{_e(_opt(r))}</td>"
            f"<td>{_e(r.holds_op)} {r.threshold:g}</td>"
            f"<td>{_e(fmt(r.witness_value))}</td>"
            f"<td>{a.number.get(wit.states, '-') if wit else '-'}</td>"
            f"<td>{a.number.get(cex.states, '-') if cex else '-'}</td>"
            f"<td>{a.adversarial[i]}</td><td>{_e(fmt(a.brute[i]))} ({check})</td></tr>"
        )
    parts.append(
        "<h3>Verdicts (Table 4)</h3><table><tr><th>property</th><th>verdict</th><th>minimise</th>"
        "<th>subject to</th><th>optimum</th><th>holds if</th><th>θ*</th><th>ρ* (track no.)</th>"
        "<th>counterexample (track no.)</th><th>adversarial tracks</th>"
        "<th>min over them, recomputed from the paths</th></tr>" + "".join(rows) + "</table>"
    )
    # figures
    ref = a.window[1]
    for i, (bp, r) in enumerate(zip(run.bound, run.results, strict=True)):
        drawn = _drawn(a, i)
        if not drawn:
            continue
        img = None
        first = int(model.meta.get("first_frame", 0))
        if image_for is not None:
            img = image_for(first + ref)
        name = f"{tag}-{bp.name}-tracks.png"
        figs[name] = figures.track_crop(
            model,
            drawn,
            ref,
            run.scene,
            img,
            f"{bp.name}: tracks in the frame of step {ref} (frame {first + ref})",
        )
        parts.append(
            _img(
                name,
                f"{bp.name} ({run.name}): original track (green), counterexample "
                f"(dashed), witness ρ* (blue) over the detections of step {ref}.",
            )
        )
        series = [
            (d.label, d.color, d.dashed, deviations(model, d.path.states, bp.components, bp.norm))
            for d in drawn
        ]
        cumulative = (
            bp.constraint.source == "dist"
            and bp.constraint.aggregate == "sum"
            and bp.constraint.hi > bp.constraint.lo
        )
        bound = bp.bound if bp.constraint.source == "dist" else None
        name = f"{tag}-{bp.name}-deviation.png"
        figs[name] = figures.deviation(
            series, bound, cumulative, (bp.l, bp.u), f"{bp.name}: {r.constraint}"
        )
        parts.append(
            _img(
                name,
                f"{bp.name} ({run.name}): deviation from the original track per "
                "step"
                + (" and accumulated" if cumulative else "")
                + ", against the constraint's threshold.",
            )
        )
    highlight = _tree_highlight(a)
    name = f"{tag}-tree.png"
    figs[name], drawn_n = figures.tree(a.paths.paths, highlight, a.paths.total, a.window)
    left = a.paths.total - drawn_n
    parts.append(
        _img(
            name,
            f"All attacked paths ({run.name}); nodes are step-detection; "
            f"{drawn_n} of {a.paths.total} drawn"
            + (f", {left} left out of the drawing" if left else "")
            + ".",
        )
    )
    name = f"{tag}-uncertainty.png"
    figs[name] = figures.uncertainty(model, highlight, a.window)
    parts.append(
        _img(
            name,
            f"Covariance trace τ along the highlighted tracks ({run.name}); "
            "a cross marks a monitor alarm.",
        )
    )
    parts.append(_table3(a))
    for r in run.results:
        for n in r.notes:
            parts.append(f"<p class='note'>{_e(r.property)}: {_e(n)}</p>")
    return "<section>" + "".join(parts) + "</section>"


def _table3(a: _Analysed) -> str:
    marks: dict[tuple[str, ...], list[str]] = {}
    if a.original is not None:
        marks.setdefault(a.original.states, []).append("original")
    for bp, cex, wit in zip(a.run.bound, a.cex, a.wit, strict=True):
        if cex is not None:
            marks.setdefault(cex.states, []).append(f"{bp.name} counterexample")
        if wit is not None:
            marks.setdefault(wit.states, []).append(f"{bp.name} ρ*")
    order = a.paths.paths  # tree order, as numbered
    shown = [p for p in order if p.states in marks]
    shown += [p for p in order if p.states not in marks][: max(MAX_TABLE_ROWS - len(shown), 0)]
    shown.sort(key=lambda p: a.number[p.states])
    l, u = a.window
    rows = []
    for p in shown:
        labels = p.labels()[l : u + 1]
        cls = (
            "original"
            if "original" in marks.get(p.states, [])
            else ("marked" if p.states in marks else "")
        )
        rows.append(
            f"<tr class='{cls}'><td>{a.number[p.states]}</td><td>{_e(' → '.join(labels))}</td>"
            f"<td>{fmt(p.payoff)}</td><td>{fmt(p.dist_sum)}</td><td>{fmt(p.dist_max)}</td>"
            f"<td>{fmt(p.dist_end)}</td><td>{_e(', '.join(marks.get(p.states, [])))}</td></tr>"
        )
    left = a.paths.total - len(shown)
    note = (
        f"<p>{len(shown)} of {a.paths.total} tracks listed"
        + (f"; {left} left out (all are in results.json up to {MAX_PATHS})." if left else ".")
        + "</p>"
    )
    return (
        "<h3>Measures of the attacked tracks (Table 3)</h3>"
        "<p>φ: combined payoff over the window (Eq. 5, 8); deviations of the position (x, y) "
        "from the original track in pixels: accumulated dist<sup>0,e</sup>, maximum, and at the "
        f"end. Observations along the window {l}..{u} as step-detection.</p>"
        + note
        + "<table><tr><th>no.</th><th>observations in the window</th><th>φ</th><th>dist.sum</th>"
        "<th>dist.max</th><th>dist.at(end)</th><th></th></tr>" + "".join(rows) + "</table>"
    )


def _results_json(analysed: list[_Analysed], meta: dict[str, Any]) -> dict[str, Any]:
    def num(x: float) -> float | str:
        return x if math.isfinite(x) else ("inf" if x > 0 else "-inf")

    runs = []
    for a in analysed:
        runs.append(
            {
                "design": a.run.name,
                "results": [r.to_json() for r in a.run.results],
                "adversarial_tracks": dict(
                    zip([bp.name for bp in a.run.bound], a.adversarial, strict=True)
                ),
                "paths_total": a.paths.total,
                "paths": [
                    {
                        "no": a.number[p.states],
                        "states": list(p.states),
                        "labels": p.labels(),
                        "payoff": num(p.payoff),
                        "dist_sum": num(p.dist_sum),
                        "dist_max": num(p.dist_max),
                        "dist_end": num(p.dist_end),
                    }
                    for p in a.paths.paths
                ],
            }
        )
    return {"format": "lesmc-report", "version": 1, "meta": meta, "runs": runs}


_CSS = """
body{font-family:system-ui,Segoe UI,Helvetica,Arial,sans-serif;margin:2em auto;max-width:1100px;
color:#222;line-height:1.4}
h1{font-size:1.6em}h2{border-bottom:2px solid #ddd;padding-bottom:.2em;margin-top:1.6em}
table{border-collapse:collapse;margin:.6em 0;font-size:.85em}
td,th{border:1px solid #ccc;padding:.25em .5em;text-align:right}th{background:#f4f4f4}
td:nth-child(2){text-align:left}
.holds{color:#1a7f37;font-weight:bold}.violated{color:#c62828;font-weight:bold}
.unknown{color:#b26a00;font-weight:bold}tr.original{background:#e8f5e9}tr.marked{background:#fdecea}
figure{display:inline-block;margin:.8em;vertical-align:top;max-width:100%}
figure img{max-width:100%;border:1px solid #ddd}
figcaption{font-size:.85em;color:#555;max-width:640px}
.note{color:#8a6d3b;font-size:.9em}table.meta th{text-align:left}
"""


def _page(body: list[str], figs: dict[str, bytes]) -> str:
    text = "".join(body)
    for name, png in figs.items():
        text = text.replace(
            f"@@{name}@@", "data:image/png;base64," + base64.b64encode(png).decode()
        )
    return (
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
        "<title>lesmc verification report</title>"
        f"<style>{_CSS}</style></head><body>{text}</body></html>\n"
    )
