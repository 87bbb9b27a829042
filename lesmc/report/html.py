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

import base64
import html
import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from lesmc.common.numbers import fmt
from lesmc.engines.result import verdict_words
from lesmc.report import figures
from lesmc.report.figures import COLOURS, Series, TreePath
from lesmc.report.staging import staged
from lesmc.report.text import optimum_cell

MAX_TABLE_ROWS = 60
MAX_TREE_LEAVES = 40

ImageFor = Callable[[int], np.ndarray | None]


def write_report(
    doc: dict[str, Any],
    out_dir: str | Path,
    image_for: ImageFor | None = None,
    files: dict[str, str] | None = None,
) -> Path:
    """Write report.html, figures/*.png, results.json (``doc``) and ``files`` (name -> text,
    e.g. the scene the results refer to) into ``out_dir``.

    Staged and moved in at the end (lesmc/report/staging.py): nothing the run did
    not create is deleted, two runs into one directory do not mix, and an interrupt
    leaves the old files or the new ones, never a mix.
    ``image_for(frame)`` returns the grey video frame with that index, when known.
    """
    page, figs = render(doc, image_for)
    with staged(out_dir) as tmp:
        for name, text in (files or {}).items():
            (tmp / name).write_text(text, encoding="utf-8")
        (tmp / "figures").mkdir()
        for name, png in figs.items():
            (tmp / "figures" / name).write_bytes(png)
        (tmp / "results.json").write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n")
        (tmp / "report.html").write_text(page, encoding="utf-8")
    return Path(out_dir) / "report.html"


def _e(x: object) -> str:
    return html.escape(str(x))


def _f(x: Any) -> float:
    """A number of the results file ("inf" strings, None) as a float."""
    if x is None:
        return math.nan
    if isinstance(x, str):
        return float(x)  # "inf", "-inf"
    return float(x)


def verdict_of(r: dict[str, Any]) -> str:
    """A result's verdict word and why (lesmc.engines.result.verdict_words)."""
    replay = (r.get("replay") or {}).get("status")
    return verdict_words(r["verdict"], bool(r["vacuous"]), r["original_alarms"] or [], replay)


def status_class(r: dict[str, Any]) -> str:
    """The CSS class of a result's verdict word: one colour per word."""
    return _tag(r["status"])


def _opt(r: dict[str, Any]) -> str:
    known = r["stats"]["stopped"] == "finished" and r["optimum"] != "unknown"
    opt = None if r["optimum"] in (None, "unknown") else _f(r["optimum"])
    b = r["bounds"]
    return optimum_cell(opt, known, _f(b["lower"]), _f(b["upper"]), r.get("payoffs") == "interval")


def _tag(name: str) -> str:
    return "".join(ch if ch.isalnum() else "-" for ch in name)


class _Run:
    """Accessors over one run of the results document."""

    def __init__(self, run: dict[str, Any]) -> None:
        self.d = run
        self.name: str = run["label"]
        self.tag = _tag(run["design"])
        self.paths: list[dict[str, Any]] = run["paths"]
        self.by_no = {p["no"]: p for p in self.paths}
        self.states: dict[str, Any] = run["states"]
        self.props: list[dict[str, Any]] = run["properties"]
        self.results: list[dict[str, Any]] = run["results"]
        self.window = (int(run["window"][0]), int(run["window"][1]))
        self.comps: list[str] = run["model"]["components"]
        roles = run["roles"]
        self.original: int | None = roles["original"]
        self.cex: list[int | None] = roles["counterexample"]
        self.wit: list[int | None] = roles["witness"]

    def s(self, no: int) -> np.ndarray:
        return np.array([self.states[q]["s"] for q in self.by_no[no]["states"]], float)

    def tau(self, no: int) -> np.ndarray:
        return np.array([_f(self.states[q]["tau"]) for q in self.by_no[no]["states"]])

    def end(self) -> int:
        return int(self.d["model"]["end"])

    def deviations(self, i: int, role: str) -> np.ndarray:
        """Property ``i``'s dist.at(k), k = 0..end, of its counterexample or witness as the
        check computed them (inf after a halt); the original track's are 0 (Eq. 4)."""
        if role == "original":
            return np.zeros(self.end() + 1)
        path = self.results[i]["counterexample" if role == "counterexample" else "witness"]
        return np.array([_f(x) for x in path["deviation"]])

    def adversarial(self, i: int) -> int:
        """Listed tracks that break property ``i`` and that its monitor does not flag."""
        return sum(
            j["admissible"] and j["violates"] and not j["alarms"]
            for j in (p["judged"][i] for p in self.paths)
        )

    def roles(self) -> dict[int, list[tuple[str, int | None]]]:
        """Path number -> (role, property index) pairs: original first, then per property."""
        out: dict[int, list[tuple[str, int | None]]] = {}
        if self.original is not None:
            out.setdefault(self.original, []).append(("original", None))
        for i in range(len(self.props)):
            if self.wit[i] is not None:
                out.setdefault(self.wit[i], []).append(("witness", i))  # type: ignore[arg-type]
            if self.cex[i] is not None:
                out.setdefault(self.cex[i], []).append(("counterexample", i))  # type: ignore[arg-type]
        return out

    def role_text(self, no: int) -> list[str]:
        return [
            r if i is None else f"{self.props[i]['name']} {'ρ*' if r == 'witness' else r}"
            for r, i in self.roles().get(no, [])
        ]


