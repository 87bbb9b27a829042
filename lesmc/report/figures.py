"""The report's figures (matplotlib, no display needed): the paper's Figures 6-10.

Every function draws one figure from plain arrays (read from a results file)
and returns PNG bytes at twice the usual resolution. One colour scheme holds in
every figure: each *role* has its colour (:data:`COLOURS`), each property its
marker (:data:`MARKERS`), so a legend entry names both and no two look alike.
"""

from __future__ import annotations

import io
import itertools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

#: One colour per role, in every figure and in the report's text.
COLOURS = {
    "original": "#1a9850",  # green, as in the paper
    "counterexample": "#d73027",  # red
    "cheapest": "#984ea3",  # purple: the cheapest path that breaks a property that holds
    "witness": "#4575b4",  # blue
    "truth": "#111111",  # black
    "other": "#b0b0b0",  # grey: the remaining attacked tracks
    "window": "#fee08b",  # the attack window's band
    "detections": "#ffbf00",  # amber rings
}
#: One line style per role.
STYLES = {"original": "-", "counterexample": "--", "witness": "-", "truth": ":", "other": "-"}
STYLES["cheapest"] = "--"
#: What the tree's legend calls each role.
ROLE_WORDS = {
    "original": "original",
    "counterexample": "counterexample",
    "cheapest": "cheapest path breaking a property that holds (not a counterexample)",
    "witness": "witness",
}
#: ``frame index -> grey image`` (None past the video's end): the frames the report's
#: image figures draw on (lesmc/report/publish.py's frame_reader makes one).
ImageFor = Callable[[int], np.ndarray | None]
#: One marker per property (by its index in the run).
MARKERS = ["o", "s", "^", "D", "v", "P"]
DPI = 200


@dataclass(frozen=True)
class Series:
    """One drawn path: its label, role (colour), property index (marker), values per step."""

    label: str
    role: str
    values: np.ndarray  # per step k = 0..; inf/nan where there is none
    prop: int | None = None
    alarms: tuple[int, ...] = ()
    number: int | None = None  # Table 3's row

    @property
    def colour(self) -> str:
        return COLOURS[self.role]

    @property
    def marker(self) -> str:
        return "o" if self.prop is None else MARKERS[self.prop % len(MARKERS)]


def pyplot() -> Any:
    """matplotlib's pyplot on the Agg backend (no display), imported with the first figure
    drawn: a report whose figures all come from a cache does not pay its 0.6 s of imports."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def png(fig: Figure) -> bytes:
    """The figure as PNG at :data:`DPI`, cropped to what is drawn (``bbox_inches="tight"``).

    savefig's "tight" first draws the whole figure, drawing disabled, to lay it out;
    none of these figures has a layout engine, so the box is found here without that
    pass, at the output's resolution as savefig would: the same bytes (tests/test_report.py)
    in 0.83-0.96x the time (benchmarks/bench_figures.py)."""
    from matplotlib import rcParams

    buf = io.BytesIO()
    fig.set_dpi(DPI)
    renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]  # Agg's canvas
    box = fig.get_tightbbox(renderer).padded(rcParams["savefig.pad_inches"])
    # zlib level 1: a third of the encoding time of the default 6, files within 5%
    fig.savefig(buf, format="png", dpi=DPI, bbox_inches=box, pil_kwargs={"compress_level": 1})
    pyplot().close(fig)
    return buf.getvalue()


def _steps_axis(ax: Axes, window: tuple[int, int]) -> None:
    from matplotlib.ticker import MaxNLocator

    ax.xaxis.set_major_locator(MaxNLocator(integer=True, nbins=12, min_n_ticks=2))
    ax.axvspan(window[0] - 0.5, window[1] + 0.5, color=COLOURS["window"], alpha=0.45, zorder=0)
    ax.set_xlabel("step k")


def _plot(ax: Axes, s: Series, ks: np.ndarray, ys: np.ndarray) -> None:
    ax.plot(
        ks,
        ys,
        STYLES[s.role],
        color=s.colour,
        lw=5.0 if s.role == "original" else 1.8,
        alpha=0.55 if s.role == "original" else 1.0,
        marker=s.marker,
        ms=4,
        mfc="white" if s.role in ("counterexample", "cheapest") else s.colour,
        label=s.label,
        zorder=4 if s.role in ("counterexample", "cheapest") else 3,
    )


def square_view(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A square view (at least 160 px) around ``points`` with a 40 px margin: (lo, hi) corners."""
    lo, hi = points.min(axis=0) - 40, points.max(axis=0) + 40
    size = max(float((hi - lo).max()), 160.0)
    centre = (lo + hi) / 2
    return centre - size / 2, centre + size / 2


