"""A campaign's statistics, read from its rows (never re-checked): numbers, figures, HTML.

* per design and property, the distribution (ECDF) of the optima over targets
  and windows: robustness' cheapest attack payoff, resilience's smallest
  deviation that is not recovered from (+inf: no attacked path violates);
* the fraction violated per window length u − l + 1;
* the paper's Table 5 as statistics: of the (target, window) pairs where the
  plain tracker is violated (an adversarial track exists), how many each
  improved design removes (holds there, not vacuously), how many hold only
  vacuously (the monitor flags the unattacked track too), and how many it adds;
* the worst cases, each with the ``lesmc verify`` command that reproduces it.
"""

from __future__ import annotations

import io
import math
from collections import Counter, defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lesmc.common.files import atomic_write_text
from lesmc.common.numbers import fmt
from lesmc.designs import registry
from lesmc.engines.result import status_word
from lesmc.report.pages import Figure, Markup, Table, images, render_page, table
from lesmc.results.campaign_row import CampaignRow, Target, read_row

FORMAT = "lesmc-campaign-summary"
VERSION = 2
#: Worst cases listed per (design, property).
WORST = 5


def _value(x: Any) -> float | None:
    """A row's number: floats, "inf" for +inf, None for unknown."""
    if isinstance(x, int | float) and not isinstance(x, bool):
        return float(x)
    if x == "inf":
        return math.inf
    return None


def _target_text(t: Target) -> str:
    return f"{t.x:.2f},{t.y:.2f}@{t.step}"


def command(row: CampaignRow, scenes: str) -> str:
    """The ``lesmc verify`` line that reproduces ``row``."""
    w = row.window
    return (
        f"lesmc verify --scene {scenes}/{row.video}.json --target {_target_text(row.target)}"
        f" --window {w[0]}..{w[1]} --design {row.design}"
        + (f" --payoffs {row.payoffs}" if row.payoffs is not None else "")
    )


def quantiles(values: Sequence[float]) -> dict[str, float | str]:
    """Min, quartiles, 90th percentile and max ("inf" where infinite), by the nearest rank."""
    v = sorted(values)
    out: dict[str, float | str] = {}
    for name, q in (
        ("min", 0),
        ("p25", 25),
        ("median", 50),
        ("p75", 75),
        ("p90", 90),
        ("max", 100),
    ):
        x = v[min(len(v) - 1, max(0, math.ceil(q / 100 * len(v)) - 1))]
        out[name] = "inf" if math.isinf(x) else round(x, 6)
    return out


@dataclass(frozen=True)
class LengthCount:
    """The rows of one window length u - l + 1, and how many of them are violated."""

    rows: int
    violated: int

    @property
    def fraction(self) -> float:
        """The fraction violated."""
        return self.violated / self.rows


@dataclass(frozen=True)
class Worst:
    """One of the cheapest violations of a cell, with the command that redoes it."""

    row: CampaignRow
    command: str

    def to_dict(self) -> dict[str, Any]:
        """As the summary document writes it."""
        r = self.row
        return {
            "video": r.video,
            "target": r.target.to_dict(),
            "window": list(r.window),
            "optimum": r.optimum,
            "command": self.command,
        }


@dataclass(frozen=True)
class Cell:
    """One design's rows of one property: the counts of each verdict word, the optima, the
    fraction violated by window length, and the worst cases. ``fewest_frames``: the fewest
    frames an attacker must touch: exact (``fewest_frames_exact``) when the property minimises
    count.frames (its optimum), else the frames of the cheapest attacks found."""

    rows: int
    holds: int
    vacuous: int
    violated: int
    not_replayed: int
    unknown: int
    optimum_quantiles: dict[str, float | str] | None
    fewest_frames: int | None
    fewest_frames_exact: bool
    optima: tuple[float, ...]
    by_length: dict[int, LengthCount]
    worst: tuple[Worst, ...]

    def to_dict(self) -> dict[str, Any]:
        """As the summary document writes it ("inf" for an infinite optimum)."""
        return {
            "rows": self.rows,
            "holds": self.holds,
            "vacuous": self.vacuous,
            "violated": self.violated,
            "not_replayed": self.not_replayed,
            "unknown": self.unknown,
            "optimum_quantiles": self.optimum_quantiles,
            "fewest_frames": self.fewest_frames,
            "fewest_frames_exact": self.fewest_frames_exact,
            "optima": ["inf" if math.isinf(x) else x for x in self.optima],
            "violated_by_window_length": {
                str(n): {"rows": c.rows, "violated": c.violated, "fraction": c.fraction}
                for n, c in self.by_length.items()
            },
            "worst": [w.to_dict() for w in self.worst],
        }