def render(doc: dict[str, Any], image_for: ImageFor | None = None) -> tuple[str, dict[str, bytes]]:
    """The report page (figures referenced as data URIs) and its figures by file name."""
    runs = [_Run(r) for r in doc["runs"]]
    figs: dict[str, bytes] = {}
    toc: list[tuple[str, str]] = [("verdicts", "Verdicts")]
    body = [_verdicts(runs)]
    if len(runs) > 1:
        toc.append(("designs", "Designs compared (Table 5)"))
        body.append(_table5(runs))
    if doc.get("monitor_false_alarms"):
        toc.append(("false-alarms", "The monitor on unattacked tracks"))
        body.append(_false_alarms(doc["monitor_false_alarms"]))
    for run in runs:
        toc.append((f"design-{run.tag}", f"Design: {run.name}"))
        body.append(_section(run, figs, image_for))
    toc.append(("specs", "Properties (spec text)"))
    body.append(_specs(doc))
    toc.append(("provenance", "Provenance and timings"))
    body.append(_provenance(doc))
    head = (
        "<h1>lesmc verification report</h1>"
        "<p>Robustness and resilience of a learning-enabled state estimator, checked exactly on "
        "its &lt;PO&gt;²-LTS (every attacked track of the attack window). Colours, in every "
        f"figure: {_swatch('original', 'original (unattacked) track')}, "
        f"{_swatch('counterexample', 'counterexample (dashed, hollow markers)')}, "
        f"{_swatch('witness', 'witness ρ*')}, {_swatch('truth', 'ground truth (dotted)')}, "
        f"{_swatch('other', 'other attacked tracks')}; the attack window is shaded "
        f"{_swatch('window', 'yellow')}. Each property has its own marker "
        "(● first, ■ second, ▲ third).</p>"
        + _meta(doc)
        + "<nav><h2>Contents</h2><ol>"
        + "".join(f"<li><a href='#{a}'>{_e(t)}</a></li>" for a, t in toc)
        + "</ol></nav>"
    )
    return _page([head, *body], figs), figs


def _swatch(role: str, text: str) -> str:
    return f"<span style='color:{COLOURS[role]};font-weight:bold'>{_e(text)}</span>"


def _meta(doc: dict[str, Any]) -> str:
    prov = doc.get("provenance", {})
    rows = dict(doc.get("meta", {}))
    rows["lesmc"] = f"{prov.get('tool_version', '?')} (Python {prov.get('python', '?')})"
    rows["date"] = prov.get("date", "?")
    rows["command"] = " ".join(prov.get("command", []))
    body = "".join(f"<tr><th>{_e(k)}</th><td>{_e(v)}</td></tr>" for k, v in rows.items())
    return f"<table class='meta'>{body}</table>"


def _verdicts(runs: list[_Run]) -> str:
    items = []
    for run in runs:
        for r in run.results:
            items.append(
                f"<li><b>{_e(run.name)}</b> · {_e(r['property'])}: "
                f"<span class='{status_class(r)}'>{_e(verdict_of(r))}</span> "
                f"(optimum {_e(_opt(r))}, holds if {_e(r['holds_if'])})</li>"
            )
    return f"<h2 id='verdicts'>Verdicts</h2><ul>{''.join(items)}</ul>"


