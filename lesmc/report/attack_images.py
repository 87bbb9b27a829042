"""The perturbations of one design's section of the verification report
(lesmc/report/html.py, lesmc/report/design_section.py): the detections an attack hides, the
perturbed frames and crops, and the replay of a counterexample through the real detector.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from lesmc.common.numbers import fmt
from lesmc.report import figures
from lesmc.report.figure_cache import FigureSet
from lesmc.report.figures import ImageFor
from lesmc.report.pages import Cell, Figure, Markup, Text, para, table
from lesmc.report.run_view import RunView, number
from lesmc.results.read import HiddenEntry
from lesmc.results.result_doc import Perturbation


def patches(run: RunView, figs: FigureSet, image_for: ImageFor | None, payoffs: str) -> list[Any]:
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
            if lo is not None and math.isfinite(number(up)) and number(up) > 0:
                tight = f"{number(lo) / number(up):.2f}"
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


def _patch_figures(
    run: RunView,
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
    run: RunView, triples: list[tuple[str, np.ndarray, np.ndarray]], figs: FigureSet
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


def _replay_lines(run: RunView) -> list[Text]:
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
        elif rp.on_frames is not None and rp.on_frames.violated:
            text = Markup(
                "<b>diverged</b>{} at step {}: {}; but the replayed run is real: {}, and the "
                "verdict is violated"
            ).format(how, rp.step, rp.reason, rp.on_frames.why)
        else:
            text = Markup(
                "<b>diverged</b>{} at step {}: {}; the "
                "counterexample is no proof of violation and the verdict is unknown{}"
            ).format(
                how, rp.step, rp.reason, "" if rp.on_frames is None else f" ({rp.on_frames.why})"
            )
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
