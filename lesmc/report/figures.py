"""The report's figures (matplotlib, no display needed): the paper's Figures 6-10.

Every function draws one figure from a run and returns PNG bytes.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from dataclasses import dataclass

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure

from lesmc.model.kernel import DEFAULT_TOLERANCE, alarm
from lesmc.model.lts import LTS
from lesmc.report.paths import TrackPath, position, tau_series
from lesmc.tracking.kalman import warp
from lesmc.tracking.scene import Scene

ORIGINAL = "#1a9850"  # green, as in the paper
PALETTE = ["#d73027", "#4575b4", "#984ea3", "#ff7f00"]  # red, blue, ...


@dataclass(frozen=True)
class Drawn:
    """A path to draw: what it is, its colour and line style."""

    path: TrackPath
    label: str
    color: str
    dashed: bool = False


def _png(fig: Figure) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()


def _to_step(scene: Scene, first: int, end: int, ref: int) -> list[np.ndarray]:
    """Homographies from each model step k = 0..end's frame pixels to step ``ref``'s."""
    nxt: list[np.ndarray] = []
    for k in range(end):
        m = scene.frame(first + k).to_next
        nxt.append(np.eye(3) if m is None else m)
    out = [np.eye(3)] * (end + 1)
    for k in range(ref - 1, -1, -1):  # earlier steps: forward through to_next
        out[k] = out[k + 1] @ nxt[k]
    for k in range(ref + 1, end + 1):  # later steps: backward
        out[k] = out[k - 1] @ np.linalg.inv(nxt[k - 1])
    return out


def track_crop(
    model: LTS,
    drawn: Sequence[Drawn],
    ref_step: int,
    scene: Scene | None = None,
    image: np.ndarray | None = None,
    title: str = "",
) -> bytes:
    """Tracks over the frame of ``ref_step`` (Figures 6-8): image crop, detections, paths."""
    first = int(model.meta.get("first_frame", 0))
    fig, ax = plt.subplots(figsize=(6.4, 6.4))
    to_ref = _to_step(scene, first, model.end, ref_step) if scene is not None else None
    tracks = []
    for d in drawn:
        pts = np.array([position(model, q) for q in d.path.states])
        if to_ref is not None:
            pts = np.array([warp(to_ref[k], p) for k, p in enumerate(pts)])
        tracks.append(pts)
    allpts = np.concatenate(tracks)
    lo, hi = allpts.min(axis=0) - 40, allpts.max(axis=0) + 40
    size = max(float((hi - lo).max()), 160.0)
    centre = (lo + hi) / 2
    lo, hi = centre - size / 2, centre + size / 2
    if image is not None:
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
    if scene is not None and first + ref_step <= scene.last_step:
        det = scene.frame(first + ref_step).positions()
        if len(det):
            ax.scatter(
                det[:, 0],
                det[:, 1],
                s=40,
                facecolors="none",
                edgecolors="#ffd92f",
                linewidths=1.0,
                label=f"detections (frame {first + ref_step})",
                zorder=3,
            )
    for d, pts in zip(drawn, tracks, strict=True):
        ax.plot(
            pts[:, 0],
            pts[:, 1],
            "--" if d.dashed else "-",
            color=d.color,
            lw=2,
            marker="o",
            ms=3,
            label=d.label,
            zorder=4,
        )
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(hi[1], lo[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x (pixels)")
    ax.set_ylabel("y (pixels)")
    ax.set_title(title or f"tracks in the frame of step {ref_step}")
    ax.legend(loc="upper left", fontsize=7, framealpha=0.85)
    return _png(fig)


def tree(
    paths: Sequence[TrackPath],
    highlight: Sequence[Drawn],
    total: int,
    window: tuple[int, int],
    max_leaves: int = 40,
) -> tuple[bytes, int]:
    """The tree of attacked paths (Figure 9c), nodes "step-detection"; returns (png, drawn)."""
    merged: dict[tuple[str, ...], Drawn] = {}
    for d in highlight:  # one path may play several roles: one line, joined labels
        if d.path.states in merged:
            m = merged[d.path.states]
            merged[d.path.states] = Drawn(m.path, f"{m.label}; {d.label}", m.color, m.dashed)
        else:
            merged[d.path.states] = d
    highlight = list(merged.values())
    keep = set(merged)
    chosen = [d.path for d in highlight]
    for p in paths:
        if len(chosen) >= max_leaves:
            break
        if p.states not in keep:
            chosen.append(p)
            keep.add(p.states)
    chosen.sort(key=lambda p: p.states)
    l, _ = window
    start = max(l - 1, 0)
    ypos: dict[tuple[str, ...], float] = {}
    for i, p in enumerate(chosen):
        ypos[p.states] = float(i)
    # internal node y = mean of its leaves' y
    acc: dict[tuple[str, ...], list[float]] = {}
    for p in chosen:
        for k in range(start, len(p.states) + 1):
            acc.setdefault(p.states[:k], []).append(ypos[p.states])
    fig_h = max(3.0, 0.22 * len(chosen) + 1.5)
    fig, ax = plt.subplots(figsize=(11, fig_h))
    colour = {d.path.states: d for d in highlight}
    drawn_edges: set[tuple[tuple[str, ...], tuple[str, ...]]] = set()
    for p in chosen:
        labels = p.labels()
        for k in range(start + 1, len(p.states)):
            a, b = p.states[:k], p.states[: k + 1]
            if (a, b) in drawn_edges:
                continue
            drawn_edges.add((a, b))
            ya, yb = float(np.mean(acc[a])), float(np.mean(acc[b]))
            ax.plot([k - 1, k], [ya, yb], color="#bbbbbb", lw=0.8, zorder=1)
            if k <= window[1] + 1 or k == len(p.states) - 1:
                ax.text(
                    k,
                    yb,
                    labels[k],
                    fontsize=6,
                    ha="center",
                    va="bottom",
                    zorder=3,
                    bbox={"boxstyle": "round,pad=0.1", "fc": "white", "ec": "none", "alpha": 0.7},
                )
    for states, d in colour.items():
        ys = [float(np.mean(acc[states[: k + 1]])) for k in range(start, len(states))]
        ax.plot(
            range(start, len(states)),
            ys,
            "--" if d.dashed else "-",
            color=d.color,
            lw=2.2,
            label=d.label,
            zorder=2,
        )
    ax.axvspan(
        window[0] - 0.5,
        window[1] + 0.5,
        color="#fee08b",
        alpha=0.35,
        zorder=0,
        label=f"attack window {window[0]}..{window[1]}",
    )
    ax.set_yticks([])
    ax.set_xlabel("step k")
    left = total - len(chosen)
    note = f"{len(chosen)} of {total} paths drawn" + (f", {left} left out" if left else "")
    ax.set_title(f"all attacked paths from step {start} ({note})")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7, framealpha=0.85)
    return _png(fig), len(chosen)


def deviation(
    series: Sequence[tuple[str, str, bool, np.ndarray]],
    bound: float | None,
    cumulative: bool,
    window: tuple[int, int],
    title: str,
) -> bytes:
    """dist.at(k) per step (and the running sum) against the threshold (Figure 7c-d)."""
    fig, axes = plt.subplots(
        1, 2 if cumulative else 1, figsize=(10 if cumulative else 6, 3.6), squeeze=False
    )
    ax = axes[0][0]
    for label, color, dashed, d in series:
        ks = np.arange(len(d))
        finite = np.isfinite(d)
        ax.plot(
            ks[finite],
            d[finite],
            "--" if dashed else "-",
            color=color,
            marker="o",
            ms=3,
            label=label,
        )
        if (~finite).any():
            ax.axvline(ks[~finite][0], color=color, ls=":", lw=1)
    if bound is not None and not cumulative:
        ax.axhline(bound, color="k", ls="--", lw=1, label=f"threshold {bound:g}")
    ax.axvspan(window[0] - 0.5, window[1] + 0.5, color="#fee08b", alpha=0.35)
    ax.set_xlabel("step k")
    ax.set_ylabel("deviation dist.at(k)")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7)
    if cumulative:
        ax2 = axes[0][1]
        for label, color, dashed, d in series:
            c = np.cumsum(np.where(np.isfinite(d), d, np.nan))
            ax2.plot(
                np.arange(len(d)),
                c,
                "--" if dashed else "-",
                color=color,
                marker="o",
                ms=3,
                label=label,
            )
        if bound is not None:
            ax2.axhline(bound, color="k", ls="--", lw=1, label=f"threshold {bound:g}")
        ax2.set_xlabel("step k")
        ax2.set_ylabel("accumulated deviation")
        ax2.legend(fontsize=7)
    return _png(fig)


def uncertainty(
    model: LTS,
    drawn: Sequence[Drawn],
    window: tuple[int, int],
    tolerance: float = DEFAULT_TOLERANCE,
) -> bytes:
    """τ = tr(P_ll) per step with the monitor's alarms, Eq. 12-13 (Figure 10)."""
    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    for d in drawn:
        tau = tau_series(model, d.path)
        ks = np.arange(len(tau))
        ax.plot(ks, tau, "--" if d.dashed else "-", color=d.color, marker="o", ms=3, label=d.label)
        ks_on = np.arange(max(window[0], 1), len(tau))
        rise = ks_on[alarm(tau[ks_on - 1], tau[ks_on], tolerance)]
        if len(rise):
            ax.scatter(rise, tau[rise], marker="x", s=70, color=d.color, zorder=5)
    ax.axvspan(window[0] - 0.5, window[1] + 0.5, color="#fee08b", alpha=0.35)
    ax.set_yscale("log")
    ax.set_xlabel("step k")
    ax.set_ylabel("τ = trace of P (location), px²")
    ax.set_title("Bayesian uncertainty; × = monitor alarm (τ rises, Eq. 13)", fontsize=9)
    ax.legend(fontsize=7)
    return _png(fig)