def image_crop(ax: Axes, image: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> None:
    """Draw the part of the grey ``image`` inside the view [lo, hi] in pixel coordinates."""
    h, w = image.shape[:2]
    x0, y0 = int(max(lo[0], 0)), int(max(lo[1], 0))
    x1, y1 = int(min(hi[0], w)), int(min(hi[1], h))
    if x1 > x0 and y1 > y0:
        ax.imshow(
            image[y0:y1, x0:x1],
            cmap="gray",
            vmin=0,
            vmax=255,
            extent=(x0 - 0.5, x1 - 0.5, y1 - 0.5, y0 - 0.5),
            interpolation="nearest",
        )


def track_crop(
    tracks: Sequence[tuple[Series, np.ndarray]],
    ref_step: int,
    frame: int,
    detections: np.ndarray | None = None,
    truth: np.ndarray | None = None,
    image: np.ndarray | None = None,
    title: str = "",
) -> bytes:
    """Tracks in the frame of ``ref_step`` (Figures 6-8): image crop, detections, truth, paths.

    ``tracks`` pairs each series with its (n, 2) positions, already in that frame's pixels.
    """
    fig, ax = pyplot().subplots(figsize=(6.0, 6.0))
    pts_all = [p for _, p in tracks] + ([truth] if truth is not None else [])
    lo, hi = square_view(np.concatenate([p[np.isfinite(p).all(axis=1)] for p in pts_all]))
    if image is not None:
        image_crop(ax, image, lo, hi)
    if detections is not None and len(detections):
        ax.scatter(
            detections[:, 0],
            detections[:, 1],
            s=60,
            facecolors="none",
            edgecolors=COLOURS["detections"],
            linewidths=1.4,
            label=f"detections of step {ref_step} (frame {frame})",
            zorder=2,
        )
    if truth is not None:
        ok = np.isfinite(truth).all(axis=1)
        ax.plot(
            truth[ok, 0],
            truth[ok, 1],
            ":",
            color=COLOURS["truth"],
            lw=1.6,
            marker="x",
            ms=4,
            label="ground truth of the target",
            zorder=3,
        )
    for s, pts in tracks:
        _plot(ax, s, pts[:, 0], pts[:, 1])
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(hi[1], lo[1])
    ax.set_aspect("equal")
    ax.set_xlabel(f"x (pixels of frame {frame})")
    ax.set_ylabel("y (pixels)")
    ax.set_title(title, fontsize=10)
    ax.legend(loc="upper left", fontsize=8, framealpha=0.9)
    return png(fig)


def deviation(
    series: Sequence[Series],
    bound: float | None,
    cumulative: bool,
    window: tuple[int, int],
    title: str,
) -> bytes:
    """dist.at(k) per step (and the running sum) against the threshold (Figure 7c-d)."""
    n = 2 if cumulative else 1
    fig, axes = pyplot().subplots(1, n, figsize=(5.4 * n, 3.6), squeeze=False)
    ax = axes[0][0]
    for s in series:
        ks = np.arange(len(s.values))
        finite = np.isfinite(s.values)
        _plot(ax, s, ks[finite], s.values[finite])
        if (~finite).any():
            ax.axvline(ks[~finite][0], color=s.colour, ls=":", lw=1)
    if bound is not None and not cumulative:
        ax.axhline(bound, color="k", ls="-.", lw=1, label=f"threshold {bound:g}")
    _steps_axis(ax, window)
    ax.set_ylabel("deviation dist.at(k) (pixels)")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=8)
    if cumulative:
        ax2 = axes[0][1]
        for s in series:
            c = np.cumsum(np.where(np.isfinite(s.values), s.values, np.nan))
            _plot(ax2, s, np.arange(len(c)), c)
        if bound is not None:
            ax2.axhline(bound, color="k", ls="-.", lw=1, label=f"threshold {bound:g}")
        _steps_axis(ax2, window)
        ax2.set_ylabel("accumulated deviation (pixels)")
        ax2.legend(fontsize=8)
    return png(fig)


