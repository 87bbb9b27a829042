"""The report of a multi-target design (``sort``, ``gnn``), drawn from a ``lesmc-multi-check``
document alone (``lesmc verify --design sort``'s results.json, or ``lesmc check --design
sort --json``'s output): nothing is checked again.

Per property: its verdict and optimum (for a check stopped by its budget, the bounds it
proved and its notes), and for its counterexample one panel per step
drawing every track of the attacked run (its box and id; a point design's position),
the target's track thick, the target's reference box dotted, the detections hidden
(red, crossed) and the candidates injected (green); the panel of a step where the
target's id switches is titled SWITCH. A table lists each step's target id, switch,
hidden and injected detections and every track's id and status. All of it is in the
document (version 2: lesmc/pipeline/multi_tracks.py); a version 1 document has no
tracks, and its report lists the steps without panels. The path of a check stopped by its
budget whose verdict is not ``violated`` is only the best attack found, and is labelled so.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from html import escape
from pathlib import Path
from typing import Any

import numpy as np

from lesmc.common.numbers import fmt
from lesmc.report.figures import COLOURS, ImageFor, png, pyplot, square_view
from lesmc.report.pages import (
    Figure,
    Markup,
    Text,
    images,
    key_values,
    para,
    render_page,
    table,
)
from lesmc.report.staging import staged

#: At most this many steps get a panel (the attacked steps and those after them first).
MAX_PANELS = 12
#: A step's tracks are all listed in its table row up to this many (else those drawn).
MAX_LISTED = 40
#: The switch marker on the page and on the panels.
SWITCH = "SWITCH"


def write_multi_report(
    doc: dict[str, Any],
    out_dir: str | Path,
    image_for: ImageFor | None = None,
    files: dict[str, str] | None = None,
) -> Path:
    """Write report.html, figures/*.png, results.json (``doc``) and ``files`` into
    ``out_dir``, staged as :func:`lesmc.report.html.write_report` writes them."""
    page, figs = render_multi(doc, image_for)
    with staged(out_dir) as tmp:
        for name, text in (files or {}).items():
            (tmp / name).write_text(text, encoding="utf-8")
        (tmp / "figures").mkdir()
        for name, data in figs.items():
            (tmp / "figures" / name).write_bytes(data)
        (tmp / "results.json").write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n")
        (tmp / "report.html").write_text(page, encoding="utf-8")
    return Path(out_dir) / "report.html"


def render_multi(
    doc: dict[str, Any], image_for: ImageFor | None = None
) -> tuple[str, dict[str, bytes]]:
    """The page and its figures by file name."""
    design = str(doc["design"])
    figs: dict[str, bytes] = {}
    drawn: dict[str, str] = {}
    sections = []
    for i, r in enumerate(doc["results"]):
        parts: list[Any] = [para(_verdict_line(r))]
        if r.get("notes"):
            parts.append(Text("ul", items=list(r["notes"])))
        steps = r.get("counterexample") or []
        views = _views(steps) if steps and "tracks" in steps[0] else None
        if views is not None:
            key = json.dumps(steps, sort_keys=True)  # one drawing for equal counterexamples
            if key not in drawn:
                drawn[key] = f"multi_{i}_{_tag(r['property'])}.png"
                figs[drawn[key]] = track_panels(steps, image_for)
            parts.append(Figure(drawn[key], _caption(r)))
        if steps:
            parts.append(_steps_table(steps, views))
        sections.append({"name": r["property"], "tag": _tag(r["property"]), "parts": parts})
    meta = [("design", design), ("target's reference", doc["reference"])]
    meta += [(k, _text(v)) for k, v in (doc.get("meta") or {}).items()]
    meta += [(f"{k} (s)", fmt(v)) for k, v in (doc.get("timings") or {}).items()]
    page = render_page(
        "multi.html.j2",
        design=design,
        meta=key_values(meta),
        verdicts=_verdicts(doc["results"]),
        sections=sections,
        legend=_legend(),
        images=images(figs, scale=2),
    )
    return page, figs


def _tag(name: str) -> str:
    return "".join(ch if ch.isalnum() else "-" for ch in name)


def _text(v: Any) -> str:
    return ", ".join(map(str, v)) if isinstance(v, list) else str(v)


def _opt(x: Any) -> str:
    return "inf" if x is None else fmt(float(x)) if not isinstance(x, str) else x


def _verdict_line(r: dict[str, Any]) -> Markup:
    word = r["verdict"]
    return Markup(
        f"<span class='{word}'>{word}</span>: optimum {_opt(r['optimum'])}"
        f"{escape(bounds_text(r))}, constraint's measure "
        f"{_opt(r['constraint_value'])} ({r['states']} states, "
        f"{r['transitions']} transitions)" + escape(replay_text(r.get("replay")))
    )


def bounds_text(r: dict[str, Any]) -> str:
    """What a result stopped by its budget proved (``stopped``, ``bounds``: the schema's
    lesmc-multi-check), as a parenthesis after its optimum; empty for a finished check."""
    b = r.get("bounds")
    if not isinstance(b, dict):
        return ""
    return (
        f" (stopped by {r.get('stopped', 'a budget')}; the optimum lies between "
        f"{_opt(b['lower'])} and {_opt(b['upper'])})"
    )


def _path_name(r: dict[str, Any]) -> str:
    """What a result's path is: a counterexample when violated; the best attack found by a
    check its budget stopped (``bounds`` given) before it decided; else the optimal attack
    of a property that holds. Only the first is a counterexample."""
    if r["verdict"] == "violated":
        return "the counterexample"
    return "the best attack found" if "bounds" in r else "the optimal attack"


def replay_text(rp: Any) -> str:
    """What the replay of a result's counterexample found (lesmc/replay/multi.py), as a
    clause after its verdict; empty when it was not replayed."""
    if not isinstance(rp, dict):
        return ""
    if rp.get("status") == "confirmed":
        return "; replay: confirmed on the real frames"
    return f"; replay: diverged at step {rp.get('step')} ({rp.get('reason')})"


def _verdicts(results: Sequence[dict[str, Any]]) -> Any:
    rows = [
        [
            r["property"],
            r["verdict"],
            _opt(r["optimum"]) + bounds_text(r),
            _opt(r["constraint_value"]),
            r["states"],
            r["transitions"],
            ", ".join(str(s["step"]) for s in r.get("counterexample") or () if s.get("switch"))
            or "-",
        ]
        for r in results
    ]
    head = ["property", "verdict", "optimum", "constraint", "states", "transitions", "switch at"]
    return table(head, rows)


def _caption(r: dict[str, Any]) -> str:
    label = _path_name(r)
    why = "" if label == "the counterexample" else f" {label.capitalize()} is not a counterexample."
    if "bounds" in r and r["verdict"] != "violated":
        why += f" The check did not finish{bounds_text(r)}."
    return (
        f"{r['property']}: every track of the attacked run of {label}, step by step "
        "(ids beside the boxes); the target's track thick, its reference dotted, hidden "
        f"detections crossed in red, injected ones green; {SWITCH}: the target's id changes." + why
    )


def _steps_table(
    steps: Sequence[dict[str, Any]], views: list[tuple[np.ndarray, np.ndarray]] | None
) -> Any:
    """Each step's target id, switch, hidden and injected detections and tracks: every
    track when a step has at most :data:`MAX_LISTED`, else those in its panel's view
    (``views``, one per step) and how many others."""
    rows = []
    for k, s in enumerate(steps):
        listed = list(s.get("tracks", ()))
        if len(listed) > MAX_LISTED and views is not None:
            view = views[k]
            listed = [t for t in listed if _in_view(t.get("box") or t["position"], *view)]
        tracks = " ".join(f"{t['id']}:{t['status'][:4]}" for t in listed)
        if len(listed) < len(s.get("tracks", ())):
            tracks += f" (and {len(s['tracks']) - len(listed)} outside the panels)"
        rows.append(
            [
                s["step"],
                s["frame"],
                "-" if s["target_id"] is None else s["target_id"],
                SWITCH if s.get("switch") else "",
                ", ".join(s["hidden"]) or "-",
                ", ".join(s["injected"]) or "-",
                tracks or "-",
            ]
        )
    head = ["step", "frame", "target id", "switch", "hidden", "injected", "tracks (id:status)"]
    return table(head, rows)


def _legend() -> list[tuple[str, str]]:
    return [
        (COLOURS["counterexample"], "the target's track (thick), hidden detections (crossed)"),
        (COLOURS["other"], "other tracks"),
        (COLOURS["truth"], "the target's reference (dotted)"),
        (COLOURS["original"], "injected candidates"),
    ]


def _shown(steps: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """The steps drawn: from the step before the first attacked one, at most
    :data:`MAX_PANELS` (every switch step kept)."""
    attacked = [i for i, s in enumerate(steps) if s["hidden"] or s["injected"]]
    first = max(0, (attacked[0] if attacked else 0) - 1)
    out = list(steps[first : first + MAX_PANELS])
    out += [s for s in steps[first + MAX_PANELS :] if s.get("switch")]
    return out


def _corners(row: Sequence[float]) -> np.ndarray:
    """A box's (or a position's) corners as a (2, 2) array."""
    v = np.asarray(row, dtype=float)
    return v.reshape(2, 2) if len(v) == 4 else np.vstack([v, v])


def _in_view(row: Sequence[float], lo: np.ndarray, hi: np.ndarray) -> bool:
    """A box (or position) meets the view [lo, hi]."""
    c = _corners(row)
    return bool((c[1] >= lo).all() and (c[0] <= hi).all())


def _views(steps: Sequence[dict[str, Any]]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each step's view: a square (at least 160 px, figures' ``square_view``) around its
    reference box, the target's track and the attacked detections; a step with none of
    them keeps the previous step's view (the first such: around all its tracks). Each
    frame of a video is in its own pixel coordinates, so each step has its own."""
    out: list[tuple[np.ndarray, np.ndarray]] = []
    for s in steps:
        pts = [_corners(s["reference"])] if s.get("reference") is not None else []
        pts += [_corners(a.get("box") or a["position"]) for a in s["attacked"]]
        pts += [
            _corners(t.get("box") or t["position"])
            for t in s["tracks"]
            if t["id"] == s["target_id"]
        ]
        if not pts and out:
            out.append(out[-1])
            continue
        if not pts:
            pts = [_corners(t.get("box") or t["position"]) for t in s["tracks"]]
        out.append(square_view(np.vstack(pts)) if pts else (np.zeros(2), np.full(2, 160.0)))
    return out


def track_panels(steps: Sequence[dict[str, Any]], image_for: ImageFor | None = None) -> bytes:
    """One panel per shown step (:func:`_shown`) of a counterexample: every track's box
    (or position) and id, the target's track thick, the reference dotted, hidden
    detections crossed, injected ones green, SWITCH in the title of a switch step."""
    plt = pyplot()
    shown = _shown(steps)
    views = _views(steps)
    at = {s["step"]: i for i, s in enumerate(steps)}
    cols = min(4, len(shown))
    rows = (len(shown) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(2.6 * cols, 2.7 * rows), squeeze=False)
    for ax in axes.flat[len(shown) :]:
        ax.set_axis_off()
    for ax, s in zip(axes.flat, shown, strict=False):
        _panel(ax, s, *views[at[s["step"]]], image_for)
    fig.subplots_adjust(wspace=0.08, hspace=0.25)
    return png(fig)


def _panel(
    ax: Any, s: dict[str, Any], lo: np.ndarray, hi: np.ndarray, image_for: ImageFor | None
) -> None:
    from matplotlib.patches import Rectangle

    image = image_for(int(s["frame"])) if image_for is not None else None
    if image is not None:
        from lesmc.report.figures import image_crop

        image_crop(ax, image, lo, hi)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(hi[1], lo[1])  # image rows grow downwards
    ax.set_xticks([])
    ax.set_yticks([])

    def outline(row: Sequence[float], **kw: Any) -> None:
        c = _corners(row)
        if np.allclose(c[0], c[1]):
            ax.plot([c[0, 0]], [c[0, 1]], "o", ms=5, mfc="none", **kw)
        else:
            ax.add_patch(Rectangle(tuple(c[0]), *(c[1] - c[0]), fill=False, **kw))

    if s.get("reference") is not None:
        outline(s["reference"], color=COLOURS["truth"], ls=":", lw=1.2)
    for t in s["tracks"]:
        place = t.get("box") or t["position"]
        if not _in_view(place, lo, hi):  # hundreds on a video frame: only those seen
            continue
        mine = t["id"] == s["target_id"]
        colour = COLOURS["counterexample"] if mine else COLOURS["other"]
        outline(
            place,
            color=colour,
            lw=2.4 if mine else 0.9,
            ls="-" if t["status"] == "confirmed" else "--",
        )
        c = _corners(place)
        if lo[0] <= c[0, 0] <= hi[0] and lo[1] <= c[0, 1] <= hi[1]:
            ax.text(c[0, 0], c[0, 1] - 1, str(t["id"]), color=colour, fontsize=6, clip_on=True)
    for a in s["attacked"]:
        c = _corners(a.get("box") or a["position"])
        mid = c.mean(axis=0)
        hidden = a["action"] == "hidden"
        colour = COLOURS["counterexample"] if hidden else COLOURS["original"]
        outline(a.get("box") or a["position"], color=colour, ls="--", lw=1.0)
        ax.plot([mid[0]], [mid[1]], "x" if hidden else "+", color=colour, ms=7, mew=1.8)
    title = f"step {s['step']} (frame {s['frame']}): id {s['target_id'] or '-'}"
    if s.get("switch"):
        title += f" {SWITCH}"
    ax.set_title(title, fontsize=7, color=COLOURS["counterexample"] if s.get("switch") else "k")
