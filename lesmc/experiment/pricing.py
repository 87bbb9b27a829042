"""Payoffs on demand: ``verify`` attacks a detection when a model first reads its payoff.

DeepFool on every Q_dr blob of a video is a third of perception (the default video:
6,164 windows, 4.8 s of 14 s), yet the models the bundled specs check read the payoffs
of about a hundred detections, those near the target's tracks in the attack windows.
So ``verify`` (``--payoffs attack``, no ``--faults``, no ``--price-all``) perceives
without attacking, keeps each blob's N_dr window, and gives the scene
:class:`~lesmc.scene.PricedFrame` frames: a payoff read by a model is priced then,
by the same attack with the same settings, each blob once
(:func:`lesmc.perception.run.price_detections`). A model therefore sees the payoffs
it would see had every detection been priced up front, up to float32 rounding (a
window attacked in another batch can end about 1e-7 apart: docs/cnn.md); OUT/scene.json
marks the others ``"unpriced"`` (docs/scene-format.md).

A perception read back from OUT/cache has no windows: the first payoff it lacks
makes :class:`VideoPricer` perceive the video again (the networks loaded then),
after which it prices like a fresh run.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from lesmc.scene import Footage, OnDemandPayoffs, PricedFrame

if TYPE_CHECKING:
    from lesmc.perception.cnn import Nets
    from lesmc.perception.run import PerceiveRun

#: How the results' meta and OUT/scene.json name what was priced.
SCOPE = "the detections the checked models read; the others are unpriced"


class VideoPricer:
    """Prices detections of a perception run on its N_dr (the default attack settings).

    ``again()`` returns (networks, run) for a perception read from the cache, which
    has no windows: called once, on the first request. ``on_price(n)`` before each
    attack, ``n`` the detections asked for (the budget).
    """

    def __init__(
        self,
        nets: Nets | None,
        run: PerceiveRun | None,
        again: Callable[[], tuple[Nets, PerceiveRun]],
        on_price: Callable[[int], None] | None = None,
    ) -> None:
        self.nets, self.run, self.again = nets, run, again
        self.on_price = on_price
        self.seconds = 0.0
        self.released = False

    def __call__(self, wanted: Mapping[int, np.ndarray]) -> dict[int, np.ndarray]:
        from lesmc.perception.attack_settings import AttackConfig
        from lesmc.perception.run import price_detections

        if self.released:
            raise RuntimeError("payoffs asked for after the pricer let go of its windows")
        if self.run is None or self.nets is None:
            self.nets, self.run = self.again()
        if self.on_price is not None:
            self.on_price(sum(len(v) for v in wanted.values()))
        t0 = time.monotonic()
        out = price_detections(self.nets, self.run, wanted, AttackConfig())
        self.seconds += time.monotonic() - t0
        return out

    def release(self) -> None:
        """Let go of the run's N_dr windows (the checks are done: nothing is priced after)."""
        self.released = True
        if self.run is not None:
            self.run.detections = [
                replace(fd, windows=fd.windows[:0].copy()) for fd in self.run.detections
            ]


def on_demand(footage: Footage, pricer: VideoPricer) -> tuple[Footage, OnDemandPayoffs]:
    """``footage`` whose unpriced payoffs ``pricer`` prices when a model reads them."""
    values = {f.step: f.payoff_values() for f in footage.frames if f.has_unpriced}
    prices = OnDemandPayoffs(values, pricer)
    frames = tuple(
        PricedFrame(f.step, f.detections, f.to_next, prices, candidates=f.candidates)
        if f.step in values
        else f
        for f in footage.frames
    )
    return replace(footage, frames=frames), prices


def priced_meta(scene: Any) -> dict[str, Any]:
    """A scene's ``meta.priced``: how many of its detections carry a payoff, of how many,
    and which ones (:data:`SCOPE`). The same for a rerun that priced nothing."""
    frames = scene.frames
    return {
        "detections": sum(d.priced for f in frames for d in f.detections),
        "of": sum(len(f.detections) for f in frames),
        "scope": SCOPE,
    }
