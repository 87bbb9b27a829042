"""The perceive stage as a whole: a directory of frames -> detections, payoffs -> a scene.

``lesmc perceive`` and :func:`lesmc.api.perceive` both run it: the inputs are read
and checked against each other first (:func:`open_inputs`), then the detector runs
frame by frame (lesmc/perception/run.py) and the footage gets its target
(:func:`perceive_frames`). Writing the scene is the caller's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from lesmc.common.errors import InputError, Location, UsageError
from lesmc.perception import DELTA_BC, FRONTEND_RANGES, HISTORY, NetFiles
from lesmc.video import FPS

if TYPE_CHECKING:
    from collections.abc import Callable

    from lesmc.perception.attack_settings import AttackConfig
    from lesmc.perception.boxes import BoxDetections
    from lesmc.perception.certify import CertifyConfig
    from lesmc.perception.cnn import Nets
    from lesmc.perception.detector_file import LoadedDetector
    from lesmc.perception.heatmap import HeatmapDetections
    from lesmc.perception.quality import Truth
    from lesmc.perception.run import PerceiveRun
    from lesmc.scene import Footage, Scene, TrackerConfig
    from lesmc.tracking.targets import TargetSpec
    from lesmc.video.reader import FrameSet


@dataclass(frozen=True)
class PerceiveRequest:
    """What to perceive and how (the options of ``lesmc perceive``, docs/cli.md)."""

    frames_dir: str
    nets: NetFiles = (None, None, None)  #: (--nets, --detector, --locator); None: shipped
    cnn: bool = True  #: False: the front end only (candidates Q_bc), no scene
    scene: bool = True  #: compute payoffs and make the scene (needs the CNN)
    target: str | None = None  #: X,Y[@STEP]: the scene's target (none: a scene without)
    truth: str | None = None  #: truth.json: precision, recall, F1, and target velocities
    tracker: str | None = None  #: a tracker file (JSON/TOML) for the scene
    attack: Literal["deepfool", "pgd"] = "deepfool"
    payoff_norm: Literal["l2", "per-pixel"] = "l2"
    overshoot: float = 0.02
    max_iter: int = 50
    certify: bool = False  #: also certified lower bounds on the payoffs (slow)
    history: int = HISTORY  #: L, previous frames in the background median
    delta_bc: int = DELTA_BC  #: background subtraction threshold (grey levels)
    dt: float | None = None  #: seconds between frames [from the truth, else 1/FPS]
    radius: float = 4.0  #: match distance to the truth (pixels)
    min_speed: float = 1.5  #: slower true vehicles (m/s) are don't care
    #: injection candidates (issue 61): the candidates N_dr rejects within this many px of
    #: a detection, priced towards "vehicle" (None: none; docs/cnn.md, "Injection candidates")
    inject_within: float | None = None
    inject_cap: int = 32  #: with ``inject_within``: at most this many candidates a frame


@dataclass(frozen=True)
class Inputs:
    """The request's files, read and checked before the long work."""

    frames: FrameSet
    spec: TargetSpec | None
    truth: Truth | None
    tracker: TrackerConfig | None


@dataclass
class Perceived:
    """A perceive run: its per-frame figures and, when asked, the scene it made."""

    run: PerceiveRun
    nets: Nets | None
    scene: Scene | Footage | None  #: a Scene with the target, a Footage without one
    target_note: str  #: where the target was placed, in words


#: Each setting's allowed values, as the command line's options have them.
_RANGES: dict[str, tuple[float, float]] = {
    **FRONTEND_RANGES,
    "overshoot": (0.0, 1.0),
    "max_iter": (1, 10000),
    "radius": (0.1, math.inf),
    "min_speed": (0.0, math.inf),
}


