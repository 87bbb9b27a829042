"""``lesmc verify FRAMES --detector FILE.toml``: the experiment on the user's whole-frame detector.

The detector file (docs/detectors.md) runs on every frame with no WAMI front end, as
``lesmc perceive --detector FILE.toml -o`` does (lesmc/experiment/perceive.py,
:func:`~lesmc.experiment.perceive.perceive_with_file`). A heatmap or box detector's
detections are priced when a model first reads them (:class:`FilePricer`; up front with
``--price-all`` or ``--payoffs certified|interval``); the certified payoffs of verify
(:func:`verify_certifier`) and of a campaign bound those the models can hide, through
:func:`file_certifier` (up front, as ``perceive --certify``, with ``--price-all``).
The scene then gets its
target and goes through the same checks as the window pipeline's
(lesmc/experiment/experiment.py); a violation is replayed through the detector file
(lesmc/replay/detector_file.py). With the video's truth, the detections' recall and
precision are measured as ``lesmc train --kind heatmap`` measures them: a detection is
a true positive when it matches a visible vehicle one to one within 4 px.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from lesmc.common.errors import UsageError
from lesmc.common.progress import Reporter
from lesmc.experiment.pricing import VideoPricer
from lesmc.perception import NetFiles

if TYPE_CHECKING:
    from lesmc.experiment.cache import StageCache
    from lesmc.perception.file_pricing import FilePricing
    from lesmc.perception.quality import Truth
    from lesmc.pipeline.job import Certifier
    from lesmc.replay.run import Outcome
    from lesmc.results.read import ResultsDoc
    from lesmc.scene import Footage, Frame, Scene
    from lesmc.video.reader import FrameSet

#: A detection matches a visible vehicle within this many pixels (one to one).
MATCH_PX = 4.0


def detector_file_of(nets: NetFiles) -> str | None:
    """The detector file ``--detector`` names (a .toml or .json), or None: the window
    pipeline's networks."""
    from lesmc.perception.detector_file import is_detector_file

    path = nets[1]
    return path if path is not None and is_detector_file(path) else None


def refuse_window_options(nets: NetFiles, neuron_faults: bool, inject: bool = False) -> None:
    """Options of the window pipeline that a detector file replaces are errors naming them;
    so is ``inject`` (--inject-within), which verify does not yet perceive through a file."""
    if nets[0] is not None or nets[2] is not None:
        given = "--nets" if nets[0] is not None else "--locator"
        raise UsageError(
            f"{given} gives the window pipeline's networks; --detector {nets[1]} is a "
            "detector file, which replaces them (docs/detectors.md)"
        )
    if neuron_faults:
        raise UsageError(
            "neuron faults stick a unit of the window pipeline's networks; a detector file's "
            "network has no such faults yet (drop the neuron faults, or --detector FILE.toml)"
        )
    if inject:
        raise UsageError(
            f"--inject-within: lesmc verify does not perceive injection candidates through "
            f"a detector file yet (--detector {nets[1]}); lesmc perceive --detector "
            f"{nets[1]} -o SCENE --inject-within PX writes them (docs/detectors.md)"
        )


def perceive_video(
    frames_dir: str,
    frames: FrameSet,
    path: str,
    truth: str | None,
    truths: Truth | None,
    certify: bool,
    dt: float,
    rep: Reporter,
    spent: Callable[[str], None],
    priced: bool = True,
) -> tuple[Footage, dict[str, Any]]:
    """The detector file on every frame of ``frames_dir``, every detection priced (and
    certified when ``certify``; none priced when not ``priced``: :func:`perceive_cached`):
    the footage (no target), and the detections' facts (counts; with ``truth``, recall
    and precision) for the results' ``perception``."""
    from lesmc.experiment.perceive import PerceiveRequest, perceive_with_file
    from lesmc.scene import Footage

    req = PerceiveRequest(frames_dir, (None, path, None), truth=truth, certify=certify, dt=dt)
    with rep.bar("perceiving", None) as bar:

        def advance() -> None:
            bar.advance()
            spent("perceiving the video with the detector file")

        def start(n: int) -> Callable[[], None]:
            bar.update(total=n)
            return advance

        got = perceive_with_file(req, path, start, priced=priced)
    footage = got.scene
    assert isinstance(footage, Footage)  # no target asked: the caller places it
    return footage, detection_facts(footage, frames, truths, path)