def uncertainty(series: Sequence[Series], window: tuple[int, int]) -> bytes:
    """τ = tr(P_ll) per step with the monitor's alarms, Eq. 12-13 (Figure 10)."""
    fig, ax = pyplot().subplots(figsize=(7.0, 3.8))
    for s in series:
        ks = np.arange(len(s.values))
        ok = np.isfinite(s.values)
        _plot(ax, s, ks[ok], s.values[ok])
        al = [k for k in s.alarms if k < len(s.values) and np.isfinite(s.values[k])]
        if al:
            ax.scatter(al, s.values[al], marker="x", s=90, color=s.colour, zorder=6, linewidths=2)
    ax.scatter([], [], marker="x", s=60, color="k", label="× monitor alarm (Eq. 13)")
    _steps_axis(ax, window)
    ax.set_yscale("log")
    ax.set_ylabel("τ = trace of P over (x, y), px²")
    ax.set_title("Bayesian uncertainty τ (Eq. 12) and the monitor's alarms", fontsize=9)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return png(fig)


@dataclass
class TreePath:
    """A path of the tree figure: its Table 3 number, states and node labels per step."""

    number: int
    states: tuple[str, ...]
    labels: tuple[str, ...]
    role: str = "other"
    tags: list[str] = field(default_factory=list)


def tree_columns(paths: Sequence[TreePath], start: int) -> list[int]:
    """The steps drawn: ``start``, every step at which some drawn path branches, the last.

    Steps at which no path branches are compressed into one gap between columns.
    """
    last = max(len(p.states) for p in paths) - 1
    cols = [start]
    for k in range(start + 1, last + 1):
        before = {p.states[:k] for p in paths if len(p.states) >= k}
        after = {p.states[: k + 1] for p in paths if len(p.states) > k}
        if len(after) > len(before):
            cols.append(k)
    if cols[-1] != last:
        cols.append(last)
    return cols


def tree(
    paths: Sequence[TreePath],
    total: int,
    window: tuple[int, int],
) -> bytes:
    """The tree of attacked paths (Figure 9c): leaves numbered as Table 3, quiet steps compressed.

    ``paths`` are in tree order (sorted by their states), which is Table 3's numbering.
    """
    start = max(window[0] - 1, 0)
    cols = tree_columns(paths, start)
    xcol = {k: i for i, k in enumerate(cols)}
    y_leaf = {p.number: float(i) for i, p in enumerate(paths)}
    acc: dict[tuple[str, ...], list[float]] = {}
    for p in paths:
        for k in cols:
            if k < len(p.states):
                acc.setdefault(p.states[: k + 1], []).append(y_leaf[p.number])

    def y(prefix: tuple[str, ...]) -> float:
        return float(np.mean(acc[prefix]))

    fig_h = max(3.2, 0.36 * len(paths) + 1.4)
    fig, ax = pyplot().subplots(figsize=(2.0 + 1.5 * len(cols), fig_h))
    seen_edges: set[tuple[tuple[str, ...], tuple[str, ...]]] = set()
    labelled: set[tuple[str, ...]] = set()
    legend_roles: dict[str, str] = {}
    longest = max(len(q.states) for q in paths)
    for p in sorted(paths, key=lambda p: p.role != "other"):  # roles drawn on top
        drawn_cols = [k for k in cols if k < len(p.states)]
        _draw_track(ax, p, drawn_cols, xcol, y, seen_edges, labelled)
        if p.role != "other":
            legend_roles.setdefault(p.role, p.role)
        _leaf_tag(ax, p, xcol[drawn_cols[-1]] + 0.35, y_leaf[p.number], len(p.states) < longest)
    for role, words in ROLE_WORDS.items():
        if role in legend_roles:
            ax.plot([], [], STYLES[role], color=COLOURS[role], lw=2.2, label=words)
    ax.plot([], [], ":", color="#777777", lw=1, label="steps without branching (compressed)")
    _tree_axes(ax, cols, xcol, window, len(paths))
    left = total - len(paths)
    note = f"{len(paths)} of {total} attacked tracks" + (f", {left} not drawn" if left else "")
    ax.set_title(f"attacked tracks from step {start} ({note}); #n = row n of Table 3", fontsize=10)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.14), fontsize=8, ncol=4)
    return png(fig)


def _leaf_tag(ax: Axes, p: TreePath, x: float, y: float, halted: bool) -> None:
    """The label at a leaf of the tree: ``#n``, the path's tags, and whether it halted."""
    tag = f"#{p.number}" + (f"  {'; '.join(p.tags)}" if p.tags else "")
    if halted:
        tag += "  (halted)"
    ax.text(
        x,
        y,
        tag,
        fontsize=8.5,
        ha="left",
        va="center",
        color=COLOURS[p.role] if p.role != "other" else "#333333",
        fontweight="bold" if p.role != "other" else "normal",
    )