def _table5(runs: list[_Run]) -> str:
    head = "".join(f"<th colspan=4>{_e(r.name)}</th>" for r in runs)
    sub = "<th>verdict</th><th>optimum</th><th>θ*</th><th>adversarial tracks</th>" * len(runs)
    props = [p["name"] for p in runs[0].props]
    rows = []
    for i, p in enumerate(props):
        cells = []
        for run in runs:
            if i >= len(run.results):
                cells.append("<td colspan=4>-</td>")
                continue
            r = run.results[i]
            cells.append(
                f"<td class='{status_class(r)}'>{_e(verdict_of(r))}</td><td>{_e(_opt(r))}</td>"
                f"<td>{_e(fmt(r['witness_value']))}</td>"
                f"<td>{run.adversarial(i)}</td>"
            )
        rows.append(f"<tr><th>{_e(p)}</th>{''.join(cells)}</tr>")
    return (
        "<h2 id='designs'>Designs compared (Table 5)</h2><p>Adversarial tracks: attacked paths "
        "that break the system (the constraint holds) and that the runtime monitor, where the "
        "design has one, does not flag. A monitor that flags the unattacked track itself makes "
        "'holds' vacuous: it then excludes every path, the harmless ones too.</p>"
        f"<table><tr><th rowspan=2>property</th>{head}</tr><tr>{sub}</tr>{''.join(rows)}</table>"
    )


def _false_alarms(fa: dict[str, Any]) -> str:
    rows = "".join(
        f"<tr><th>{_e(r['monitor'])}</th><td>{r['tracks']}</td><td>{r['steps']}</td>"
        f"<td>{r['alarms']}</td><td>{_e(_pct(r['alarms'], r['steps']))}</td>"
        f"<td>{r['tracks_alarmed']}</td><td>{_e(_pct(r['tracks_alarmed'], r['tracks']))}</td></tr>"
        for r in fa["rows"]
    )
    return (
        "<h2 id='false-alarms'>The monitor on unattacked tracks</h2>"
        f"<p>{_e(fa['what'])}</p><table><tr><th>monitor</th><th>tracks</th><th>steps</th>"
        "<th>alarms</th><th>per step</th><th>tracks with an alarm</th><th>per track</th></tr>"
        f"{rows}</table>"
    )


def _pct(a: int, b: int) -> str:
    return "-" if b == 0 else f"{100.0 * a / b:.1f} %"


def _img(name: str, caption: str) -> str:
    return (
        f"<figure><img src='@@{name}@@' alt='{_e(caption)}'>"
        f"<figcaption>{_e(caption)}</figcaption></figure>"
    )


def _series_for(run: _Run, i: int) -> list[tuple[int, str, int | None]]:
    """(path number, role, property) drawn in property ``i``'s figures: original, ρ*, cex."""
    out: list[tuple[int, str, int | None]] = []
    if run.original is not None:
        out.append((run.original, "original", None))
    w, c = run.wit[i], run.cex[i]
    if w is not None:
        out.append((w, "witness", i))
    if c is not None:
        out.append((c, "counterexample", i))
    return out


def _label(run: _Run, no: int, role: str, prop: int | None) -> str:
    name = "original track" if role == "original" else ("witness ρ*" if role == "witness" else role)
    if prop is not None and len(run.props) > 1:
        name = f"{run.props[prop]['name']}: {name}"
    return f"{name} (#{no})"


def _drawn_words(drawn: list[tuple[int, str, int | None]]) -> str:
    words = {"original": "the original track (green)", "witness": "the witness ρ* (blue)"}
    words["counterexample"] = "the counterexample (red, dashed)"
    return ", ".join(words[r] for _, r, _ in drawn)


