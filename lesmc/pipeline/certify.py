"""On-demand certification: bound only the detections a check's models can hide.

A certified check (docs/semantics.md, "Payoff intervals") reads a certified
lower payoff only for the detections whose payoffs enter a combined payoff
(Eq. 5) of its model: those an attack in the window can hide. The probe
(lesmc/unfold/probe.py) finds them per (tracker, window); the caller's
certifier (perception's CROWN bounds, lesmc/perception/run.py) bounds those
that have no bound yet; a detection left without one counts as 0, the
trivial bound, and the check says how many its model can hide.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, replace
from typing import Any, TypeVar

import numpy as np

from lesmc.common.budget import Budget
from lesmc.pipeline.job import Certifier
from lesmc.scene import Footage, Frame, Scene
from lesmc.unfold.probe import merged_detections, priced_detections

S = TypeVar("S", Scene, Footage)

#: What the unbounded count of a window is when its probe stopped early.
PROBE_STOPPED = -1

#: The note of a check whose window's probe a budget stopped.
PROBE_STOPPED_NOTE = (
    "finding the detections this window's model can hide stopped at the budget "
    "(--max-states or --timeout): some may carry no certified bound and count as 0, the "
    "trivial bound (the certified optimum is sound but may be far below the true one)"
)


class _ProbeBudget(Exception):
    """The probe's model outgrew its budget."""


@dataclass(frozen=True)
class Probed:
    """What one probe found: per frame step the detections a model attacked in ``window``
    can hide, and whether it finished (a stopped probe keeps what it had read)."""

    window: tuple[int, int]
    found: dict[int, np.ndarray]
    finished: bool


def probe(scene: Scene, window: tuple[int, int], budget: Budget) -> Probed:
    """:func:`~lesmc.unfold.probe.priced_detections` within one check's share of ``budget``."""
    b = budget.for_check()

    def spent(model: Any) -> None:
        if b.exceeded(model.n_states) is not None:
            raise _ProbeBudget

    reads: dict[int, set[int]] = {}
    try:
        found = priced_detections(
            scene, window, on_batch=spent, reads=reads, max_states=b.max_states
        )
        return Probed(window, found, True)
    except _ProbeBudget:
        read = {k: np.array(sorted(v), dtype=np.int64) for k, v in reads.items() if v}
        return Probed(window, read, False)


def widest(windows: Iterable[tuple[int, int]]) -> list[tuple[int, int]]:
    """The windows that lie inside no other: probing them covers every window (a window's
    model reads a subset of what a wider window's reads)."""
    ws = set(windows)
    return sorted(w for w in ws if not any(o != w and o[0] <= w[0] and w[1] <= o[1] for o in ws))


def probe_all(scene: Scene, windows: Iterable[tuple[int, int]], budget: Budget) -> list[Probed]:
    """One probe per window of :func:`widest` (``scene``: with the tracker to probe)."""
    return [probe(scene, w, budget) for w in widest(windows)]


def without_bound(frames: Footage | Scene, dets: Mapping[int, Iterable[int]]) -> dict[int, Any]:
    """Per frame step, the given detections that carry no ``payoff_lower`` yet (sorted)."""
    out = {}
    for k, idx in sorted(dets.items()):
        frame = frames.frame(k)
        need = sorted(int(i) for i in idx if frame.detections[int(i)].payoff_lower is None)
        if need:
            out[k] = np.array(need, dtype=np.int64)
    return out


def unbounded(frames: Footage | Scene, probes: list[Probed], window: tuple[int, int]) -> int:
    """How many detections a model attacked in ``window`` can hide without a bound: the
    least over the finished probes of windows holding it (each found a superset), else
    :data:`PROBE_STOPPED`."""
    counts = [
        sum(map(len, without_bound(frames, p.found).values()))
        for p in probes
        if p.finished and p.window[0] <= window[0] and window[1] <= p.window[1]
    ]
    return min(counts) if counts else PROBE_STOPPED


def unbounded_note(n: int) -> list[str]:
    """The note of a certified check whose model can hide ``n`` detections without a bound."""
    if n == PROBE_STOPPED:
        return [PROBE_STOPPED_NOTE]
    if not n:
        return []
    return [
        f"{n} detection(s) the model can hide carry no certified bound (payoff_lower) and "
        "count as 0, the trivial bound: the certified optimum is sound but may be far "
        "below the true one"
    ]


def certify(
    scene: S, probes: Iterable[Probed], certifier: Certifier, scope: str, **extra: Any
) -> S:
    """``scene`` with certified lower payoffs for what the probes found and the scene does
    not bound yet, and ``meta.certified`` saying what was done."""
    started = time.monotonic()
    todo = without_bound(scene, merged_detections(p.found for p in probes))
    low = scene.with_lower(certifier(todo)) if todo else scene
    spent = time.monotonic() - started + float(scene.meta.get("certified", {}).get("seconds", 0))
    meta = certification_meta(low.frames, scope, spent, **extra)
    return replace(low, meta={**scene.meta, "certified": meta})


class MemoCertifier:
    """A certifier that certifies each detection once: later requests for it are answered
    from what it returned (the fault variants of one property ask for the same detections
    many times)."""

    def __init__(self, certifier: Certifier) -> None:
        self.certifier = certifier
        self.known: dict[int, np.ndarray] = {}  #: per frame step, every detection's bound

    def __call__(self, wanted: Mapping[int, np.ndarray]) -> dict[int, np.ndarray]:
        todo = {}
        for k, idx in wanted.items():
            have = self.known.get(k)
            new = [int(i) for i in idx if have is None or np.isnan(have[int(i)])]
            if new:
                todo[k] = np.array(new, dtype=np.int64)
        for k, got in (self.certifier(todo) if todo else {}).items():
            have = self.known.get(k)
            self.known[k] = got if have is None else np.where(np.isnan(got), have, got)
        return {k: self.known[k] for k in wanted if k in self.known}


def split_certifier(
    by_set: Mapping[frozenset[str] | None, Certifier], perceived: Mapping[int, frozenset[str]]
) -> Certifier:
    """One certifier for a fault variant's frames: each frame's detections go to the
    certifier of the run that perceived them (``perceived[step]``, a set of neuron
    faults; a step not in it, the fault-free run: key None). A run without a certifier
    leaves its detections unbounded."""

    def certify(wanted: Mapping[int, np.ndarray]) -> dict[int, np.ndarray]:
        groups: dict[frozenset[str] | None, dict[int, np.ndarray]] = {}
        for k, idx in wanted.items():
            groups.setdefault(perceived.get(k), {})[k] = idx
        out: dict[int, np.ndarray] = {}
        for key, part in groups.items():
            if key in by_set:
                out.update(by_set[key](part))
        return out

    return certify


#: How certified bounds are computed (lesmc/perception/certify.py; docs/cnn.md).
CERTIFICATION_METHOD = "CROWN, L2 ball (docs/cnn.md)"


def certification_meta(
    frames: Iterable[Frame], scope: str, seconds: float, **extra: Any
) -> dict[str, Any]:
    """A scene's ``meta.certified`` after on-demand certification: the method, the
    detections of ``frames`` that carry a bound, ``scope`` (which ones), ``extra`` fields
    and the seconds spent."""
    frames = list(frames)
    return {
        "method": CERTIFICATION_METHOD,
        **extra,
        "detections": sum(d.payoff_lower is not None for f in frames for d in f.detections),
        "of": sum(len(f.detections) for f in frames),
        "scope": scope,
        "seconds": round(seconds, 3),
    }