def refuse_mismatched(req: PerceiveRequest) -> None:
    """Settings out of range, and settings that would be ignored, are errors (the
    command line's options have the same ranges)."""
    for name, (lo, hi) in _RANGES.items():
        v = getattr(req, name)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not lo <= v <= hi:
            raise UsageError(f"{name} must be in {lo:g}..{hi:g}, got {v!r}")
    if req.dt is not None and not (isinstance(req.dt, (int, float)) and 0 < req.dt < math.inf):
        raise UsageError(f"dt must be a positive number of seconds, got {req.dt!r}")
    if req.attack not in ("deepfool", "pgd"):
        raise UsageError(f"attack must be 'deepfool' or 'pgd', got {req.attack!r}")
    if req.payoff_norm not in ("l2", "per-pixel"):
        raise UsageError(f"payoff_norm must be 'l2' or 'per-pixel', got {req.payoff_norm!r}")
    if req.scene and not req.cnn:
        raise UsageError("--no-cnn cannot write a scene: payoffs need the CNN")
    if req.target is not None and not req.scene:
        raise UsageError("--target needs -o/--output: it is the target of the scene written")
    if req.certify and not req.scene:
        raise UsageError("--certify needs -o/--output: the bounds go into the scene")
    if req.inject_within is not None:
        w = req.inject_within
        if isinstance(w, bool) or not isinstance(w, (int, float)) or not 0 <= w < math.inf:
            raise UsageError(f"inject_within must be a number of px >= 0, got {w!r}")
        if not req.scene:
            raise UsageError("--inject-within needs -o/--output: the candidates go into the scene")
    cap = req.inject_cap
    if isinstance(cap, bool) or not isinstance(cap, int) or cap < 1:
        raise UsageError(f"inject_cap must be a whole number >= 1, got {cap!r}")
    if not req.cnn and any(req.nets):
        raise UsageError(
            "--nets, --detector and --locator give the CNNs that --no-cnn leaves out: give one "
            "or the other"
        )


def open_inputs(req: PerceiveRequest, minimum: int | None = None) -> Inputs:
    """The frames (at least ``minimum``, default L + 1), the target asked for and the truth,
    each checked against the others, and the tracker file's configuration."""
    from lesmc.perception.quality import load_truth
    from lesmc.scene import load_tracker
    from lesmc.tracking.targets import check_target, parse_target
    from lesmc.video.reader import open_frames

    spec = parse_target(req.target) if req.target else None
    frames = open_frames(req.frames_dir, req.history + 1 if minimum is None else minimum)
    if spec is not None:
        check_target(spec, frames.width, frames.height, len(frames))
    truths = load_truth(req.truth) if req.truth else None
    if truths is not None:
        missing = [p.name for p in frames.paths if p.name not in truths.frames]
        if missing:
            raise InputError(f"no truth for frame {missing[0]}", Location(req.truth or ""))
    tracker = load_tracker(req.tracker) if req.tracker else None
    return Inputs(frames, spec, truths, tracker)


def attack_config(req: PerceiveRequest) -> AttackConfig:
    """How the scene's payoffs are computed (docs/cnn.md, "Attack settings")."""
    from lesmc.perception.attack_settings import AttackConfig

    norm: Literal["l2", "per-pixel"] = req.payoff_norm
    return AttackConfig(req.attack, overshoot=req.overshoot, max_iter=req.max_iter, norm=norm)


def perceive_frames(
    req: PerceiveRequest, inputs: Inputs, on_frame: Callable[[], None] | None = None
) -> Perceived:
    """Run the detector over the frames; with ``req.scene``, the payoffs and the scene."""
    from lesmc.perception.certify import CertifyConfig
    from lesmc.perception.cnn import load_nets
    from lesmc.perception.run import PerceiveOptions, perceive

    nets = load_nets(*req.nets) if req.cnn else None
    att = attack_config(req) if req.scene else None
    cert = CertifyConfig() if req.certify else None
    opts = PerceiveOptions(
        req.history, req.delta_bc, nets, att, cert, req.radius, req.min_speed,
        inject_within=req.inject_within if req.scene else None,
        inject_cap=req.inject_cap,
    )  # fmt: skip
    run = perceive(inputs.frames, opts, inputs.truth, on_frame)
    if nets is None or att is None:
        return Perceived(run, nets, None, "")
    dt = req.dt or (inputs.truth.dt if inputs.truth else None) or 1 / FPS
    scene, note = _scene(run, dt, scene_meta(req, nets.settings.trained_on, cert), inputs)
    return Perceived(run, nets, scene, note)


