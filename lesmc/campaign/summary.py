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
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from lesmc.common.files import atomic_write_text
from lesmc.common.numbers import fmt
from lesmc.designs import registry
from lesmc.engines.result import status_word
from lesmc.report.pages import Figure, Markup, Table, images, render_page, table

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


def _target_text(t: dict[str, Any]) -> str:
    return f"{t['x']:.2f},{t['y']:.2f}@{t['step']}"


def command(row: dict[str, Any], scenes: str) -> str:
    """The ``lesmc verify`` line that reproduces ``row``."""
    w = row["window"]
    return (
        f"lesmc verify --scene {scenes}/{row['video']}.json --target {_target_text(row['target'])}"
        f" --window {w[0]}..{w[1]} --design {row['design']}"
        + (f" --payoffs {row['payoffs']}" if "payoffs" in row else "")
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


def summarise(rows: list[dict[str, Any]], scenes: str) -> dict[str, Any]:
    """Every number of the summary (``lesmc campaign --json``)."""
    by: dict[tuple[str, str], list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        by[(r["design"], r["property"])].append(r)
    present = {k[0] for k in by}
    designs = [d for d in registry.names() if d in present] + sorted(
        present - set(registry.names())
    )
    props = sorted({k[1] for k in by})
    cells: dict[str, dict[str, Any]] = {}
    for d in designs:
        cells[d] = {}
        for p in props:
            cells[d][p] = _cell(by.get((d, p), []), scenes)
    return {
        "format": FORMAT,
        "version": VERSION,
        "rows": len(rows),
        "payoffs": rows[0].get("payoffs", "attack") if rows else "attack",
        "videos": sorted({r["video"] for r in rows}),
        "targets": len({(r["video"], _target_text(r["target"])) for r in rows}),
        "windows": len({tuple(r["window"]) for r in rows}),
        "designs": designs,
        "properties": props,
        "cells": cells,
        "improvements": improvements(rows, props),
    }


def _cell(rs: list[dict[str, Any]], scenes: str) -> dict[str, Any]:
    """One design's rows of one property: the counts of each verdict word, the optima, the
    fraction violated by window length, and the worst cases with their commands."""
    statuses = Counter(_status(r) for r in rs)
    optima = [v for r in rs if (v := _value(r["optimum"])) is not None]
    lengths: dict[int, list[int]] = defaultdict(lambda: [0, 0])
    for r in rs:
        n = r["window"][1] - r["window"][0] + 1
        lengths[n][0] += 1
        lengths[n][1] += r["verdict"] == "violated"
    frames = [r["attacked_frames"] for r in rs if r.get("attacked_frames") is not None]
    by_count = all(r.get("objective_source") == "frames" for r in rs)
    worst = sorted(
        (r for r in rs if r["verdict"] == "violated" and _value(r["optimum"]) is not None),
        key=lambda r: (_value(r["optimum"]), r["video"], r["key"]),
    )[:WORST]
    return {
        "rows": len(rs),
        "holds": statuses.get("holds", 0),  # a vacuous holds is not one
        "vacuous": statuses.get("holds (vacuous)", 0),
        "violated": statuses.get("violated", 0),
        "not_replayed": statuses.get("violated (not replayed)", 0),
        "unknown": statuses.get("unknown", 0),
        "optimum_quantiles": quantiles(optima) if optima else None,
        # the fewest frames an attacker must touch: exact when the property minimises
        # count.frames (its optimum), else the frames of the cheapest attacks found
        "fewest_frames": min(frames, default=None),
        "fewest_frames_exact": by_count and bool(frames),
        "optima": ["inf" if math.isinf(x) else x for x in sorted(optima)],
        "violated_by_window_length": {
            str(n): {"rows": c[0], "violated": c[1], "fraction": c[1] / c[0]}
            for n, c in sorted(lengths.items())
        },
        "worst": [
            {
                "video": r["video"],
                "target": r["target"],
                "window": r["window"],
                "optimum": r["optimum"],
                "command": command(r, scenes),
            }
            for r in worst
        ],
    }


#: Colours of the designs in the figures, in registry order (the paper's three first).
PALETTE = ("#d73027", "#4575b4", "#1a9850", "#984ea3", "#ff7f00", "#a65628", "#f781bf")


def design_colours(designs: Sequence[str]) -> dict[str, str]:
    """A colour per design, stable across campaigns (by the registry's order)."""
    order = [*registry.names(), *sorted(set(designs) - set(registry.names()))]
    return {d: PALETTE[order.index(d) % len(PALETTE)] for d in designs}


def _status(row: dict[str, Any]) -> str:
    """The row's verdict word (lesmc.engines.result.status_word)."""
    replay = "not replayed" if row.get("status") == "violated (not replayed)" else None
    return status_word(row["verdict"], bool(row.get("vacuous", False)), replay)


def improvements(rows: list[dict[str, Any]], props: list[str]) -> dict[str, Any]:
    """Table 5 over many tracks: per property, the (target, window) pairs violated by the
    plain tracker, and for each other design how many of them it removes and adds.

    A vacuous 'holds' (the monitor flags the unattacked track too) removes nothing:
    it is counted apart, as ``vacuous``."""
    verdict: dict[tuple[str, str, str, tuple[int, int], str], str] = {}
    for r in rows:
        case = (r["property"], r["video"], _target_text(r["target"]), tuple(r["window"]))
        word = _status(r)
        verdict[(*case, r["design"])] = "vacuous" if word == "holds (vacuous)" else r["verdict"]
    base = registry.BASELINE
    others = [d for d in dict.fromkeys(k[4] for k in verdict) if d != base]
    out: dict[str, Any] = {}
    for p in props:
        cases = {k[:4] for k in verdict if k[0] == p and k[4] == base}
        base_bad = {c for c in cases if verdict[(*c, base)] == "violated"}
        per: dict[str, Any] = {}
        for d in others:
            both = {c for c in cases if (*c, d) in verdict}
            if not both:
                continue
            per[d] = {
                "compared": len(both),
                "removed": sum(verdict[(*c, d)] == "holds" for c in both & base_bad),
                "vacuous": sum(verdict[(*c, d)] == "vacuous" for c in both & base_bad),
                "still_violated": sum(verdict[(*c, d)] == "violated" for c in both & base_bad),
                "added": sum(
                    verdict[(*c, d)] == "violated" and verdict[(*c, base)] == "holds" for c in both
                ),
            }
        out[p] = {
            "baseline": base,
            "baseline_violated": len(base_bad),
            "cases": len(cases),
            "designs": per,
        }
    return out


# ------------------------------------------------------------------ figures


def figures(summary: dict[str, Any]) -> dict[str, bytes]:
    """PNG figures: one ECDF of the optima per property, the fraction violated per length."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = design_colours(summary["designs"])
    out: dict[str, bytes] = {}
    for p in summary["properties"]:
        fig, ax = plt.subplots(figsize=(6, 3.6))
        finite_max = 0.0
        for d in summary["designs"]:
            vals = [x for x in summary["cells"][d][p]["optima"] if x != "inf"]
            finite_max = max([finite_max, *vals])
        for d in summary["designs"]:
            opt = summary["cells"][d][p]["optima"]
            if not opt:
                continue
            n = len(opt)
            xs = [x for x in opt if x != "inf"]
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
        1, len(summary["properties"]), figsize=(5 * len(summary["properties"]), 3.4), squeeze=False
    )
    for ax, p in zip(axes[0], summary["properties"], strict=True):
        for d in summary["designs"]:
            by = summary["cells"][d][p]["violated_by_window_length"]
            xs = [int(n) for n in by]
            ax.plot(
                xs,
                [by[str(n)]["fraction"] for n in xs],
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


def cell_rows(summary: dict[str, Any], quantile_keys: tuple[str, ...]) -> list[list[str]]:
    """One row per (design, property) cell: the counts of ``CELL_HEADER``, then
    the optimum's quantiles named by ``quantile_keys`` ("-" when no optimum)."""
    rows = []
    for d in summary["designs"]:
        for p in summary["properties"]:
            c = summary["cells"][d][p]
            q = c["optimum_quantiles"] or {}
            counts = (
                c["rows"],
                c["holds"],
                c["vacuous"],
                c["violated"],
                c["not_replayed"],
                c["unknown"],
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


def _frames_text(cell: dict[str, Any]) -> str:
    """The cell's fewest attacked frames: exact (a count.frames objective's optimum) or,
    marked ≤, those of the cheapest counterexamples (a bound on the fewest)."""
    n = cell.get("fewest_frames")
    if n is None:
        return "-"
    return str(n) if cell.get("fewest_frames_exact") else f"≤ {n}"


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


def write_html(
    summary: dict[str, Any], figs: dict[str, bytes], out: Path, meta: dict[str, str]
) -> Path:
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
        design_labels=[registry.label(d) for d in s["designs"]],
        payoff_text=Markup(PAYOFF_TEXT.get(s["payoffs"], "")),
        cells=table(head, cell_rows(s, QUANTILE_KEYS)),
        ecdfs=[
            Figure(f"ecdf_{p}", f"Distribution of the {p} optimum over targets and windows.")
            for p in s["properties"]
            if f"ecdf_{p}" in figs
        ],
        by_length=[
            Figure(
                "violated_by_length", "Fraction of (target, window) pairs violated, by u - l + 1."
            )
        ]
        if "violated_by_length" in figs
        else [],
        improvements=_improvements_table(s["improvements"]),
        worst=_worst_table(s),
        images=images(figs),
    )
    path = out / "campaign.html"
    atomic_write_text(path, page)
    return path


def _improvements_table(improvements: dict[str, Any]) -> Table:
    """Per property and design: what the design removes of the baseline's violations."""
    rows = [
        [
            p,
            registry.label(d),
            imp["baseline_violated"],
            v["removed"],
            v["vacuous"],
            v["still_violated"],
            v["added"],
        ]
        for p, imp in improvements.items()
        for d, v in imp["designs"].items()
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


def _worst_table(summary: dict[str, Any]) -> Table:
    """The cheapest violations of each design and property, with the command that redoes one."""
    rows = [
        [registry.label(d), p, fmt(w["optimum"]), Markup("<code>{}</code>").format(w["command"])]
        for d in summary["designs"]
        for p in summary["properties"]
        for w in summary["cells"][d][p]["worst"]
    ]
    return table(["design", "property", "optimum", "reproduce with"], rows)
