"""Replaying counterexamples through a detector file (docs/detectors.md, "Replay").

The window pipeline's replay (run.py) reruns its front end and N_dr; a scene made
with a detector file is replayed through that file's network instead:

1. every frame up to the counterexamples' last goes through the network and is
   decoded; every detection the results name must come out where they say;
2. at each attacked frame, each hidden detection's attack is run again with the
   scene's recorded settings (lesmc/perception/heatmap_attack.py, boxes.py; the
   recomputed payoff must equal the recorded one), and the perturbations of all
   the frame's hidden detections are added together to the network's input;
3. the perturbed frame is decoded: a hidden detection still there, another one
   lost, or an extra one is reported;
4. the tracker runs over the replayed detections and its track is compared with
   the counterexample's, as run.py does: ``confirmed`` or ``diverged``.

No repair is tried: perturbations of a frame add up in the input, and the
replay says whether their sum still hides every hidden detection.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from lesmc.common.errors import InputError, Location, UsageError
from lesmc.replay.case import DET_TOL_PX, PAYOFF_RTOL, PERTURBATION_DIGITS, FrameAttack, cases
from lesmc.replay.perturbed import hidden_indices
from lesmc.replay.run import Outcome, _check_known, _hidden_by_frame, _replay_case
from lesmc.results.read import HiddenDoc as Hidden
from lesmc.results.read import ResultsDoc

if TYPE_CHECKING:
    from lesmc.common.progress import Bar
    from lesmc.perception.attack_settings import AttackConfig
    from lesmc.perception.detector_file import LoadedDetector


@dataclass(frozen=True)
class Decoded:
    """One frame's decoded detections as the replay needs them: (n, 2) positions (and no
    homography: a detector file's scene has a still camera)."""

    index: int
    positions: np.ndarray
    raw: Any  #: the detector's own detections (HeatmapDetections or BoxDetections)
    from_prev: None = None


def replay_with_file(
    doc: ResultsDoc, frames_dir: str, path: str, prop: str | None, bar: Bar
) -> Outcome:
    """``lesmc replay RESULTS --frames DIR --detector FILE.toml``: every violated
    property's counterexample (or ``prop``'s) replayed through the detector file."""
    from lesmc.perception.detector_file import load_detector
    from lesmc.perception.heatmap import check_frames, frame_input
    from lesmc.video.reader import open_frames

    t0 = time.monotonic()
    todo = cases(doc, prop)
    injecting = next((c for c in todo if c.injects), None)
    if injecting is not None:  # not built: refused rather than misread as a mismatch
        raise UsageError(
            f"property {injecting.prop} ({injecting.design}) lets the attacker inject "
            "(allow hide, inject): replaying injections through a detector file is not "
            'built yet (docs/detectors.md, "Replay"); give --property to replay another'
        )
    det = load_detector(path)
    frames = open_frames(frames_dir, 1)
    det = check_frames(frames, det, frames_dir)
    if not todo:
        return Outcome({}, 0.0)
    cfg = _attack_settings(doc)
    off = next((r.replay_inputs.frames_offset for r in doc.runs if r.replay_inputs), 0)
    last = max(c.first_frame + len(c.positions) - 1 for c in todo)
    if last + off >= len(frames):
        raise InputError(
            f"the frames stop before frame {last + off}, the last step of a counterexample",
            Location("--frames"),
        )
    by_frame = _hidden_by_frame(todo)
    attacked: list[dict[int, FrameAttack]] = [{} for _ in todo]
    clean: dict[int, Decoded] = {}
    bar.update(total=last + 1 + len(by_frame))
    for i in range(max(0, -off), last + 1):  # scene frame i is the directory's i + off
        clean[i] = _decode(det, frame_input(frames, i + off, det), i)
        bar.advance()
    for c in todo:  # every detection the results name, where they say, before any attack
        _check_known(c, clean)  # type: ignore[arg-type]  # Decoded has what it reads
    for i, items in sorted(by_frame.items()):
        x = frame_input(frames, i + off, det)
        per_case: dict[int, list[Hidden]] = {}
        for ci, h in items:
            per_case.setdefault(ci, []).append(h)
        for ci, hidden in per_case.items():
            attacked[ci][i] = attack_frame(det, x, clean[i], hidden, cfg)
        bar.advance()
    replays = {
        (c.run, c.result): _replay_case(c, clean, attacked[ci])  # type: ignore[arg-type]
        for ci, c in enumerate(todo)
    }
    return Outcome(replays, time.monotonic() - t0)