@dataclass
class PerceivedWithFile:
    """A run of a detector file (docs/detectors.md) over the frames: its detections and,
    with ``req.scene``, the scene."""

    detector: LoadedDetector
    detections: list[HeatmapDetections] | list[BoxDetections]
    scene: Scene | Footage | None
    target_note: str


def perceive_with_file(
    req: PerceiveRequest,
    path: str,
    on_start: Callable[[int], Any] | None = None,
    save_attacks: str | None = None,
    priced: bool = True,
) -> PerceivedWithFile:
    """The detector file ``path`` on every frame (no front end: lesmc/perception/heatmap.py);
    with ``req.scene`` each detection's payoff (lesmc/perception/heatmap_attack.py; each
    hiding perturbation saved to ``save_attacks`` as FRAME_K.npy) and the footage, its
    target placed when asked for. ``on_start(n_frames)`` gives the per-frame callback.
    ``priced=False`` (no certification): the footage's payoffs are left unpriced, for
    ``lesmc verify`` to price those its models read (lesmc/perception/file_pricing.py)."""
    from lesmc.perception.detector_file import load_detector
    from lesmc.perception.heatmap import check_frames, footage_of, run_detector

    det = load_detector(path)
    if det.spec.kind == "boxes":
        return _with_boxes(req, det, on_start, save_attacks, priced)
    inputs = open_inputs(req, minimum=1)
    det = check_frames(inputs.frames, det, req.frames_dir)
    price = _pricer(req, det, save_attacks) if req.scene and priced else None
    on_frame = on_start(len(inputs.frames)) if on_start else None
    inject = None if req.inject_within is None else (req.inject_within, req.inject_cap)
    dets = run_detector(inputs.frames, det, on_frame, price, inject)
    if not req.scene:
        return PerceivedWithFile(det, dets, None, "")
    dt = req.dt or (inputs.truth.dt if inputs.truth else None) or 1 / FPS
    recorded = file_attack_meta(
        req, det.spec.scale, "the crop covered by the receptive fields of the detection's "
        "nms square",
    )  # fmt: skip
    from lesmc.perception.certify import CertifyConfig

    cert = certify_meta(CertifyConfig()) if req.certify else None
    cands = None
    if req.inject_within is not None:
        cands = candidates_meta(req.inject_within, req.inject_cap, HEATMAP_CANDIDATES)
    footage = footage_of(dets, det, dt, str(Path(req.frames_dir)), recorded, cert, cands)
    scene, note = _placed(footage, inputs)
    return PerceivedWithFile(det, dets, scene, note)


def file_attack_meta(
    req: PerceiveRequest, scale: tuple[float, float], where: str
) -> dict[str, Any]:
    """A detector file's attack settings and notes (its input's ``scale``, the part of the
    frame ``where`` a perturbation may change), for the scene's ``meta.attack``."""
    from lesmc.scene.meta_attack import AttackNotes

    att = attack_config(req)
    notes = AttackNotes(
        input=f"the detector file's network input (1, C, H, W), units {list(scale)}",
        where=where,
    )
    return {
        "method": att.method, "overshoot": att.overshoot, "max_iter": att.max_iter,
        "converged": att.converged, "norm": "l2",
    } | notes.meta()  # fmt: skip


