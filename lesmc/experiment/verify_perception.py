"""``lesmc verify``'s perception of a video: read from OUT/cache or perceived now (by the
networks, or a detector file), its payoffs priced up front or when a model first reads
them (lesmc/experiment/pricing.py).
"""

from __future__ import annotations

import dataclasses
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from lesmc.common.budget import Budget
from lesmc.common.errors import UsageError
from lesmc.common.progress import Reporter
from lesmc.experiment import detector_verify, video_perception
from lesmc.experiment.cache import StageCache, code_digest, digest, file_digests, net_files
from lesmc.experiment.perceive import networks_meta
from lesmc.experiment.pricing import VideoPricer
from lesmc.experiment.pricing import on_demand as on_demand_footage
from lesmc.experiment.verify_request import Request, spent
from lesmc.experiment.video_perception import UnitMax
from lesmc.perception import DELTA_BC, HISTORY
from lesmc.scene import Footage, OnDemandPayoffs

if TYPE_CHECKING:  # reading frames imports cv2: only where a video is read
    from lesmc.video.reader import FrameSet


@dataclass
class Perception:
    """The video's footage, with the networks and run that made it (None when read from
    OUT/cache), each hidden unit's largest value, and the cache key of the inputs."""

    footage: Footage
    nets: Any
    run: Any
    unit_max: UnitMax
    key: str
    pricing: tuple[OnDemandPayoffs, VideoPricer, Footage] | None = None
    #: a detector file's detections: counts, recall and precision, payoffs (detector_verify)
    detections: dict[str, Any] | None = None
    #: a detector file's detections all certified now (--price-all, certified payoffs):
    #: no check certifies them on demand then
    certified: bool = False


def perception(
    req: Request,
    frames: FrameSet,
    frames_dir: str,
    dt: float,
    cache: StageCache,
    rep: Reporter,
    maxima: bool,
    on_demand: bool,
) -> Perception:
    """The video's detections and attack payoffs: read from OUT/cache when this video was
    perceived before with the same networks, settings and code (then no network is
    loaded; in a certified payoff mode the run is needed, so the video is perceived
    again), else perceived now and stored. ``maxima``: the networks' unit maxima are
    needed too; an entry stored without them (by a run without neuron faults) is then
    perceived again, recording them. ``on_demand``: a payoff is priced when a model
    first reads it (lesmc/experiment/pricing.py); otherwise every detection is priced now,
    and an entry with unpriced payoffs is perceived again."""
    key = _perception_key(req, frames, frames_dir, dt)
    hit = video_perception.read(cache, "perception", key) if req.payoffs == "attack" else None
    if hit is not None and maxima and not hit[1]:
        rep.log("perceiving the video again: its cached perception has no unit maxima")
        hit = None
    if hit is not None and not on_demand and hit[0].has_unpriced:
        rep.log("perceiving the video again: its cached perception has unpriced payoffs")
        hit = None

    def perceive() -> tuple[Footage, Any, Any]:
        return _perceive_now(req, frames, frames_dir, dt, rep, maxima, on_demand)

    if hit is not None:
        rep.log(f"reusing the perception of {frames_dir} from {cache.dir}")
        seen = Perception(hit[0], None, None, hit[1], key)
        if not on_demand or not hit[0].has_unpriced:
            return seen

        def again() -> tuple[Any, Any]:  # a payoff the cached entry lacks: its windows
            rep.log("perceiving the video again: a check reads payoffs its cache lacks")
            footage, nets, run = perceive()
            same_detections(hit[0], footage, cache)
            return nets, run

        return _on_demand(seen, VideoPricer(None, None, again), req.budget)
    footage, nets, run = perceive()
    video_perception.store(cache, "perception", key, footage, run.unit_max)
    seen = Perception(footage, nets, run, run.unit_max, key)
    if not on_demand:
        return seen
    return _on_demand(seen, VideoPricer(nets, run, lambda: (nets, run)), req.budget)