@dataclass(frozen=True)
class Change:
    """What one design does to the baseline's verdicts on the cases both were checked on."""

    compared: int
    removed: int
    vacuous: int
    still_violated: int
    added: int

    def to_dict(self) -> dict[str, Any]:
        """As the summary document writes it."""
        return {
            "compared": self.compared,
            "removed": self.removed,
            "vacuous": self.vacuous,
            "still_violated": self.still_violated,
            "added": self.added,
        }


@dataclass(frozen=True)
class Improvement:
    """One property's Table 5: the baseline's violated cases and each other design's change."""

    baseline: str
    baseline_violated: int
    cases: int
    designs: dict[str, Change]

    def to_dict(self) -> dict[str, Any]:
        """As the summary document writes it."""
        return {
            "baseline": self.baseline,
            "baseline_violated": self.baseline_violated,
            "cases": self.cases,
            "designs": {d: c.to_dict() for d, c in self.designs.items()},
        }


@dataclass(frozen=True)
class Summary:
    """Every number of a campaign's summary; :meth:`to_dict` is ``lesmc campaign --json``
    (lesmc/schemas/campaign-summary.json)."""

    rows: int
    payoffs: str
    videos: tuple[str, ...]
    targets: int
    windows: int
    designs: tuple[str, ...]
    properties: tuple[str, ...]
    cells: dict[tuple[str, str], Cell]
    improvements: dict[str, Improvement]

    def cell(self, design: str, prop: str) -> Cell:
        """The cell of ``design`` and ``prop``."""
        return self.cells[(design, prop)]

    def to_dict(self) -> dict[str, Any]:
        """The summary document."""
        return {
            "format": FORMAT,
            "version": VERSION,
            "rows": self.rows,
            "payoffs": self.payoffs,
            "videos": list(self.videos),
            "targets": self.targets,
            "windows": self.windows,
            "designs": list(self.designs),
            "properties": list(self.properties),
            "cells": {
                d: {p: self.cell(d, p).to_dict() for p in self.properties} for d in self.designs
            },
            "improvements": {p: i.to_dict() for p, i in self.improvements.items()},
        }


def summarise(documents: Sequence[Mapping[str, Any]], scenes: str) -> Summary:
    """Every number of the summary of the campaign rows ``documents`` (``results.jsonl``
    objects, read through lesmc.results.campaign_row.read_row)."""
    rows = [read_row(d) for d in documents]
    by: dict[tuple[str, str], list[CampaignRow]] = defaultdict(list)
    for r in rows:
        by[(r.design, r.property)].append(r)
    present = {k[0] for k in by}
    designs = [d for d in registry.names() if d in present] + sorted(
        present - set(registry.names())
    )
    props = sorted({k[1] for k in by})
    first = rows[0].payoffs if rows else None
    return Summary(
        rows=len(rows),
        payoffs=first if first is not None else "attack",
        videos=tuple(sorted({r.video for r in rows})),
        targets=len({(r.video, _target_text(r.target)) for r in rows}),
        windows=len({r.window for r in rows}),
        designs=tuple(designs),
        properties=tuple(props),
        cells={(d, p): _cell(by.get((d, p), []), scenes) for d in designs for p in props},
        improvements=improvements(rows, props),
    )


def _cell(rs: list[CampaignRow], scenes: str) -> Cell:
    """One design's rows of one property: the counts of each verdict word, the optima, the
    fraction violated by window length, and the worst cases with their commands."""
    statuses = Counter(_status(r) for r in rs)
    optima = [v for r in rs if (v := _value(r.optimum)) is not None]
    lengths: dict[int, list[int]] = defaultdict(lambda: [0, 0])
    for r in rs:
        n = r.window[1] - r.window[0] + 1
        lengths[n][0] += 1
        lengths[n][1] += r.verdict == "violated"
    frames = [r.attacked_frames for r in rs if r.attacked_frames is not None]
    by_count = all(r.objective_source == "frames" for r in rs)
    worst = sorted(
        (r for r in rs if r.verdict == "violated" and _value(r.optimum) is not None),
        key=lambda r: (_value(r.optimum), r.video, r.key),
    )[:WORST]
    return Cell(
        rows=len(rs),
        holds=statuses.get("holds", 0),  # a vacuous holds is not one
        vacuous=statuses.get("holds (vacuous)", 0),
        violated=statuses.get("violated", 0),
        not_replayed=statuses.get("violated (not replayed)", 0),
        unknown=statuses.get("unknown", 0),
        optimum_quantiles=quantiles(optima) if optima else None,
        fewest_frames=min(frames, default=None),
        fewest_frames_exact=by_count and bool(frames),
        optima=tuple(sorted(optima)),
        by_length={n: LengthCount(c[0], c[1]) for n, c in sorted(lengths.items())},
        worst=tuple(Worst(r, command(r, scenes)) for r in worst),
    )