def perceive_cached(
    frames_dir: str,
    frames: FrameSet,
    path: str,
    truth: str | None,
    truths: Truth | None,
    certify: bool,
    dt: float,
    rep: Reporter,
    spent: Callable[[str], None],
    cache: StageCache,
    lazy: bool,
) -> tuple[Footage, dict[str, Any], str]:
    """:func:`perceive_video`, kept in OUT/cache (lesmc/experiment/cache.py) as the window
    pipeline keeps its perception: a rerun on the same frames, detector file, network,
    settings and code reads the footage back (no network is run). ``lazy``: the payoffs
    are left unpriced, for :class:`FilePricer` to price those the models read (an entry
    is stored again with them, lesmc/experiment/experiment.py ``_keep_priced``); else a
    kept entry with unpriced payoffs is perceived again. Also the facts and the key."""
    from lesmc.experiment import video_perception

    key = perception_key(frames_dir, frames, path, certify, dt)
    hit = video_perception.read(cache, STAGE, key)
    if hit is not None and not lazy and hit[0].has_unpriced:
        rep.log("perceiving the video again: its cached perception has unpriced payoffs")
        hit = None
    if hit is not None and len(hit[0].frames) != len(frames):  # an entry cut or edited
        rep.log("perceiving the video again: its cached perception is not of every frame")
        hit = None
    if hit is not None:
        rep.log(f"reusing the perception of {frames_dir} through {path} from {cache.dir}")
        return hit[0], detection_facts(hit[0], frames, truths, path), key
    footage, facts = perceive_video(frames_dir, frames, path, truth, truths, certify, dt, rep,
                                    spent, priced=not lazy)  # fmt: skip
    video_perception.store(cache, STAGE, key, footage, {})
    return footage, facts, key


class FilePricer(VideoPricer):
    """Prices a detector file's detections when a model first reads them
    (:class:`~lesmc.scene.OnDemandPayoffs`): frame k's wanted detections, known by their
    positions, by the attack ``lesmc perceive --detector`` runs on each, with the same
    settings (:class:`~lesmc.perception.file_pricing.FilePricing`, for a heatmap or a box
    detector alike). The detector is loaded on the first request (none for a run whose
    models read no payoff)."""

    def __init__(self, path: str, frames: FrameSet, footage: Footage) -> None:
        super().__init__(None, None, _no_run)
        self.path, self.frames = path, frames
        self.positions = {f.step: f.positions() for f in footage.frames}
        self.how: Any = None

    def __call__(self, wanted: Mapping[int, np.ndarray]) -> dict[int, np.ndarray]:
        if self.released:
            raise RuntimeError("payoffs asked for after the pricer let go of its detector")
        if self.how is None:
            self.how = file_pricing(self.path, self.frames)
        if self.on_price is not None:
            self.on_price(sum(len(v) for v in wanted.values()))
        t0 = time.monotonic()
        out = per_frame(wanted, self.positions.__getitem__, self.how.price)
        self.seconds += time.monotonic() - t0
        return out

    def release(self) -> None:
        """Let go of the detector (the checks are done: nothing is priced after)."""
        self.released = True
        self.how = None


def _no_run() -> Any:
    """A detector file's pricer has no perception run to perceive again."""
    raise RuntimeError("a detector file's pricer perceives nothing again")


def file_pricing(path: str, frames: FrameSet) -> FilePricing:
    """The detector file's :class:`~lesmc.perception.file_pricing.FilePricing` on
    ``frames`` with the attack settings of ``lesmc perceive --detector`` (its default
    ``PerceiveRequest``): verify's and campaign's."""
    from lesmc.experiment.perceive import PerceiveRequest, attack_config
    from lesmc.perception.detector_file import load_detector
    from lesmc.perception.file_pricing import FilePricing
    from lesmc.perception.heatmap import check_frames

    det = check_frames(frames, load_detector(path), str(frames.paths[0].parent))
    return FilePricing(det, frames, attack_config(PerceiveRequest(str(frames.paths[0].parent))))


