"""``verify``'s perception of its video: the detector over every frame, kept in OUT/cache.

The fault-free networks run once per video (lesmc/experiment/experiment.py); with
neuron faults, the faulty networks run too (lesmc/experiment/neuron_faults.py). Both
go through :func:`perceive_video` and store what they found with :func:`store`:
the footage (a scene file without a target, validated on reading like any scene)
and each hidden unit's largest value on the scored windows (a stuck-at-max fault's
value).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from lesmc.common.errors import LesmcError, UsageError
from lesmc.common.progress import Reporter
from lesmc.experiment.cache import StageCache
from lesmc.perception import HISTORY
from lesmc.pipeline.job import Certifier
from lesmc.scene import Footage, footage_from_dict, scene_to_dict

if TYPE_CHECKING:
    from lesmc.perception.cnn import Nets
    from lesmc.perception.run import PerceiveRun
    from lesmc.video.reader import FrameSet


#: Per network, per hidden layer, each unit's largest value (PerceiveRun.unit_max).
UnitMax = dict[str, list[np.ndarray]]


def perceive_video(
    frames: FrameSet,
    nets: Nets,
    dt: float,
    meta: dict[str, Any],
    keep_windows: bool,
    advance: Callable[[], None] | None = None,
    record_maxima: bool = False,
    attack: bool = True,
    inject: tuple[float, int] | None = None,
) -> tuple[Footage, PerceiveRun]:
    """Detections and DeepFool payoffs of every frame (the default attack settings), as
    footage; ``keep_windows`` keeps the N_dr windows (certification and pricing on
    demand read them), ``record_maxima`` the hidden units' largest values (stuck-at-max
    faults read them); without ``attack`` every payoff is unpriced (lesmc/experiment/pricing.py);
    ``inject`` (px, cap): the injection candidates too, priced now (docs/cnn.md)."""
    return perceive_videos(
        frames, [nets], dt, [meta], keep_windows, advance, record_maxima, attack, inject
    )[0]


def perceive_videos(
    frames: FrameSet,
    nets: Sequence[Nets],
    dt: float,
    metas: Sequence[dict[str, Any]],
    keep_windows: bool,
    advance: Callable[[], None] | None = None,
    record_maxima: bool = False,
    attack: bool = True,
    inject: tuple[float, int] | None = None,
) -> list[tuple[Footage, PerceiveRun]]:
    """:func:`perceive_video` for several networks over one front end (each frame is
    registered and its candidates found once)."""
    from lesmc.perception.attack_settings import AttackConfig
    from lesmc.perception.run import PerceiveOptions, perceive_all
    from lesmc.perception.to_scene import footage_from_run

    opts = [
        PerceiveOptions(
            history=HISTORY,
            nets=n,
            attack=AttackConfig() if attack else None,
            keep_windows=keep_windows,
            record_maxima=record_maxima,
            inject_within=None if inject is None else inject[0],
            inject_cap=32 if inject is None else inject[1],
        )
        for n in nets
    ]
    runs = perceive_all(frames, opts, None, advance)
    if not runs[0].detections:
        raise UsageError("the video produced no detections")
    if inject is not None:
        from lesmc.experiment.perceive import candidates_meta

        metas = [{**m, "candidates": candidates_meta(*inject)} for m in metas]
    return [(footage_from_run(r, dt, m), r) for r, m in zip(runs, metas, strict=True)]


def certifier(
    nets: Nets, run: PerceiveRun, label: str, rep: Reporter, spent: Callable[[str], None]
) -> Certifier:
    """Certification on demand of a perception run's detections, on its N_dr, with a
    progress bar named ``label``; ``spent(stage)`` stops the run once the budget is spent."""
    from lesmc.perception.run import certify_on_demand

    def certify(wanted: Mapping[int, np.ndarray]) -> dict[int, np.ndarray]:
        with rep.bar(label, None) as bar:

            def batch(done: int, total: int) -> None:
                bar.update(total=total, completed=done)
                spent(label)

            return certify_on_demand(nets, run, dict(wanted), batch)

    return certify


def store(cache: StageCache, stage: str, key: str, footage: Footage, unit_max: UnitMax) -> None:
    """Keep a perception under ``key``."""
    maxima = {
        net: [[float(v) if np.isfinite(v) else None for v in m] for m in layers]
        for net, layers in unit_max.items()
    }
    cache.put(stage, key, {"footage": scene_to_dict(footage), "unit_max": maxima})


def read(cache: StageCache, stage: str, key: str) -> tuple[Footage, UnitMax] | None:
    """A perception kept under ``key``; None when absent or not a valid entry."""
    hit = cache.get(stage, key)
    if not isinstance(hit, dict) or not isinstance(hit.get("unit_max"), dict):
        return None
    try:
        footage, _ = footage_from_dict(hit.get("footage"), str(cache.dir))
        unit_max = {
            str(net): [_maxima(layer) for layer in layers]
            for net, layers in hit["unit_max"].items()
        }
    except (LesmcError, TypeError, ValueError):
        return None
    return footage, unit_max


def _maxima(layer: Any) -> np.ndarray:
    """One layer's maxima: a list of numbers, null for a unit never scored (``-inf``)."""
    if not isinstance(layer, list) or not all(
        v is None or (isinstance(v, (int, float)) and not isinstance(v, bool)) for v in layer
    ):
        raise ValueError("unit maxima must be lists of numbers")
    return np.asarray([-np.inf if v is None else v for v in layer], np.float32)