#: Colours of the designs in the figures, in registry order (the paper's three first).
PALETTE = ("#d73027", "#4575b4", "#1a9850", "#984ea3", "#ff7f00", "#a65628", "#f781bf")


def design_colours(designs: Sequence[str]) -> dict[str, str]:
    """A colour per design, stable across campaigns (by the registry's order)."""
    order = [*registry.names(), *sorted(set(designs) - set(registry.names()))]
    return {d: PALETTE[order.index(d) % len(PALETTE)] for d in designs}


def _status(row: CampaignRow) -> str:
    """The row's verdict word (lesmc.engines.result.status_word)."""
    replay = "not replayed" if row.status == "violated (not replayed)" else None
    return status_word(row.verdict, row.vacuous, replay)


def improvements(rows: Sequence[CampaignRow], props: Sequence[str]) -> dict[str, Improvement]:
    """Table 5 over many tracks: per property, the (target, window) pairs violated by the
    plain tracker, and for each other design how many of them it removes and adds.

    A vacuous 'holds' (the monitor flags the unattacked track too) removes nothing:
    it is counted apart, as ``vacuous``."""
    verdict: dict[tuple[str, str, str, tuple[int, int], str], str] = {}
    for r in rows:
        case = (r.property, r.video, _target_text(r.target), r.window)
        word = _status(r)
        verdict[(*case, r.design)] = "vacuous" if word == "holds (vacuous)" else r.verdict
    base = registry.BASELINE
    others = [d for d in dict.fromkeys(k[4] for k in verdict) if d != base]
    out: dict[str, Improvement] = {}
    for p in props:
        cases = {k[:4] for k in verdict if k[0] == p and k[4] == base}
        base_bad = {c for c in cases if verdict[(*c, base)] == "violated"}
        per: dict[str, Change] = {}
        for d in others:
            both = {c for c in cases if (*c, d) in verdict}
            if not both:
                continue
            per[d] = Change(
                compared=len(both),
                removed=sum(verdict[(*c, d)] == "holds" for c in both & base_bad),
                vacuous=sum(verdict[(*c, d)] == "vacuous" for c in both & base_bad),
                still_violated=sum(verdict[(*c, d)] == "violated" for c in both & base_bad),
                added=sum(
                    verdict[(*c, d)] == "violated" and verdict[(*c, base)] == "holds" for c in both
                ),
            )
        out[p] = Improvement(
            baseline=base, baseline_violated=len(base_bad), cases=len(cases), designs=per
        )
    return out


# ------------------------------------------------------------------ figures


def figures(summary: Summary) -> dict[str, bytes]:
    """PNG figures: one ECDF of the optima per property, the fraction violated per length."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = design_colours(summary.designs)
    out: dict[str, bytes] = {}
    for p in summary.properties:
        fig, ax = plt.subplots(figsize=(6, 3.6))
        finite_max = 0.0
        for d in summary.designs:
            vals = [x for x in summary.cell(d, p).optima if not math.isinf(x)]
            finite_max = max([finite_max, *vals])
        for d in summary.designs:
            opt = summary.cell(d, p).optima
            if not opt:
                continue
            n = len(opt)
            xs = [x for x in opt if not math.isinf(x)]
            ys = [(i + 1) / n for i in range(len(xs))]
            ax.step([0.0, *xs], [0.0, *ys], where="post", color=colours[d], label=registry.label(d))
        ax.set_xlabel(f"{p} optimum (curves stop where the rest is +inf)")
        ax.set_ylabel("fraction of (target, window)")
        ax.set_ylim(0, 1.02)
        ax.set_xlim(0, finite_max * 1.05 if finite_max > 0 else 1)
        ax.legend(fontsize=8)
        ax.set_title(f"{p}: ECDF of the optimum")
        out[f"ecdf_{p}"] = _png(fig, plt)
    fig, axes = plt.subplots(
        1, len(summary.properties), figsize=(5 * len(summary.properties), 3.4), squeeze=False
    )
    for ax, p in zip(axes[0], summary.properties, strict=True):
        for d in summary.designs:
            by = summary.cell(d, p).by_length
            lens = list(by)
            ax.plot(
                lens,
                [by[n].fraction for n in lens],
                "o-",
                color=colours[d],
                label=registry.label(d),
            )
        ax.set_xlabel("window length u - l + 1")
        ax.set_ylabel("fraction violated")
        ax.set_ylim(-0.02, 1.02)
        ax.set_title(p)
        ax.legend(fontsize=8)
    out["violated_by_length"] = _png(fig, plt)
    return out


def _png(fig: Any, plt: Any) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()


# ------------------------------------------------------------------ html

#: The columns of a summary table: a vacuous holds and a violation not replayed through the
#: detector are counted apart from holds and violated (lesmc.engines.result.STATUSES).
CELL_HEADER = (
    "design",
    "property",
    "rows",
    "holds",
    "holds (vacuous)",
    "violated",
    "violated (not replayed)",
    "unknown",
    "fewest frames",
)
QUANTILE_KEYS = ("min", "p25", "median", "p75", "max")


def cell_rows(summary: Summary, quantile_keys: tuple[str, ...]) -> list[list[str]]:
    """One row per (design, property) cell: the counts of ``CELL_HEADER``, then
    the optimum's quantiles named by ``quantile_keys`` ("-" when no optimum)."""
    rows = []
    for d in summary.designs:
        for p in summary.properties:
            c = summary.cell(d, p)
            q = c.optimum_quantiles or {}
            counts = (
                c.rows,
                c.holds,
                c.vacuous,
                c.violated,
                c.not_replayed,
                c.unknown,
                _frames_text(c),
            )
            rows.append(
                [
                    registry.label(d),
                    p,
                    *map(str, counts),
                    *(fmt(q[k]) if k in q else "-" for k in quantile_keys),
                ]
            )
    return rows