def _attack_settings(doc: ResultsDoc) -> AttackConfig:
    """The attack settings the payoffs were made with: the results' (``perception``), else
    those of the scene they name (``meta.scene``, its ``meta.attack``), else the defaults."""
    from pathlib import Path

    from lesmc.common.files import read_json
    from lesmc.perception.attack_settings import AttackConfig, attack_of

    if doc.perception.attack:
        return AttackConfig(**doc.perception.attack)
    scene = doc.meta.get("scene")
    if isinstance(scene, str) and Path(scene).is_file():
        raw = read_json(scene)
        meta = raw.get("meta") if isinstance(raw, dict) else None
        if isinstance(meta, dict):
            return attack_of(meta, scene)
    return AttackConfig()


def _decode(det: LoadedDetector, x: np.ndarray, index: int) -> Decoded:
    """Frame ``index`` (network input ``x``) through the detector, decoded."""
    import torch

    with torch.no_grad():
        y = det.net.module(torch.from_numpy(np.ascontiguousarray(x, np.float32)))
    if det.spec.kind == "boxes":
        from lesmc.perception.boxes import decode_boxes

        bd = decode_boxes(y[0].double().numpy(), det, index)
        return Decoded(index, bd.positions, bd)
    from lesmc.perception.heatmap import decode

    fd = decode(y.reshape(det.cells).double().numpy(), det, index)
    return Decoded(index, fd.positions, fd)


def attack_frame(
    det: LoadedDetector,
    x: np.ndarray,
    clean: Decoded,
    hidden: list[Hidden],
    cfg: AttackConfig,
) -> FrameAttack:
    """The hidden detections' attacks run again on frame input ``x``, their perturbations
    added together, the frame decoded again."""
    idx = hidden_indices(clean, hidden)  # type: ignore[arg-type]  # reads positions only
    deltas = _perturbations(det, x, clean, idx, cfg)
    fa = FrameAttack(clean.index, hidden[0].step, clean)  # type: ignore[arg-type]
    total = np.zeros_like(x)
    for h, j in zip(hidden, idx, strict=True):
        pay, delta = deltas.get(j, (math.inf, None))
        if delta is not None:
            total += delta
        fa.perturbations.append(_record(h, clean, j, pay, delta))
    after = _decode(det, x + total, clean.index)
    _diagnose(det, fa, clean, after, idx)
    fa.detections = after  # type: ignore[assignment]  # Decoded has what the tracker reads
    return fa


def _perturbations(
    det: LoadedDetector, x: np.ndarray, clean: Decoded, idx: list[int], cfg: AttackConfig
) -> dict[int, tuple[float, np.ndarray]]:
    """Detection index -> (payoff, perturbation) of each of ``idx`` that the attack hides."""
    from dataclasses import replace

    got: dict[int, tuple[float, np.ndarray]] = {}
    if det.spec.kind == "boxes":
        from lesmc.perception.boxes import price_boxes

        sub = clean.raw
        one = replace(sub, boxes=sub.boxes[idx], scores=sub.scores[idx], rows=sub.rows[idx])
        deltas: dict[int, np.ndarray] = {}
        priced = price_boxes(det, x, one, cfg, lambda k, d: deltas.__setitem__(k, d))
        pays = priced.payoffs
    else:
        from lesmc.perception.heatmap_attack import price_frame, pricing

        fd = clean.raw
        one = replace(fd, positions=fd.positions[idx], scores=fd.scores[idx], cells=fd.cells[idx])
        deltas = {}
        pays = price_frame(pricing(det, cfg), x, one, lambda k, d: deltas.__setitem__(k, d))
    assert pays is not None
    for k, j in enumerate(idx):
        if k in deltas:
            got[j] = (float(pays[k]), deltas[k])
    return got


