"""Which detections an attack can hide: the probe behind on-demand certification.

A certified check (docs/semantics.md, "Payoff intervals") needs a certified
lower bound only for the detections whose payoffs enter a combined payoff
(Eq. 5) of the model it checks. :func:`priced_detections` finds them by
unfolding the model once with every payoff of the window's frames finite
and noting which the tracker design reads.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import replace

import numpy as np

from lesmc.model.growing import GrowingModel
from lesmc.scene import Detection, Scene, WatchedFrame
from lesmc.unfold.unfold import build_model


def priced_detections(
    scene: Scene,
    window: tuple[int, int],
    end: int | None = None,
    on_batch: Callable[[GrowingModel], None] | None = None,
    reads: dict[int, set[int]] | None = None,
    max_states: int | None = None,
) -> dict[int, np.ndarray]:
    """Per frame step, the detections whose payoffs the model of ``scene`` attacked in
    ``window`` reads: a superset of those one of its attacks can hide.

    ``reads`` (empty; filled as the model grows): what was read so far, should
    ``on_batch`` stop the build by raising (``max_states``: the limit it enforces,
    so that batches shrink near it, as in :func:`build_model`).

    Only the window's frames count: an attack at step k hides detections of
    frame ``target.step + k``, and outside the window no transition has a
    cheaper sibling whose payoff could enter a combined payoff (Eq. 5). The
    model is built once over a copy of the scene in which those frames' payoffs
    are all finite (an attack could hide every candidate) and each notes the
    entries of its payoff column the design reads (:class:`WatchedFrame`). Any
    other use of the column counts as reading all of it. ``verify --payoffs
    certified|interval`` certifies only these (a detection without a bound gets
    the trivial 0 anyway, so a missed one costs tightness, never soundness).
    """
    first, last = scene.target.step + window[0], scene.target.step + window[1]
    reads = {} if reads is None else reads
    reads.update({f.step: set() for f in scene.frames if first <= f.step <= last})
    frames = tuple(
        WatchedFrame(
            f.step, _finite(f.detections), f.to_next, None, reads[f.step], candidates=f.candidates
        )
        if f.step in reads
        else f
        for f in scene.frames
    )
    build_model(
        replace(scene, frames=frames), window, end, on_batch=on_batch, max_states=max_states
    )
    return {k: np.array(sorted(v), dtype=np.int64) for k, v in reads.items() if v}


def merged_detections(sets: Iterable[Mapping[int, np.ndarray]]) -> dict[int, np.ndarray]:
    """The union, per frame step, of several :func:`priced_detections` answers (sorted)."""
    union: dict[int, set[int]] = {}
    for found in sets:
        for k, dets in found.items():
            union.setdefault(k, set()).update(dets.tolist())
    return {k: np.array(sorted(v), dtype=np.int64) for k, v in sorted(union.items())}


def _finite(dets: tuple[Detection, ...]) -> tuple[Detection, ...]:
    """The detections, every one attackable (payoff 1): the probe's frames."""
    return tuple(replace(d, payoff=1.0) for d in dets)