def _frames_text(cell: Cell) -> str:
    """The cell's fewest attacked frames: exact (a count.frames objective's optimum) or,
    marked ≤, those of the cheapest counterexamples (a bound on the fewest)."""
    n = cell.fewest_frames
    if n is None:
        return "-"
    return str(n) if cell.fewest_frames_exact else f"≤ {n}"


#: What a verdict rests on, per payoff mode other than the attack's (docs/semantics.md).
PAYOFF_TEXT = {
    "certified": (
        "<p>Payoffs: the <b>certified lower bounds</b> (CROWN, docs/cnn.md) of the "
        "detections the models can hide, 0 for the others. A 'holds' is proven against "
        "every attack within the threat model; a 'violated' only says that the bounds "
        "do not prove it (no attack was run).</p>"
    ),
    "interval": (
        "<p>Payoffs: <b>intervals</b>. 'holds' is proven with the certified lower payoffs "
        "(against every attack within the threat model); 'violated' has the attack's "
        "counterexample, not replayed here (its row's command with --frames VIDEO_DIR "
        "replays it through the detector and tracker); 'unknown' lies "
        "in between, and its optimum, somewhere between the two optima of its row, enters "
        "no ECDF.</p>"
    ),
}


def write_html(summary: Summary, figs: dict[str, bytes], out: Path, meta: dict[str, str]) -> Path:
    """``DIR/campaign.html`` (self-contained; templates/campaign.html.j2) and
    ``DIR/figures/campaign_*.png``."""
    fig_dir = out / "figures"
    fig_dir.mkdir(parents=True, exist_ok=True)
    for name, png in figs.items():
        (fig_dir / f"campaign_{name}.png").write_bytes(png)
    s = summary
    head = [*CELL_HEADER, *(f"optimum {k}" for k in QUANTILE_KEYS)]
    page = render_page(
        "campaign.html.j2",
        s=s,
        run_table=table(["run", "value"], list(meta.items())),
        design_labels=[registry.label(d) for d in s.designs],
        payoff_text=Markup(PAYOFF_TEXT.get(s.payoffs, "")),
        cells=table(head, cell_rows(s, QUANTILE_KEYS)),
        ecdfs=[
            Figure(f"ecdf_{p}", f"Distribution of the {p} optimum over targets and windows.")
            for p in s.properties
            if f"ecdf_{p}" in figs
        ],
        by_length=[
            Figure(
                "violated_by_length", "Fraction of (target, window) pairs violated, by u - l + 1."
            )
        ]
        if "violated_by_length" in figs
        else [],
        improvements=_improvements_table(s.improvements),
        worst=_worst_table(s),
        images=images(figs),
    )
    path = out / "campaign.html"
    atomic_write_text(path, page)
    return path


def _improvements_table(improvements: dict[str, Improvement]) -> Table:
    """Per property and design: what the design removes of the baseline's violations."""
    rows = [
        [
            p,
            registry.label(d),
            imp.baseline_violated,
            v.removed,
            v.vacuous,
            v.still_violated,
            v.added,
        ]
        for p, imp in improvements.items()
        for d, v in imp.designs.items()
    ]
    head = [
        "property",
        "design",
        f"violated ({registry.label(registry.BASELINE)})",
        "removed",
        "holds only vacuously",
        "still violated",
        "added",
    ]
    return table(head, rows)


def _worst_table(summary: Summary) -> Table:
    """The cheapest violations of each design and property, with the command that redoes one."""
    rows = [
        [registry.label(d), p, fmt(w.row.optimum), Markup("<code>{}</code>").format(w.command)]
        for d in summary.designs
        for p in summary.properties
        for w in summary.cell(d, p).worst
    ]
    return table(["design", "property", "optimum", "reproduce with"], rows)