def _record(
    h: Hidden, clean: Decoded, j: int, rec: float, delta: np.ndarray | None
) -> dict[str, Any]:
    """One hidden detection's recomputed attack (the replay schema's perturbation: the
    nonzero crop of the network input, C x h x w, and its origin x, y), refused if its
    payoff differs from the results'."""
    if math.isfinite(h.payoff) and not (
        math.isfinite(rec) and abs(rec - h.payoff) <= PAYOFF_RTOL * max(h.payoff, 1e-9)
    ):
        raise InputError(
            f"the attack on detection {h.obs} now costs {rec:g}, the results say "
            f"{h.payoff:g}: the frames, detector file or attack settings differ from the run "
            "that wrote the results",
            Location("--frames"),
        )
    crop: list[Any] = []
    origin = [0, 0]
    if delta is not None and np.any(delta):
        ys, xs = np.nonzero(np.abs(delta[0]).sum(axis=0))
        y0, y1, x0, x1 = int(ys.min()), int(ys.max()) + 1, int(xs.min()), int(xs.max()) + 1
        origin = [x0, y0]
        crop = np.round(delta[0, :, y0:y1, x0:x1].astype(np.float64), PERTURBATION_DIGITS).tolist()
    return {
        "step": h.step,
        "frame": clean.index,
        "obs": h.obs,
        "x": float(clean.positions[j, 0]),
        "y": float(clean.positions[j, 1]),
        "window_origin": origin,
        "payoff": h.payoff,
        "payoff_recomputed": rec if math.isfinite(rec) else "inf",
        "flipped_alone": delta is not None,
        "delta": crop,
    }


def _diagnose(
    det: LoadedDetector, fa: FrameAttack, clean: Decoded, after: Decoded, idx: list[int]
) -> None:
    """What the frame's perturbations did: hidden detections still there, other detections
    lost or moved, extra detections."""
    a, b = clean.positions, after.positions
    for j in range(len(a)):
        d = np.hypot(*(b - a[j]).T) if len(b) else np.zeros(0)
        near = float(d.min()) if len(d) else math.inf
        did = f"{clean.index}:{j}"
        if j in idx:
            if _still(det, clean, after, j):
                fa.still.append(did)
        elif near > DET_TOL_PX:
            fa.lost.append(did)
        elif near > 0:
            fa.moved.append((did, near))
    for q in range(len(b)):
        d = np.hypot(*(a - b[q]).T) if len(a) else np.zeros(0)
        far = not len(d) or float(d.min()) > DET_TOL_PX
        if far and not any(_covers(det, clean, j, after, q) for j in idx):
            fa.extra.append((float(b[q, 0]), float(b[q, 1])))


def _still(det: LoadedDetector, clean: Decoded, after: Decoded, j: int) -> bool:
    """Hidden detection ``j`` is still detected after the perturbation (a detection in its
    square, heatmap; a box overlapping it by IoU >= 0.5, boxes)."""
    return any(_covers(det, clean, j, after, q) for q in range(len(after.positions)))


def _covers(det: LoadedDetector, clean: Decoded, j: int, after: Decoded, q: int) -> bool:
    """Detection ``q`` after the perturbation counts as clean detection ``j``."""
    if det.spec.kind == "boxes":
        from lesmc.perception.boxes import HIDE_IOU, iou

        return bool(iou(clean.raw.boxes[j], after.raw.boxes[q : q + 1])[0] >= HIDE_IOU)
    r = det.spec.nms_radius
    ci, cj = clean.raw.cells[j]
    ai, aj = after.raw.cells[q]
    return abs(int(ai) - int(ci)) <= r and abs(int(aj) - int(cj)) <= r