def file_perception(
    req: Request,
    frames: FrameSet,
    frames_dir: str,
    path: str,
    truth: tuple[str | None, Any],
    dt: float,
    rep: Reporter,
    on_demand: bool,
) -> Perception:
    """The video through the detector file ``path`` (lesmc/experiment/detector_verify.py),
    kept in OUT/cache: a heatmap or box detector's payoffs priced when a model reads them
    (as the window pipeline's: ``on_demand``, --payoffs attack, no --price-all), else every
    detection priced now (a multi-target design reads the scene's payoffs directly). In a
    certified payoff mode the checks certify what their models can hide
    (detector_verify.verify_certifier); with --price-all every detection is certified now."""
    lazy = on_demand and req.payoffs == "attack" and not req.price_all
    certify = req.payoffs != "attack" and req.price_all
    footage, facts, key = detector_verify.perceive_cached(
        frames_dir, frames, path, truth[0], truth[1], certify, dt, rep,
        lambda stage: spent(req.budget, stage), StageCache(req.out), lazy,
    )  # fmt: skip
    seen = Perception(footage, None, None, {}, key, detections=facts, certified=certify)
    if not lazy or not footage.has_unpriced:
        return seen
    return _on_demand(seen, detector_verify.FilePricer(path, frames, footage), req.budget)


def _perception_key(req: Request, frames: FrameSet, frames_dir: str, dt: float) -> str:
    """The cache key of a video's perception: its frames' bytes, the networks' files, the
    settings and the code that perceives."""
    from lesmc.perception.attack_settings import AttackConfig

    return digest(
        {
            "code": code_digest("perception", "video", "scene"),
            "frames": file_digests(frames.paths),
            "nets": file_digests(net_files(req.nets)),
            "source": str(frames_dir),
            "dt": dt,
            "history": HISTORY,
            "attack": asdict(AttackConfig()),
        }
        | _inject_key(req)
    )


def _inject_key(req: Request) -> dict[str, Any]:
    """The injection candidates' part of the perception's cache key (none without them:
    the keys of runs without candidates stay as they were)."""
    return {} if req.inject is None else {"inject": list(req.inject)}


def same_detections(cached: Footage, again: Footage, cache: StageCache) -> None:
    """The video perceived again must give the cached perception's detections, else its
    payoffs would be priced for other detections than the cached ones."""
    same = len(cached.frames) == len(again.frames) and all(
        f.step == g.step and np.array_equal(f.positions(), g.positions())
        for f, g in zip(cached.frames, again.frames, strict=True)
    )
    if not same:
        raise UsageError(
            f"{cache.dir}: the cached perception's detections differ from the video's "
            f"perceived again; remove {cache.dir} and run again"
        )


def _perceive_now(
    req: Request,
    frames: FrameSet,
    frames_dir: str,
    dt: float,
    rep: Reporter,
    maxima: bool,
    on_demand: bool,
) -> tuple[Footage, Any, Any]:
    """The video perceived now: its footage, the networks and the perception run (without
    an attack when ``on_demand``; keeping the N_dr windows that certification or pricing
    read)."""
    from lesmc.perception.cnn import load_nets

    nets = load_nets(*req.nets)
    spent(req.budget, "loading the video and the networks")
    with rep.bar("perceiving", len(frames)) as bar:

        def advance() -> None:
            bar.advance()
            spent(req.budget, "perceiving the video")

        meta: dict[str, Any] = {"source": str(frames_dir), "detector": nets.settings.trained_on}
        # the front end perceive_video runs (the defaults), for the replay (as perceive -o)
        meta["frontend"] = {"history": HISTORY, "delta_bc": DELTA_BC}
        meta |= networks_meta(req.nets)
        keep = req.payoffs != "attack" or on_demand
        footage, run = video_perception.perceive_video(
            frames, nets, dt, meta, keep, advance, maxima, not on_demand, req.inject
        )
    return footage, nets, run


def _on_demand(seen: Perception, pricer: VideoPricer, budget: Budget) -> Perception:
    """``seen`` with its unpriced payoffs priced by ``pricer`` when a model reads them
    (within ``budget``: past it, verify stops as while building a model)."""
    pricer.on_price = lambda _n: spent(budget, "pricing payoffs")
    footage, prices = on_demand_footage(seen.footage, pricer)
    return dataclasses.replace(seen, footage=footage, pricing=(prices, pricer, footage))