def _with_boxes(
    req: PerceiveRequest,
    det: LoadedDetector,
    on_start: Callable[[int], Any] | None,
    save_attacks: str | None,
    priced: bool = True,
) -> PerceivedWithFile:
    """:func:`perceive_with_file` for a box-list detector (lesmc/perception/boxes.py):
    attack-only, certified bounds are refused; ``priced=False``: payoffs left unpriced."""
    from lesmc.perception.boxes import footage_of_boxes, price_boxes, run_boxes
    from lesmc.perception.detector_file import located
    from lesmc.perception.file_pricing import refuse_uncertifiable
    from lesmc.perception.heatmap import check_frames
    from lesmc.perception.heatmap_attack import saver

    if req.certify:
        refuse_uncertifiable(det)
    if req.inject_within is not None:
        raise located(
            det.spec, "kind",
            "box-list detectors offer no injection candidates: --inject-within reads a "
            "heatmap detector's local maxima below its threshold (docs/detectors.md)",
        )  # fmt: skip
    inputs = open_inputs(req, minimum=1)
    det = check_frames(inputs.frames, det, req.frames_dir)
    att = attack_config(req)

    def price(frame: Any, bd: BoxDetections) -> BoxDetections:
        save = None if save_attacks is None else saver(save_attacks, bd.index)
        return price_boxes(det, frame, bd, att, save)

    on_frame = on_start(len(inputs.frames)) if on_start else None
    dets = run_boxes(inputs.frames, det, on_frame, price if req.scene and priced else None)
    if not req.scene:
        return PerceivedWithFile(det, dets, None, "")
    dt = req.dt or (inputs.truth.dt if inputs.truth else None) or 1 / FPS
    recorded = file_attack_meta(req, det.spec.scale, "the whole frame")
    footage = footage_of_boxes(dets, det, dt, str(Path(req.frames_dir)), recorded)
    scene, note = _placed(footage, inputs)
    return PerceivedWithFile(det, dets, scene, note)


def _pricer(req: PerceiveRequest, det: LoadedDetector, save_attacks: str | None) -> Any:
    """``price(frame input, detections)`` with the request's attack settings."""
    from lesmc.perception.heatmap_attack import (
        price_candidates,
        price_frame,
        pricing,
        raw_threshold,
        saver,
    )

    how = pricing(det, attack_config(req))
    conv = None
    if req.certify:
        from lesmc.perception.heatmap_certify import certifiable

        conv = certifiable(det)  # refused before the first frame

    def price(frame: Any, fd: HeatmapDetections) -> HeatmapDetections:
        save = None if save_attacks is None else saver(save_attacks, fd.index)
        pays = price_frame(how, frame, fd, save)
        if req.inject_within is not None:
            keys = fd.cand_keys
            save_c = None if save_attacks is None else saver(save_attacks, fd.index, keys)
            fd = replace(fd, cand_payoffs=price_candidates(how, frame, fd, save_c))
        if conv is None:
            return replace(fd, payoffs=pays)
        from lesmc.perception.heatmap_certify import certify_frame

        lower = certify_frame(det, frame, fd, pays, raw_threshold(det), conv=conv)
        return replace(fd, payoffs=pays, lower=lower)

    return price


def scene_meta(
    req: PerceiveRequest, trained_on: str, cert: CertifyConfig | None = None
) -> dict[str, Any]:
    """How the scene's detections and payoffs were made (its ``meta``); ``cert``: the
    settings the certified lower bounds were computed with, if any."""
    from lesmc.scene.meta_attack import AttackNotes

    att = attack_config(req)
    notes = AttackNotes(input="N_dr window, 21x21 x (m+1) frames", pixel_scale="[0, 1]")
    meta: dict[str, Any] = {
        "source": str(Path(req.frames_dir)),
        "detector": trained_on,
        "attack": {
            "method": att.method,
            "overshoot": att.overshoot,
            "max_iter": att.max_iter,
            "converged": att.converged,
            "norm": att.norm,
        }
        | notes.meta(),
    }
    meta |= networks_meta(req.nets)
    # the front end's settings: a replay of the scene's counterexamples reruns it with them
    meta["frontend"] = {"history": req.history, "delta_bc": req.delta_bc}
    if cert is not None:
        meta["certify"] = certify_meta(cert)
    if req.inject_within is not None:
        meta["candidates"] = candidates_meta(req.inject_within, req.inject_cap)
    return meta


