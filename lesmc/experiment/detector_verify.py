"""``lesmc verify FRAMES --detector FILE.toml``: the experiment on the user's whole-frame detector.

The detector file (docs/detectors.md) runs on every frame with no WAMI front end, as
``lesmc perceive --detector FILE.toml -o`` does (lesmc/experiment/perceive.py,
:func:`~lesmc.experiment.perceive.perceive_with_file`): every detection is priced up
front (and certified with ``--payoffs certified|interval``). The scene then gets its
target and goes through the same checks as the window pipeline's
(lesmc/experiment/experiment.py); a violation is replayed through the detector file
(lesmc/replay/detector_file.py). With the video's truth, the detections' recall and
precision are measured as ``lesmc train --kind heatmap`` measures them: a detection is
a true positive when it matches a visible vehicle one to one within 4 px.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any

import numpy as np

from lesmc.common.errors import UsageError
from lesmc.common.progress import Reporter
from lesmc.perception import NetFiles

if TYPE_CHECKING:
    from lesmc.perception.boxes import BoxDetections
    from lesmc.perception.heatmap import HeatmapDetections
    from lesmc.perception.quality import Truth
    from lesmc.replay.run import Outcome
    from lesmc.results.read import ResultsDoc
    from lesmc.scene import Footage
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
) -> tuple[Footage, dict[str, Any]]:
    """The detector file on every frame of ``frames_dir``, every detection priced (and
    certified when ``certify``): the footage (no target), and the detections' facts
    (counts; with ``truth``, recall and precision) for the results' ``perception``."""
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

        got = perceive_with_file(req, path, start)
    footage = got.scene
    assert isinstance(footage, Footage)  # no target asked: the caller places it
    if not any(len(d.positions) for d in got.detections):
        raise UsageError(f"the detector file {path} found no detection in {frames_dir}")
    return footage, detection_facts(got.detections, footage, frames, truths)


def detection_facts(
    dets: list[HeatmapDetections] | list[BoxDetections],
    footage: Footage,
    frames: FrameSet,
    truth: Truth | None,
) -> dict[str, Any]:
    """How many detections, how many priced finite, their payoffs' median and least; with
    the video's ``truth``, the detections matched to the visible vehicles (:func:`quality`)."""
    pays = np.array([d.payoff for f in footage.frames for d in f.detections], np.float64)
    finite = pays[np.isfinite(pays)]
    out: dict[str, Any] = {
        "frames": len(dets),
        "detections": int(sum(len(d.positions) for d in dets)),
        "attackable": len(finite),
        "payoff_median": float(np.median(finite)) if len(finite) else None,
        "payoff_min": float(finite.min()) if len(finite) else None,
    }
    if truth is not None:
        out |= quality(dets, frames, truth)
    return out


def quality(
    dets: list[HeatmapDetections] | list[BoxDetections], frames: FrameSet, truth: Truth
) -> dict[str, Any]:
    """Recall and precision against every visible (not occluded) true vehicle, moving or
    not: a detection is a true positive when it matches one one to one within
    :data:`MATCH_PX` pixels (lesmc/perception/quality.py ``visible_counts``)."""
    from lesmc.perception.quality import visible_counts

    def pairs() -> Iterator[tuple[np.ndarray, np.ndarray]]:
        for d in dets:
            tf = truth.frames.get(frames.paths[d.index].name)
            if tf is not None:
                yield np.asarray(d.positions), tf.positions[~tf.occluded]

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
    text += f", {facts['attackable']} attackable"
    if facts["payoff_median"] is not None:
        text += f" (payoff median {facts['payoff_median']:.3g}, min {facts['payoff_min']:.3g})"
    return text


def replay(doc: ResultsDoc, frames_dir: str, path: str, rep: Reporter) -> Outcome:
    """Every violated counterexample of ``doc`` replayed through the detector file."""
    from lesmc.replay.detector_file import replay_with_file

    with rep.bar("replaying", None) as bar:
        return replay_with_file(doc, frames_dir, path, None, bar)