def file_certifier(path: str, frames: FrameSet, footage: Footage | Scene) -> Certifier:
    """A certifier (lesmc/pipeline/certify.py) of ``footage``'s detections through the
    detector file ``path``: per frame step, the wanted detections' certified lower bounds
    (``nan`` for the others), each bounded as ``lesmc perceive --detector --certify``
    bounds it, below its payoff in ``footage``. What ``lesmc campaign`` and ``lesmc
    verify`` (:func:`verify_certifier`) with ``--payoffs certified|interval`` run on the
    detections their models can hide; the detector is loaded on the first request."""
    how: list[FilePricing] = []

    def certify(wanted: Mapping[int, np.ndarray]) -> dict[int, np.ndarray]:
        if not how:
            how.append(file_pricing(path, frames))

        def bound(k: int, pos: np.ndarray, idx: np.ndarray) -> np.ndarray:
            return how[0].certify(k, pos, idx, footage.frame(k).payoff_values()[idx])

        return per_frame(wanted, lambda k: footage.frame(k).positions(), bound)

    return certify


def verify_certifier(
    path: str,
    frames: FrameSet,
    scene: Scene,
    rep: Reporter,
    spent: Callable[[str], None],
) -> Certifier:
    """``lesmc verify --payoffs certified|interval``'s certifier through the detector file
    ``path``: the campaign's (:func:`file_certifier`) on the detections of ``scene`` the
    checked models can hide (lesmc/pipeline/certify.py finds them), a frame at a time
    under a progress bar, saying how many first; ``spent(stage)`` stops the run once the
    budget is spent."""
    bound = file_certifier(path, frames, scene)
    of = sum(len(f.detections) for f in scene.frames)

    def certify(wanted: Mapping[int, np.ndarray]) -> dict[int, np.ndarray]:
        n = sum(len(v) for v in wanted.values())
        rep.log(
            f"certifying {n} of {of} detections through {path} (those the checked models can hide)"
        )
        out: dict[int, np.ndarray] = {}
        with rep.bar("certifying", n) as bar:
            for k, idx in sorted(wanted.items()):
                out |= bound({k: idx})
                bar.advance(len(idx))
                spent("certifying payoff lower bounds")
        return out

    return certify


def per_frame(
    wanted: Mapping[int, np.ndarray],
    positions: Callable[[int], np.ndarray],
    value: Callable[[int, np.ndarray, np.ndarray], np.ndarray],
) -> dict[int, np.ndarray]:
    """Per frame step ``k`` of ``wanted``, a column over the frame's detections (their
    ``positions(k)``): ``value(k, positions, idx)`` at the wanted indices ``idx``, ``nan``
    elsewhere. The loop of :class:`FilePricer` (payoffs) and :func:`file_certifier`
    (certified lower bounds) alike."""
    out = {}
    for k, idx in sorted(wanted.items()):
        pos = positions(k)
        col = np.full(len(pos), np.nan)
        col[idx] = value(k, pos, idx)
        out[k] = col
    return out


def refuse_uncertifiable(path: str, option: str) -> None:
    """A detector file whose detections get no certified bounds (a box detector, or a
    network outside the supported chain) is a located error, before anything is perceived
    (lesmc/perception/file_pricing.py); ``option`` asked for the bounds."""
    from lesmc.perception.detector_file import load_detector
    from lesmc.perception.file_pricing import refuse_uncertifiable as refuse

    refuse(load_detector(path), option)


#: The OUT/cache stage of a detector file's perception (the window pipeline's: keys differ).
STAGE = "perception"


def perception_key(frames_dir: str, frames: FrameSet, path: str, certify: bool, dt: float) -> str:
    """The cache key of a video perceived through the detector file ``path``: the frames'
    bytes, the detector file's and its network's bytes, the settings (seconds between
    frames, attack, certification) and the code that perceives."""
    from dataclasses import asdict

    from lesmc.experiment.cache import code_digest, digest, file_digests
    from lesmc.perception.attack_settings import AttackConfig
    from lesmc.perception.certify import CertifyConfig
    from lesmc.perception.detector_file import read_detector_file

    spec = read_detector_file(path)
    return digest(
        {
            "code": code_digest("perception", "video", "scene"),
            "frames": file_digests(frames.paths),
            "detector_file": file_digests([Path(path), Path(spec.network)]),
            "source": str(frames_dir),
            "dt": dt,
            "attack": asdict(AttackConfig()),
            "certify": asdict(CertifyConfig()) if certify else None,
        }
    )