def _section(run: _Run, figs: dict[str, bytes], image_for: ImageFor | None) -> str:
    m = run.d["model"]
    parts = [
        f"<section><h2 id='design-{run.tag}'>Design: {_e(run.name)}</h2>",
        f"<p>{m['states']} states, {m['transitions']} transitions, steps 0..{m['end']} "
        f"(frames {m['first_frame']}..{m['first_frame'] + m['end']}), attack window "
        f"{run.window[0]}..{run.window[1]}, {run.d['paths_total']} attacked tracks. "
        f"Model sha256 <code>{_e(m['sha256'][:16])}…</code>.</p>",
        _table4(run),
    ]
    scene = run.d.get("scene")
    truth = None
    for i, prop in enumerate(run.props):
        drawn = _series_for(run, i)
        if not any(role != "original" for _, role, _ in drawn):
            parts.append(
                f"<p>{_e(prop['name'])}: no attacked track to draw (no counterexample, no "
                "witness: the monitor excludes every path"
                + (", the unattacked track included" if run.results[i].get("vacuous") else "")
                + ").</p>"
            )
            continue
        r = run.results[i]
        if scene is not None:
            parts.append(_track_figure(run, i, drawn, scene, truth, figs, image_for))
        series = [
            Series(_label(run, no, role, p), role, run.deviations(i, role), p, number=no)
            for no, role, p in drawn
        ]
        cumulative = (
            prop["constraint_source"] == "dist"
            and prop["constraint_aggregate"] == "sum"
            and prop["constraint_range"][1] > prop["constraint_range"][0]
        )
        bound = float(prop["bound"]) if prop["constraint_source"] == "dist" else None
        name = f"{run.tag}-{_tag(prop['name'])}-deviation.png"
        figs[name] = figures.deviation(
            series, bound, cumulative, run.window, f"{prop['name']}: {r['constraint']}"
        )
        parts.append(
            _img(
                name,
                f"{prop['name']} ({run.name}): deviation from the original track per step"
                + (" and accumulated" if cumulative else "")
                + f" of {_drawn_words(drawn[1:]) or 'no attacked track'}"
                + (f", against the constraint's threshold {bound:g}" if bound is not None else "")
                + ". "
                + ("" if run.cex[i] is not None else "No path violates: no counterexample drawn."),
            )
        )
    parts.append(_tree_figure(run, figs))
    parts.append(_tau_figure(run, figs))
    parts.append(_patches(run, figs, image_for))
    parts.append(_table3(run))
    for r in run.results:
        for n in r["notes"]:
            parts.append(f"<p class='note'>{_e(r['property'])}: {_e(n)}</p>")
    return "".join(parts) + "</section>"


def _table4(run: _Run) -> str:
    rows = []
    for i, r in enumerate(run.results):
        check = (
            "exhaustive"
            if run.d["paths_total"] == len(run.paths)
            else f"over {len(run.paths)} of {run.d['paths_total']} paths"
        )
        alarms = r.get("original_alarms")
        mon = run.props[i]["monitor"]
        monitor = (
            "-"
            if mon is None
            else ("except original; " if mon["except_original"] else "")
            + ("unattacked track alarms at " + ", ".join(map(str, alarms)) if alarms else "none")
        )
        rows.append(
            f"<tr><th>{_e(r['property'])}</th>"
            f"<td class='{status_class(r)}'>{_e(verdict_of(r))}</td>"
            f"<td>{_e(r['objective'])}</td><td>{_e(r['constraint'])}</td><td>{_e(_opt(r))}</td>"
            f"<td>{_e(r['holds_if'])}</td><td>{_e(fmt(r['witness_value']))}</td>"
            f"<td>{_no(run.wit[i])}</td><td>{_no(run.cex[i])}</td><td>{_e(monitor)}</td>"
            f"<td>{run.adversarial(i)} ({check})</td>"
            f"<td>{r['stats']['seconds']:.3f} s, {r['stats']['states_expanded']} states</td></tr>"
        )
    return (
        "<h3>Verdicts (Table 4)</h3><table><tr><th>property</th><th>verdict</th><th>minimise</th>"
        "<th>subject to</th><th>optimum</th><th>holds if</th><th>θ*</th><th>ρ* (track no.)</th>"
        "<th>counterexample (track no.)</th><th>monitor</th><th>adversarial tracks</th>"
        "<th>search</th></tr>" + "".join(rows) + "</table>"
    )


def _no(n: int | None) -> str:
    return "-" if n is None else f"#{n}"