def _tree_axes(
    ax: Axes, cols: list[int], xcol: dict[int, int], window: tuple[int, int], n_paths: int
) -> None:
    """The tree's axes: shaded attack window, one tick per drawn step, no y axis."""
    lo = [xcol[k] for k in cols if window[0] <= k <= window[1]]
    if lo:
        ax.axvspan(min(lo) - 0.45, max(lo) + 0.45, color=COLOURS["window"], alpha=0.45, zorder=0)
    ax.set_xticks(range(len(cols)), [str(k) for k in cols])
    ax.set_xlim(-0.6, len(cols) - 0.2 + 1.4)
    ax.set_ylim(n_paths - 0.5, -0.5)
    ax.set_yticks([])
    ax.set_xlabel("step k (attack window shaded); node: detection taken (none: no observation)")
    for side in ("top", "right", "left"):
        ax.spines[side].set_visible(False)


def _draw_track(
    ax: Axes,
    p: TreePath,
    drawn_cols: list[int],
    xcol: dict[int, int],
    y: Callable[[tuple[str, ...]], float],
    seen_edges: set[tuple[tuple[str, ...], tuple[str, ...]]],
    labelled: set[tuple[str, ...]],
) -> None:
    """One track of the tree: its edges (each once, roles on top) and its nodes' labels."""
    for a, b in itertools.pairwise(drawn_cols):
        pa, pb = p.states[: a + 1], p.states[: b + 1]
        if (pa, pb) in seen_edges and p.role == "other":
            continue
        seen_edges.add((pa, pb))
        gap = b - a > 1
        ax.plot(
            [xcol[a], xcol[b]],
            [y(pa), y(pb)],
            ":" if gap else STYLES[p.role],
            color=COLOURS[p.role],
            lw=1.0 if p.role == "other" else 2.2,
            zorder=1 if p.role == "other" else 2,
        )
    for k in drawn_cols:
        node = p.states[: k + 1]
        if node in labelled:
            continue
        labelled.add(node)
        ax.text(
            xcol[k],
            y(node),
            p.labels[k].split("-", 1)[1] if "-" in p.labels[k] else p.labels[k],
            fontsize=8,
            ha="center",
            va="center",
            zorder=5,
            bbox={"boxstyle": "round,pad=0.2", "fc": "white", "ec": "#888888", "lw": 0.5},
        )


#: The side of the N_dr window a hidden detection's patch shows (docs/cnn.md).
WINDOW = 21


