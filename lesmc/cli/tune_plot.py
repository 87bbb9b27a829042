"""``lesmc tune --plot``: each property's optimum against the false-alarm rate, the Pareto
front highlighted (the one module of ``tune`` that imports matplotlib)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from lesmc.experiment.tune import Outcome


def draw(outcomes: Sequence[Outcome], budget: float, path: str) -> None:
    """One panel per property: x the false alarms per step, y the optimum (a verified attack
    cost or deviation); the front's designs in colour and joined, the others grey,
    ``holds if``'s threshold and the budget dashed; designs with nothing verified
    (unknown, vacuous) are counted in the panel's title, not drawn. Written atomically."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from lesmc.common.files import atomic_open

    props = [r.property for r in outcomes[0].results] if outcomes else []
    fig, axes = plt.subplots(1, max(len(props), 1), figsize=(5.5 * max(len(props), 1), 4.2))
    axes_list = list(axes) if len(props) > 1 else [axes]
    for k, (ax, name) in enumerate(zip(axes_list, props, strict=False)):
        shown = [
            (o.rate, o.results[k].optimum, o.front)
            for o in outcomes
            if o.results[k].optimum is not None
            and o.results[k].optimum_known
            and not o.results[k].vacuous
        ]
        thr = outcomes[0].results[k].threshold
        finite = [y for _, y, _ in shown if y is not None and math.isfinite(y)] + [thr]
        top = max(finite) * 1.15 if max(finite) > 0 else 1.0  # where +inf is drawn
        pts = [(x, top if y is None or math.isinf(y) else y, f) for x, y, f in shown]
        rest = [(x, y) for x, y, f in pts if not f]
        front = sorted((x, y) for x, y, f in pts if f)
        if rest:
            ax.scatter(*zip(*rest, strict=True), c="0.65", s=18, label="designs")
        if front:
            ax.plot(*zip(*front, strict=True), "o-", c="tab:red", ms=6, label="Pareto front")
        ax.axhline(thr, ls="--", c="tab:blue", lw=1, label=f"holds if > {thr:g}")
        ax.axvline(budget, ls=":", c="k", lw=1, label=f"budget {budget:.1%}")
        hidden = len(outcomes) - len(shown)
        ax.set_title(name + (f" ({hidden} unknown or vacuous not drawn)" if hidden else ""))
        ax.set_xlabel("false alarms per step (unattacked tracks)")
        ax.set_ylabel("optimum (inf drawn at the top)")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fmt = path.rsplit(".", 1)[-1].lower()  # png, svg or pdf (lesmc/cli/tune.py checks)
    with atomic_open(path, binary=True) as fh:
        fig.savefig(fh, format=fmt)
    plt.close(fig)