def _track_figure(
    run: _Run,
    i: int,
    drawn: list[tuple[int, str, int | None]],
    scene: dict[str, Any],
    truth: list[list[float]] | None,
    figs: dict[str, bytes],
    image_for: ImageFor | None,
) -> str:
    prop = run.props[i]
    ref = int(scene["ref_step"])
    frame = int(scene["first_frame"]) + ref
    tracks = []
    for no, role, p in drawn:
        pts = np.array([run.states[q]["ref"] for q in run.by_no[no]["states"]], float)
        tracks.append((Series(_label(run, no, role, p), role, np.zeros(0), p, number=no), pts))
    dets = np.array([d[4:6] for d in scene["detections"][ref]], float).reshape(-1, 2)
    tr = None
    if scene.get("truth_ref"):
        tr = np.array(
            [[np.nan, np.nan] if t is None else t for t in scene["truth_ref"]],
            float,
        )
    img = image_for(frame) if image_for is not None else None
    name = f"{run.tag}-{_tag(prop['name'])}-tracks.png"
    figs[name] = figures.track_crop(
        tracks, ref, frame, dets, tr, img, f"{prop['name']}: tracks in the frame of step {ref}"
    )
    return _img(
        name,
        f"{prop['name']} ({run.name}): {_drawn_words(drawn)}"
        + (", the target's ground truth (black, dotted)" if tr is not None else "")
        + f" and the detections of step {ref} (amber rings), in the pixels of frame {frame}"
        + ("" if img is not None else " (no video frames given: lesmc report --frames DIR)")
        + "."
        + ("" if run.cex[i] is not None else " No path violates: no counterexample drawn."),
    )


def _tree_figure(run: _Run, figs: dict[str, bytes]) -> str:
    roles = run.roles()
    chosen = [p for p in run.paths if p["no"] in roles]
    for p in run.paths:
        if len(chosen) >= MAX_TREE_LEAVES:
            break
        if p["no"] not in roles:
            chosen.append(p)
    chosen.sort(key=lambda p: p["no"])
    tps = []
    for p in chosen:
        rl = roles.get(p["no"], [])
        role = rl[0][0] if rl else "other"
        if any(r == "counterexample" for r, _ in rl):
            role = "counterexample"
        if any(r == "original" for r, _ in rl):
            role = "original"
        tps.append(
            TreePath(p["no"], tuple(p["states"]), tuple(p["labels"]), role, run.role_text(p["no"]))
        )
    name = f"{run.tag}-tree.png"
    figs[name] = figures.tree(tps, run.d["paths_total"], run.window)
    left = run.d["paths_total"] - len(tps)
    return _img(
        name,
        f"Attacked tracks ({run.name}), {len(tps)} of {run.d['paths_total']} drawn"
        + (f" ({left} not drawn; all are in Table 3 and results.json)" if left else "")
        + ". A node is the detection the tracker takes at that step; each leaf carries its "
        "row number in Table 3 and its roles. Steps at which no track branches are "
        "compressed (dotted edges).",
    )


def _tau_figure(run: _Run, figs: dict[str, bytes]) -> str:
    series = []
    seen: set[int] = set()
    for i in range(len(run.props)):
        for no, role, p in _series_for(run, i):
            if no in seen:
                continue
            seen.add(no)
            alarms = set()
            for j in range(len(run.props)):
                alarms |= set(run.by_no[no]["judged"][j]["alarms"])
            if role == "original":
                for r in run.results:
                    alarms |= set(r.get("original_alarms") or [])
            series.append(
                Series(_label(run, no, role, p), role, run.tau(no), p, tuple(sorted(alarms)), no)
            )
    if not series or all(not np.isfinite(s.values).any() for s in series):
        return "<p>No covariances in this model: no uncertainty figure.</p>"
    monitored = [p["name"] for p in run.props if p["monitor"] is not None]
    name = f"{run.tag}-uncertainty.png"
    figs[name] = figures.uncertainty(series, run.window)
    return _img(
        name,
        f"Covariance trace τ ({run.name}) along "
        f"{_drawn_words([(0, s.role, None) for s in series])}; "
        + (
            f"a cross marks an alarm of the monitor of {', '.join(monitored)} (Eq. 13)."
            if monitored
            else "no property of this design is monitored: no alarms marked."
        ),
    )