def detection_facts(
    footage: Footage, frames: FrameSet, truth: Truth | None, path: str
) -> dict[str, Any]:
    """How many detections the detector file ``path`` made in ``footage``, and their
    payoffs' facts (:func:`payoff_facts`); with the video's ``truth``, the detections
    matched to the visible vehicles (:func:`quality`). No detection at all is an error."""
    n = sum(len(f.detections) for f in footage.frames)
    if not n:
        raise UsageError(f"the detector file {path} found no detection in {footage.meta['source']}")
    out: dict[str, Any] = {"frames": len(footage.frames), "detections": n}
    out |= payoff_facts(footage.frames)
    if truth is not None:
        out |= quality(footage, frames, truth)
    return out


def payoff_facts(frames: Iterable[Frame]) -> dict[str, Any]:
    """How many detections of ``frames`` carry a payoff (``priced``: verify prices those
    its models read), how many of those are finite (``attackable``), their median and
    least."""
    pays = np.array([d.payoff for f in frames for d in f.detections], np.float64)
    priced = pays[~np.isnan(pays)]
    finite = priced[np.isfinite(priced)]
    return {
        "priced": len(priced),
        "attackable": len(finite),
        "payoff_median": float(np.median(finite)) if len(finite) else None,
        "payoff_min": float(finite.min()) if len(finite) else None,
    }


def quality(footage: Footage, frames: FrameSet, truth: Truth) -> dict[str, Any]:
    """Recall and precision against every visible (not occluded) true vehicle, moving or
    not: a detection is a true positive when it matches one one to one within
    :data:`MATCH_PX` pixels (lesmc/perception/quality.py ``visible_counts``)."""
    from lesmc.perception.quality import visible_counts

    def pairs() -> Iterator[tuple[np.ndarray, np.ndarray]]:
        for f in footage.frames:
            tf = truth.frames.get(frames.paths[f.step].name)
            if tf is not None:
                yield f.positions(), tf.positions[~tf.occluded]

    got = visible_counts(pairs(), MATCH_PX)
    return {
        "vehicles": got.vehicles,
        "true_positives": got.true_positives,
        "recall": got.recall,
        "precision": got.precision,
        "match": f"one to one within {MATCH_PX:g} px of a visible vehicle, moving or not",
    }


def describe(facts: dict[str, Any]) -> str:
    """The detections' facts in one line, for the log and the results' ``meta``."""
    text = f"{facts['detections']} detections in {facts['frames']} frames"
    if facts.get("recall") is not None and facts.get("precision") is not None:
        text += f", recall {facts['recall']:.3f}, precision {facts['precision']:.3f}"
    if facts.get("priced", facts["detections"]) < facts["detections"]:
        text += f", {facts['priced']} priced (those the checked models read)"
    text += f", {facts['attackable']} attackable"
    if facts["payoff_median"] is not None:
        text += f" (payoff median {facts['payoff_median']:.3g}, min {facts['payoff_min']:.3g})"
    return text


def replay_key(nets: NetFiles) -> dict[str, Any]:
    """What a replay through a detector file reads beyond the files ``nets`` names: the
    file's network (its sha256), for the key of OUT/cache's replay; nothing for the window
    pipeline (the keys of its runs stay as they were)."""
    from lesmc.experiment.cache import file_digests
    from lesmc.perception.detector_file import read_detector_file

    path = detector_file_of(nets)
    if path is None:
        return {}
    return {"detector_network": file_digests([Path(read_detector_file(path).network)])}


def replay(doc: ResultsDoc, frames_dir: str, path: str, rep: Reporter) -> Outcome:
    """Every violated counterexample of ``doc`` replayed through the detector file."""
    from lesmc.replay.detector_file import replay_with_file

    with rep.bar("replaying", None) as bar:
        return replay_with_file(doc, frames_dir, path, None, bar)