#: ``meta.candidates`` source and payoff of the window pipeline's injection candidates.
WINDOW_CANDIDATES = (
    "candidates of Q_bc that N_dr rejects",
    "the attack towards 'vehicle' on the candidate's N_dr window",
)
#: ... and of a heatmap detector file's (docs/detectors.md, "Injection candidates").
HEATMAP_CANDIDATES = (
    "local maxima of the heatmap below the threshold, ids FRAME:cK (K: the place among "
    "the frame's sub-threshold maxima, row-major)",
    "the L2 norm of the smallest perturbation found of the crop covered by the receptive "
    "fields of the candidate's nms square after which the decoded frame has a detection "
    "at the candidate's cell",
)


def candidates_meta(
    within: float, cap: int, how: tuple[str, str] = WINDOW_CANDIDATES
) -> dict[str, Any]:
    """Where a perceived scene's injection candidates came from, for its ``meta.candidates``
    (``how``: their source and payoff)."""
    return {
        "source": how[0],
        "within_px": within,
        "cap_per_frame": cap,
        "payoff": how[1],
    }


def certify_meta(cert: CertifyConfig) -> dict[str, Any]:
    """The settings certified lower bounds were computed with, for a scene's
    ``meta.certify``."""
    return {
        "method": "CROWN, L2 ball",
        "steps": cert.steps,
        "grow_slack": cert.grow_slack,
        "start": cert.start if cert.start_model is None else list(cert.start_model),
        "model_slack": cert.model_slack,
    }


def networks_meta(nets: NetFiles) -> dict[str, Any]:
    """The networks' files as perceive was given them (``--nets``, ``--detector``,
    ``--locator``), for a scene's ``meta.networks``: what a replay must load again
    (lesmc.pipeline.check.replay_command); none for the shipped networks."""
    given = dict(zip(("nets", "detector", "locator"), nets, strict=True))
    named = {k: str(v) for k, v in given.items() if v is not None}
    return ({"networks": named} if named else {}) | {"network_files": network_files(nets)}


def network_files(nets: NetFiles) -> dict[str, dict[str, str]]:
    """Each file the window pipeline's networks were loaded from, by role (``settings``:
    the pair's nets.json; ``N_dr``, ``N_lp``: the user's file where given, else the
    pair's weights), with the sha256 of its bytes: a scene's ``meta.network_files``."""
    from lesmc.common.files import file_sha256
    from lesmc.experiment.cache import net_files

    settings, dr, lp = net_files((nets[0], None, None))
    files = {
        "settings": settings,
        "N_dr": Path(nets[1]) if nets[1] else dr,
        "N_lp": Path(nets[2]) if nets[2] else lp,
    }
    return {role: {"path": str(p), "sha256": file_sha256(p)} for role, p in files.items()}


def _scene(
    run: PerceiveRun, dt: float, meta: dict[str, Any], inputs: Inputs
) -> tuple[Scene | Footage, str]:
    """The footage of ``run``, its tracker replaced by the tracker file's, with the
    target placed when one was asked for; and where the target is, in words."""
    from lesmc.perception.to_scene import footage_from_run

    return _placed(footage_from_run(run, dt, meta), inputs)


def _placed(footage: Footage, inputs: Inputs) -> tuple[Scene | Footage, str]:
    """``footage`` with the tracker file's tracker, and the target placed when one was asked
    for; and where the target is, in words."""
    from lesmc.experiment.targets import target_scene

    if inputs.tracker is not None:
        footage = replace(footage, tracker=inputs.tracker)
    if inputs.spec is None:
        return footage, "no target (give --target to check, build or verify)"
    placed = target_scene(footage, inputs.spec, inputs.frames, inputs.truth)
    note = f"target at step {placed.target.step}, velocity {placed.meta['target_velocity_from']}"
    return placed, note