def _patches(run: _Run, figs: dict[str, bytes], image_for: ImageFor | None) -> str:
    """What the counterexamples' attacks hide: a table, the replays, and the patches."""
    hidden = run.d.get("hidden") or {}
    if not any(hidden.values()):
        return ""
    replays = {r["property"]: r.get("replay") or {} for r in run.results}
    out = _hidden_table(hidden, replays) + _replay_lines(run)
    if image_for is None:
        return out + (
            "<p>No frames were given (<code>--frames</code>): the patches are not drawn.</p>"
        )
    return out + _patch_figures(run, hidden, replays, figs, image_for)


def _hidden_table(hidden: dict[str, Any], replays: dict[str, Any]) -> str:
    """One row per hidden detection: where, its payoff, its certified interval, and the
    payoff the replay recomputed."""
    rows = []
    for prop, items in hidden.items():
        recomputed = {p["obs"]: p for p in replays.get(prop, {}).get("perturbations", [])}
        for h in items:
            where = f"({h['x']:.1f}, {h['y']:.1f})" if "x" in h else "-"
            lo, up = h.get("payoff_lower"), h["payoff"]
            interval = "-" if lo is None else f"[{fmt(lo)}, {fmt(up)}]"
            tight = "-"
            if lo is not None and math.isfinite(_f(up)) and _f(up) > 0:
                tight = f"{_f(lo) / _f(up):.2f}"
            again = recomputed.get(h["obs"])
            rec = "-" if again is None else fmt(again["payoff_recomputed"])
            rows.append(
                f"<tr><th>{_e(prop)}</th><td>{h['step']}</td><td>{h['frame']}</td>"
                f"<td>{_e(h['obs'])}</td><td>{_e(where)}</td><td>{_e(fmt(up))}</td>"
                f"<td>{_e(interval)}</td><td>{tight}</td><td>{_e(rec)}</td></tr>"
            )
    return (
        "<h3>What the counterexamples' attacks hide</h3><p>At each attacked step the tracker "
        "takes a detection of lower priority because the attacker hid those ranked before it "
        "(Eq. 5). Payoff: the size of the perturbation the attack found that makes N_dr miss "
        "that detection (an upper bound on the cheapest one; see the payoff unit above). "
        "Interval: [certified lower bound, attack payoff] when the scene carries certified "
        "bounds (<code>verify --payoffs interval</code> certifies every detection a model can "
        "hide, <code>perceive --certify</code> all); tightness = lower / upper (1: exact). "
        "Replayed: the payoff of the same attack recomputed on the frames by the replay.</p>"
        "<table><tr><th>property</th><th>step</th><th>frame</th><th>detection</th>"
        "<th>position</th><th>payoff</th><th>interval</th><th>tightness</th>"
        "<th>replayed</th></tr>" + "".join(rows) + "</table>"
    )


