"""One design's section of the verification report (lesmc/report/html.py): per property
the frame crop with the original track, counterexample, witness and ground truth
(Figures 6-8), the tree of attacked paths (Figure 9c), deviation and the covariance trace
with the monitor's alarms (Figures 7c-d, 10), sweeps, Table 3 (per-path measures) and
Table 4 (verdicts); the perturbations are lesmc/report/attack_images.py's.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from lesmc.common.numbers import fmt
from lesmc.language import measures
from lesmc.report import figures
from lesmc.report.attack_images import patches
from lesmc.report.figure_cache import FigureSet
from lesmc.report.figures import ImageFor, Series, TreePath
from lesmc.report.pages import Cell, Figure, Markup, Row, Table, Text, para, table
from lesmc.report.run_view import (
    RunView,
    css_tag,
    number,
    optimum_text,
    status_class,
    verdict_of,
)
from lesmc.report.text import not_replayed_text
from lesmc.results.read import RunDoc, SceneDoc
from lesmc.results.result_doc import ResultDoc

#: Table 3 lists at most this many paths (those with a role first).
MAX_TABLE_ROWS = 60
#: The tree figure's leaves at most (Figure 9c).
MAX_TREE_LEAVES = 40


def section(run: RunView, figs: FigureSet, image_for: ImageFor | None, payoffs: str) -> list[Any]:
    """One design's part of the report: model, Table 4, figures, Table 3, notes."""
    parts: list[Any] = [_model_line(run), Text("h3", "Verdicts (Table 4)"), _table4(run)]
    sweep = _sweep_figure(run, figs)
    if sweep is not None:
        parts.append(sweep)
    for i in range(len(run.props)):
        parts += _property_figures(run, i, figs, image_for)
    parts.append(_tree_figure(run, figs))
    parts.append(_tau_figure(run, figs))
    parts += patches(run, figs, image_for, payoffs)
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


def _model_line(run: RunView) -> Text:
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


def sweep_curves(run: RunDoc) -> list[figures.SweepCurve]:
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
                    math.nan if r.optimum == "unknown" else number(r.optimum) for _, r in rows
                ),
                threshold=rows[0][1].threshold,
                verdicts=tuple(verdict_of(r) for _, r in rows),
            )
        )
    return curves


def _sweep_figure(run: RunView, figs: FigureSet) -> Figure | None:
    curves = sweep_curves(run.d)
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


def _series_for(run: RunView, i: int) -> list[tuple[int, str, int | None]]:
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


def _label(run: RunView, no: int, role: str, prop: int | None) -> str:
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


def _property_figures(
    run: RunView, i: int, figs: FigureSet, image_for: ImageFor | None
) -> list[Any]:
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
    name = f"{run.tag}-{css_tag(prop.name)}-deviation.png"
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


def _no_cex_words(run: RunView, i: int) -> str:
    """The end of a figure's caption when property ``i`` has no counterexample to draw."""
    if run.cex[i] is None:
        return " No path violates: no counterexample drawn."
    if run.cex_role(i) == "cheapest":
        return " No counterexample: the cheapest path that breaks the system meets the threshold."
    return ""


def _table4(run: RunView) -> Table:
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
                optimum_text(r),
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


def _cex_cell(run: RunView, i: int) -> str:
    """Table 4's counterexample: its row, or, for a property that holds, none and the row
    of the cheapest path that breaks the system."""
    n = run.cex[i]
    if n is None or run.cex_role(i) == "counterexample":
        return _no(n)
    return f"none (#{n}: the cheapest breaking path, not a counterexample)"


def _track_figure(
    run: RunView,
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
    name = f"{run.tag}-{css_tag(prop.name)}-tracks.png"
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


def _tree_figure(run: RunView, figs: FigureSet) -> Figure:
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


def _tau_figure(run: RunView, figs: FigureSet) -> Figure | Text:
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


def _table3(run: RunView) -> list[Any]:
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