def patch(image: np.ndarray, centre: tuple[float, float], half: int = WINDOW // 2) -> np.ndarray:
    """The (2·half+1)² patch of a frame around a detection, zero-padded at the border."""
    side = 2 * half + 1
    return crop(image, round(centre[0]) - half, round(centre[1]) - half, side, side)


def crop(image: np.ndarray, left: int, top: int, width: int, height: int) -> np.ndarray:
    """The ``width`` x ``height`` crop of a frame at (``left``, ``top``), zero-padded where it
    leaves the frame."""
    h, w = image.shape[:2]
    out = np.zeros((height, width), dtype=float)
    y0, y1 = max(top, 0), min(top + height, h)
    x0, x1 = max(left, 0), min(left + width, w)
    if y1 > y0 and x1 > x0:
        out[y0 - top : y1 - top, x0 - left : x1 - left] = image[y0:y1, x0:x1]
    return out


def patches(rows: Sequence[tuple[str, np.ndarray]]) -> bytes:
    """The original patches of the detections an attack hides, one per column, with titles."""
    n = len(rows)
    fig, axes = pyplot().subplots(1, n, figsize=(1.6 * n + 0.4, 2.0), squeeze=False)
    for ax, (title, img) in zip(axes[0], rows, strict=True):
        ax.imshow(img, cmap="gray", vmin=0, vmax=255, interpolation="nearest")
        ax.set_title(title, fontsize=7)
        ax.set_xticks([])
        ax.set_yticks([])
    return png(fig)


def amplification(delta: np.ndarray) -> tuple[float, float]:
    """A perturbation's (pixel scale [0, 1]) largest change in grey levels, and the factor
    :func:`perturbations` draws it amplified by (1: none): so that it spans about 64 levels."""
    peak = float(np.abs(delta * 255.0).max())
    return peak, (float(max(1, round(64.0 / peak))) if peak > 0 else 1.0)


def perturbations(rows: Sequence[tuple[str, np.ndarray, np.ndarray]]) -> bytes:
    """Per hidden detection: original patch (grey levels), perturbation (pixel scale [0, 1]) and
    attacked patch. Each perturbation has its own diverging colour scale spanning its largest
    change, amplified (×k in its title, :func:`amplification`) when that change is under 64
    grey levels, so that small ones stay visible."""
    n = len(rows)
    fig, axes = pyplot().subplots(n, 3, figsize=(5.4, 1.9 * n + 0.3), squeeze=False)
    for (title, orig, delta), ax in zip(rows, axes, strict=True):
        grey = delta * 255.0
        peak, gain = amplification(delta)
        span = max(peak * gain, 1.0)
        attacked = np.clip(orig + grey, 0, 255)
        ax[0].imshow(orig, cmap="gray", vmin=0, vmax=255, interpolation="nearest")
        ax[1].imshow(grey * gain, cmap="RdBu_r", vmin=-span, vmax=span, interpolation="nearest")
        ax[2].imshow(attacked, cmap="gray", vmin=0, vmax=255, interpolation="nearest")
        ax[0].set_ylabel(title.replace(", ", "\n", 1), fontsize=7)
        middle = f"perturbation ×{gain:.0f}" if gain > 1 else "perturbation"
        middle += f"\n(±{peak:.1f} grey levels)"
        for a, t in zip(ax, ("original", middle, "attacked"), strict=True):
            a.set_title(t, fontsize=7)
            a.set_xticks([])
            a.set_yticks([])
    return png(fig)


@dataclass(frozen=True)
class SweepCurve:
    """One property's optimum for each value of a swept parameter (``--sweep``), with its
    threshold and each value's verdict word."""

    label: str
    parameter: str
    values: tuple[float, ...]
    optima: tuple[float, ...]  # +inf: no path violates
    threshold: float
    verdicts: tuple[str, ...]


#: The colour of each verdict word in the sweep figure.
VERDICT_COLOURS = {"holds": COLOURS["original"], "violated": COLOURS["counterexample"]}


def sweep(curves: Sequence[SweepCurve]) -> bytes:
    """Section 4.4's sensitivity: the optimum against the swept ε (or the norm p), the
    threshold dashed, each point coloured by its verdict, a dotted line where it flips.
    +inf (no violating path) is drawn at the top edge with an upward triangle."""
    fig, ax = pyplot().subplots(figsize=(7.0, 3.8))
    finite = [y for c in curves for y in c.optima if np.isfinite(y)]
    finite += [c.threshold for c in curves]
    top = max(finite) * 1.15 + 1e-9 if finite else 1.0
    categorical = any(c.parameter == "p" for c in curves)
    for i, c in enumerate(curves):
        xs = np.arange(len(c.values)) if categorical else np.asarray(c.values, dtype=float)
        ys = np.array([y if np.isfinite(y) else top for y in c.optima])
        marker = MARKERS[i % len(MARKERS)]
        ax.step(xs, ys, where="post", color="#555555", linewidth=1.2, label=c.label)
        for x, y, v, opt in zip(xs, ys, c.verdicts, c.optima, strict=True):
            colour = VERDICT_COLOURS.get(v.split(" ")[0], COLOURS["other"])
            ax.scatter(
                [x],
                [y],
                color=colour,
                marker="^" if not np.isfinite(opt) else marker,
                s=36,
                zorder=5,
            )
        for a, b, va, vb in zip(xs[:-1], xs[1:], c.verdicts[:-1], c.verdicts[1:], strict=True):
            if va.split(" ")[0] != vb.split(" ")[0]:
                ax.axvline((a + b) / 2, color=COLOURS["counterexample"], linestyle=":", lw=1)
        ax.axhline(c.threshold, color="#000000", linestyle="--", linewidth=0.8)
    if categorical:
        ax.set_xticks(range(len(curves[0].values)))
        ax.set_xticklabels(["inf" if np.isinf(v) else f"{v:g}" for v in curves[0].values])
    ax.set_xlabel(curves[0].parameter if curves else "")
    ax.set_ylabel("optimum")
    for word, colour in VERDICT_COLOURS.items():
        ax.scatter([], [], color=colour, label=word)
    ax.scatter([], [], color=COLOURS["other"], label="unknown")
    ax.scatter([], [], color="#555555", marker="^", label="+inf (no path breaks it)")
    ax.plot([], [], color="#000000", linestyle="--", lw=0.8, label="threshold")
    ax.plot([], [], color=COLOURS["counterexample"], linestyle=":", lw=1, label="verdict flips")
    ax.set_title("Sensitivity (section 4.4): the optimum against the swept parameter", fontsize=9)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return png(fig)