def _patch_figures(
    run: _Run,
    hidden: dict[str, Any],
    replays: dict[str, Any],
    figs: dict[str, bytes],
    image_for: ImageFor,
) -> str:
    """The hidden detections' patches: with the replayed perturbation where there is one."""
    triples, singles = [], []
    for prop, items in hidden.items():
        perts = {p["obs"]: p for p in replays.get(prop, {}).get("perturbations", [])}
        for h in items:
            img = image_for(int(h["frame"])) if "x" in h else None
            if img is None:
                continue
            pert = perts.get(h["obs"])
            if pert is None:
                singles.append(
                    (f"{prop} step {h['step']}\n{h['obs']}", figures.patch(img, (h["x"], h["y"])))
                )
                continue
            x0, y0 = pert["window_origin"]
            orig = figures.patch(img, (x0 + 10, y0 + 10))
            delta = np.asarray(pert["delta"], float)[-1]  # the current frame's channel
            triples.append((f"{prop}, step {h['step']}, {h['obs']}", orig, delta))
    if triples:
        name = f"{run.tag}-perturbations.png"
        figs[name], gain = figures.perturbations(triples[:8])
        return _img(
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
    if singles:
        name = f"{run.tag}-hidden.png"
        figs[name] = figures.patches(singles[:12])
        return _img(
            name,
            "The original 21×21 patches of the hidden detections (frame pixels); the "
            "perturbations are drawn once the counterexample is replayed (lesmc verify, "
            "lesmc replay).",
        )
    return ""


def _replay_lines(run: _Run) -> str:
    """One line per replayed counterexample: confirmed, or where and why it diverged."""
    items = []
    for r in run.results:
        rp = r.get("replay")
        if not rp:
            continue
        how = " (repaired joint attack)" if rp.get("attack") == "repaired" else ""
        if rp["status"] == "not replayed":
            text = (
                "<b>not replayed</b>: the counterexample is the model's; run it through the "
                "detector with <code>lesmc replay RESULTS.json --frames VIDEO/</code>"
            )
        elif rp["status"] == "confirmed":
            text = (
                f"<b>confirmed</b>{how}: the real detector and tracker take the same "
                f"detections; largest position error {rp['max_error_px']:.3g} px"
            )
        else:
            text = (
                f"<b>diverged</b>{how} at step {rp['step']}: {_e(rp['reason'])}; the "
                "counterexample is no proof of violation and the verdict is unknown"
            )
        items.append(f"<li>{_e(r['property'])}: {text}</li>")
    if not items:
        return ""
    return (
        "<p>Replay of the counterexamples through the real detector and tracker "
        "(docs/semantics.md, “Replay”):</p><ul>" + "".join(items) + "</ul>"
    )


def _table3(run: _Run) -> str:
    roles = run.roles()
    l, u = run.window
    shown = [p for p in run.paths if p["no"] in roles]
    shown += [p for p in run.paths if p["no"] not in roles][: max(MAX_TABLE_ROWS - len(shown), 0)]
    shown.sort(key=lambda p: p["no"])
    monitored = [i for i, p in enumerate(run.props) if p["monitor"] is not None]
    rows = []
    for p in shown:
        rl = roles.get(p["no"], [])
        cls = _row_class({r for r, _ in rl})
        breaks = "".join(f"<td>{'yes' if j['violates'] else 'no'}</td>" for j in p["judged"])
        alarms = "".join(
            f"<td>{_e(', '.join(map(str, p['judged'][i]['alarms'])) or '-')}</td>"
            for i in monitored
        )
        rows.append(
            f"<tr class='{cls}'><td>{p['no']}</td>"
            f"<td class='obs'>{_e(' → '.join(p['labels'][l : u + 1]))}</td>"
            f"<td>{fmt(p['payoff'])}</td><td>{fmt(p['dist_sum'])}</td><td>{fmt(p['dist_max'])}</td>"
            f"<td>{fmt(p['dist_end'])}</td>{breaks}{alarms}"
            f"<td>{_e(', '.join(run.role_text(p['no'])))}</td></tr>"
        )
    left = run.d["paths_total"] - len(shown)
    note = (
        f"<p>{len(shown)} of {run.d['paths_total']} tracks listed"
        + (f"; {left} left out (results.json lists up to {len(run.paths)})." if left else ".")
        + "</p>"
    )
    heads = "".join(f"<th>breaks {_e(p['name'])}</th>" for p in run.props)
    heads += "".join(f"<th>alarms ({_e(run.props[i]['name'])})</th>" for i in monitored)
    return (
        "<h3>Measures of the attacked tracks (Table 3)</h3>"
        "<p>φ: combined payoff over the window (Eq. 5, 8), in payoff units; deviations of the "
        "position (x, y) from the original track in pixels: accumulated dist<sup>0,e</sup>, "
        "maximum, and at the end. 'breaks P': the path satisfies P's constraint (it is in P+). "
        "Alarms: the steps at which P's monitor counts an alarm on the path (Eq. 13). "
        f"Observations along the window {l}..{u} as step-detection; row numbers are the tree's "
        "leaf numbers.</p>"
        + note
        + "<table><tr><th>no.</th><th>observations in the window</th><th>φ</th><th>dist.sum</th>"
        f"<th>dist.max</th><th>dist.at(end)</th>{heads}<th>role</th></tr>"
        + "".join(rows)
        + "</table>"
    )


def _row_class(roles: set[str]) -> str:
    """A Table 3 row's shading: a counterexample (red) before a witness ρ* (blue) before
    the original track (green); the witness is never shaded as a counterexample."""
    for role in ("counterexample", "witness", "original"):
        if role in roles:
            return role
    return ""


def _specs(doc: dict[str, Any]) -> str:
    specs = doc.get("provenance", {}).get("specs", [])
    blocks = "".join(f"<h3>{_e(s['path'])}</h3><pre>{_e(s['text'])}</pre>" for s in specs)
    extra = ""
    for run in doc["runs"]:
        mon = [p for p in run["properties"] if p["monitor"] is not None]
        if mon:
            extra += (
                f"<p>Design {_e(run['design'])}: "
                + "; ".join(
                    f"{_e(p['name'])} monitored (monitor uncertainty on "
                    f"{_e(', '.join(p['monitor']['components']))}, tolerance "
                    f"{p['monitor']['tolerance']:g}"
                    + (", except original" if p["monitor"]["except_original"] else "")
                    + ")"
                    for p in mon
                )
                + ".</p>"
            )
    return f"<h2 id='specs'>Properties (spec text)</h2>{blocks}{extra}"


def _provenance(doc: dict[str, Any]) -> str:
    prov = doc.get("provenance", {})
    rows = [
        ("format", f"{doc['format']} version {doc['version']}"),
        ("tool", f"{prov.get('tool', 'lesmc')} {prov.get('tool_version', '?')}"),
        ("date", prov.get("date", "?")),
        ("command", " ".join(prov.get("command", []))),
        ("seeds", ", ".join(f"{k} {v}" for k, v in prov.get("seeds", {}).items()) or "-"),
    ]
    for design, h in prov.get("model_sha256", {}).items():
        rows.append((f"model sha256 ({design})", h))
    t = "".join(f"<tr><th>{_e(k)}</th><td>{_e(v)}</td></tr>" for k, v in rows)
    timings = doc.get("timings", {})
    tt = "".join(f"<tr><th>{_e(k)}</th><td>{v:.3f} s</td></tr>" for k, v in timings.items())
    per = "".join(
        f"<tr><th>{_e(run['design'])} · {_e(r['property'])}</th>"
        f"<td>{r['stats']['seconds']:.3f} s ({_e(r['stats']['engine'])}, "
        f"{r['stats']['states_expanded']} states expanded)</td></tr>"
        for run in doc["runs"]
        for r in run["results"]
    )
    return (
        "<h2 id='provenance'>Provenance and timings</h2>"
        f"<table class='meta'>{t}</table><h3>Timings</h3><table class='meta'>{tt}{per}</table>"
    )


_CSS = """
body{font-family:system-ui,Segoe UI,Helvetica,Arial,sans-serif;margin:2em auto;max-width:1150px;
color:#222;line-height:1.4;padding:0 1em}
h1{font-size:1.6em}h2{border-bottom:2px solid #ddd;padding-bottom:.2em;margin-top:1.6em}
table{border-collapse:collapse;margin:.6em 0;font-size:.85em}
td,th{border:1px solid #ccc;padding:.25em .5em;text-align:right}th{background:#f4f4f4}
td:nth-child(2){text-align:left}td.obs{white-space:nowrap}
.holds{color:#1a7f37;font-weight:bold}.violated{color:#c62828;font-weight:bold}
.holds--vacuous-{color:#00838f;font-weight:bold;font-style:italic}
.violated--not-replayed-{color:#ad1457;font-weight:bold;font-style:italic}
.unknown{color:#b26a00;font-weight:bold}tr.original{background:#e8f5e9}tr.counterexample{background:#fdecea}
tr.witness{background:#e3ecf9}
figure{display:inline-block;margin:.8em;vertical-align:top;max-width:100%}
figure img{max-width:100%;height:auto;border:1px solid #ddd}\n.scroll{overflow-x:auto}
figcaption{font-size:.85em;color:#555;max-width:640px}
.note{color:#8a6d3b;font-size:.9em}table.meta th,table.meta td{text-align:left}
pre{background:#f7f7f7;border:1px solid #ddd;padding:.6em;font-size:.85em;overflow-x:auto}
nav ol{columns:2}
"""


def _page(body: list[str], figs: dict[str, bytes]) -> str:
    text = "".join(body).replace("<table", "<div class='scroll'><table")
    text = text.replace("</table>", "</table></div>")
    for name, png in figs.items():  # drawn at 2x: shown at half the natural size, sharp
        w, h = int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")
        text = text.replace(
            f"'@@{name}@@'",
            f"'data:image/png;base64,{base64.b64encode(png).decode()}' "
            f"width='{w // 2}' height='{h // 2}'",
        )
    return (
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
        "<title>lesmc verification report</title>"
        f"<style>{_CSS}</style></head><body>{text}</body></html>\n"
    )
