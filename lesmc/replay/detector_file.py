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

When the sum of a frame's perturbations does not leave the detections the model has
(a hidden detection survives, an extra one appears, an injected candidate is not
detected), the attack is repaired as the window pipeline's is (docs/semantics.md,
"Repaired attack"; the loop is lesmc/replay/repair.py's): up to REPAIR_ROUNDS rounds,
each attacking, on the input as every perturbation so far leaves it, the detections
the model does not have (the same hiding attack, heatmap or boxes), then raising the
injected candidates not detected (``price_candidates``), the frame decoded after each
(:class:`_FileFrame`); the extra payoffs are the ``repair_cost``.

Under ``allow hide, inject`` (heatmap files; issue 61) the attack of each window step is
derived from the path as lesmc/replay/inject.py does for the window pipeline
(:func:`inject_frame`): the detections to hide and the candidates ``k:cK`` to inject,
each candidate's raise above the threshold recomputed (``price_candidates``) and added
to the frame with the hiding perturbations.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from lesmc.common.errors import InputError, Location, UsageError
from lesmc.replay.case import (
    DET_TOL_PX,
    PERTURBATION_DIGITS,
    REPAIR_ROUNDS,
    Case,
    FrameAttack,
    cases,
    check_payoff,
    forced_skip,
    group_by_case,
    hidden_by_frame,
    perturbation_record,
)
from lesmc.replay.inject import inject_by_frame, single_forcing
from lesmc.replay.joint_forcing import derive_joint
from lesmc.replay.perturbed import hidden_indices
from lesmc.replay.repair import run_repair
from lesmc.replay.run import Outcome, check_known, replay_case
from lesmc.results.read import HiddenDoc as Hidden
from lesmc.results.read import ResultsDoc

if TYPE_CHECKING:
    from lesmc.common.progress import Bar
    from lesmc.perception.attack_settings import AttackConfig
    from lesmc.perception.attacks import Towards
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
    det = load_detector(path)
    injecting = next((c for c in todo if c.injects), None)
    if injecting is not None and det.spec.kind == "boxes":  # a box list has no candidates
        raise UsageError(
            f"property {injecting.prop} ({injecting.design}) lets the attacker inject "
            "(allow hide, inject): a box-list detector file has no injection candidates "
            '(docs/detectors.md, "Replay"); give --property to replay another'
        )
    frames = open_frames(frames_dir, 1)
    det = check_frames(frames, det, frames_dir)
    if not todo:
        return Outcome({}, 0.0)
    derive_joint(doc.meta, todo)
    cfg = _attack_settings(doc)
    off = next((r.replay_inputs.frames_offset for r in doc.runs if r.replay_inputs), 0)
    last = max(c.first_frame + len(c.positions) - 1 for c in todo)
    if last + off >= len(frames):
        raise InputError(
            f"the frames stop before frame {last + off}, the last step of a counterexample",
            Location("--frames"),
        )
    by_frame, by_inject = hidden_by_frame(todo), inject_by_frame(todo)
    attacked: list[dict[int, FrameAttack]] = [{} for _ in todo]
    clean: dict[int, Decoded] = {}
    bar.update(total=last + 1 + len(set(by_frame) | set(by_inject)))
    for i in range(max(0, -off), last + 1):  # scene frame i is the directory's i + off
        clean[i] = _decode(det, frame_input(frames, i + off, det), i)
        bar.advance()
    for c in todo:  # every detection the results name, where they say, before any attack
        check_known(c, clean)  # type: ignore[arg-type]  # Decoded has what it reads
    for i in sorted(set(by_frame) | set(by_inject)):
        x = frame_input(frames, i + off, det)
        for ci, hidden in group_by_case(by_frame.get(i, [])):
            attacked[ci][i] = attack_frame(det, x, clean[i], hidden, cfg)
        for ci, step in by_inject.get(i, []):
            fa = inject_frame(det, x, clean[i], todo[ci], step, cfg)
            if fa.perturbations:
                attacked[ci][i] = fa
        bar.advance()
    replays = {
        (c.run, c.result): replay_case(c, clean, attacked[ci])  # type: ignore[arg-type]
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

    fd = decode(det.score_maps(y)[0].double().numpy(), det, index)
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
    frame = _FileFrame(det, (x, total), clean, fa, idx, cfg)
    run_repair(fa, frame, REPAIR_ROUNDS)
    fa.detections = frame.after  # type: ignore[assignment]  # Decoded has what it reads
    return fa


class _FileFrame:
    """A frame through a detector file as :func:`~lesmc.replay.repair.run_repair` sees
    it: the network input ``x`` plus the perturbations so far (``total``), decoded and
    compared with the ``clean`` frame; ``idx`` the hidden detections, ``wanted`` the
    injected candidates' cells ((c, 2); None: nothing injected)."""

    def __init__(
        self,
        det: LoadedDetector,
        inputs: tuple[np.ndarray, np.ndarray],
        clean: Decoded,
        fa: FrameAttack,
        idx: list[int],
        cfg: AttackConfig,
        wanted: np.ndarray | None = None,
    ) -> None:
        self.det, (self.x, self.total), self.clean, self.fa = det, inputs, clean, fa
        self.idx, self.cfg, self.wanted = idx, cfg, wanted
        self.after = clean
        self.apply(np.zeros_like(self.x))

    def wrong(self) -> bool:
        """A detection the model does not have, or an injected candidate not detected."""
        return bool(self._unwanted()) or bool(len(self._missing()))

    def attack(self, towards: Towards) -> tuple[float, int, np.ndarray] | None:
        """``hide``: the detections the model does not have, each attacked as the first
        hiding was (:func:`_perturbations`) on the perturbed input; ``inject``: the
        candidates not detected, each raised again (``price_candidates``). The cost
        (their payoffs), their number and the sum of the perturbations found (None:
        none)."""
        now = self.x + self.total
        if towards == "hide":
            rows = self._unwanted()
            got = _perturbations(self.det, now, self.after, rows, self.cfg) if rows else {}
            found = list(got.values())
        else:
            found = _raise(self.det, now, self.after, self._missing(), self.cfg)
        if not found:
            return None
        more = sum((d for _, d in found), np.zeros_like(self.x))
        return float(sum(pay for pay, _ in found)), len(found), more

    def apply(self, more: np.ndarray) -> None:
        """``more`` added to the input; the frame decoded again and diagnosed."""
        self.total = self.total + more
        self.after = _decode(self.det, self.x + self.total, self.clean.index)
        _diagnose(self.det, self.fa, self.clean, self.after, self.idx, self.wanted)

    def _unwanted(self) -> list[int]:
        """Rows of the perturbed frame's detections within DET_TOL_PX of no clean detection
        the attack keeps, and not at an injected candidate's cell."""
        a, b = self.clean.positions, self.after.positions
        keep = a[[j for j in range(len(a)) if j not in set(self.idx)]]
        out = []
        for q in range(len(b)):
            if len(keep) and float(np.hypot(*(keep - b[q]).T).min()) <= DET_TOL_PX:
                continue
            if self.wanted is not None and (self.wanted == self.after.raw.cells[q]).all(1).any():
                continue
            out.append(q)
        return out

    def _missing(self) -> np.ndarray:
        """The cells of ``wanted`` without a detection of the perturbed frame."""
        if self.wanted is None:
            return np.zeros((0, 2), np.int64)
        got = self.after.raw.cells
        hit = [bool((got == c).all(axis=1).any()) for c in self.wanted]
        out: np.ndarray = self.wanted[~np.array(hit, bool)]
        return out


def _raise(
    det: LoadedDetector, x: np.ndarray, now: Decoded, cells: np.ndarray, cfg: AttackConfig
) -> list[tuple[float, np.ndarray]]:
    """Each of ``cells`` raised to a detection on input ``x`` (``price_candidates``, as an
    injection is priced): (payoff, perturbation) of those it finds a perturbation for."""
    from lesmc.perception.heatmap_attack import price_candidates, pricing

    if not len(cells):
        return []
    deltas: dict[int, np.ndarray] = {}
    one = replace(now.raw, cand_cells=cells, cand_keys=np.arange(len(cells)))
    pays = price_candidates(pricing(det, cfg), x, one, lambda k, d: deltas.__setitem__(k, d))
    return [(float(pays[k]), d) for k, d in sorted(deltas.items())]


def _perturbations(
    det: LoadedDetector, x: np.ndarray, clean: Decoded, idx: list[int], cfg: AttackConfig
) -> dict[int, tuple[float, np.ndarray]]:
    """Detection index -> (payoff, perturbation) of each of ``idx`` that the attack hides."""

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
        one = one if fd.sizes is None else replace(one, sizes=fd.sizes[idx])
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
    check_payoff(h, rec, "detector file")
    origin, crop = _crop(delta)
    pos = (clean.positions[j, 0], clean.positions[j, 1])
    return perturbation_record(
        (h.step, clean.index, h.obs), pos, origin, (h.payoff, rec), delta is not None, crop
    )


def _crop(delta: np.ndarray | None) -> tuple[list[int], list[Any]]:
    """The nonzero crop of a perturbation of the network input (C x h x w) and its origin
    x, y (none: [0, 0] and an empty crop)."""
    if delta is None or not np.any(delta):
        return [0, 0], []
    ys, xs = np.nonzero(np.abs(delta[0]).sum(axis=0))
    y0, y1, x0, x1 = int(ys.min()), int(ys.max()) + 1, int(xs.min()), int(xs.max()) + 1
    crop = np.round(delta[0, :, y0:y1, x0:x1].astype(np.float64), PERTURBATION_DIGITS).tolist()
    return [x0, y0], crop


def _diagnose(
    det: LoadedDetector,
    fa: FrameAttack,
    clean: Decoded,
    after: Decoded,
    idx: list[int],
    wanted: np.ndarray | None = None,
) -> None:
    """What the frame's perturbations did: hidden detections still there, other detections
    lost or moved, extra detections (not those at a cell of ``wanted``, (c, 2) the
    injected candidates' cells)."""
    a, b = clean.positions, after.positions
    fa.still, fa.lost, fa.moved, fa.extra = [], [], [], []  # a repair diagnoses again
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
        if wanted is not None and (wanted == after.raw.cells[q]).all(axis=1).any():
            continue  # an injected detection
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


# ---------------------------------------------------------------- injections (heatmap)


def inject_frame(
    det: LoadedDetector, x: np.ndarray, clean: Decoded, case: Case, step: int, cfg: AttackConfig
) -> FrameAttack:
    """Step ``step`` of an ``allow hide, inject`` counterexample through a heatmap file: the
    cheapest attack that forces the path's outcome (``joint``: ``case.forced``;
    ``single``: :func:`~lesmc.replay.inject.single_forcing`), each detection's hiding and
    each candidate's raising above the threshold (lesmc/perception/heatmap_attack.py)
    recomputed on frame input ``x``, added together, the frame decoded again."""
    hidden, inject = _derived(det, x, clean, case, step)
    return attack_listed(det, (x, clean), step, (hidden, inject), cfg)


def attack_listed(
    det: LoadedDetector,
    seen: tuple[np.ndarray, Decoded],
    step: int,
    attack: tuple[list[Hidden], list[tuple[str, np.ndarray]]],
    cfg: AttackConfig,
) -> FrameAttack:
    """Step ``step``'s attack on its clean frame (``seen``: its network input and its
    decoded detections): hide the detections and inject the candidates (id, cell) of
    ``attack``, each attacked alone, all perturbations added together, the frame decoded
    again and the attack repaired (:class:`_FileFrame`)."""
    x, clean = seen
    hidden, inject = attack
    fa = FrameAttack(clean.index, step, clean)  # type: ignore[arg-type]
    idx = hidden_indices(clean, hidden)  # type: ignore[arg-type]  # reads positions only
    deltas = _perturbations(det, x, clean, idx, cfg) if idx else {}
    total = np.zeros_like(x)
    for h, j in zip(hidden, idx, strict=True):
        pay, delta = deltas.get(j, (math.inf, None))
        total += 0 if delta is None else delta
        fa.cost += pay  # the results record no per-detection payoff under inject: the
        # recomputed one stands in, and the path's cost is checked as a whole (run.py)
        fa.perturbations.append(_record(replace(h, payoff=pay), clean, j, pay, delta))
    cells = _inject(det, x, clean, fa, inject, total, cfg)
    if not fa.perturbations:
        return fa
    frame = _FileFrame(det, (x, total), clean, fa, idx, cfg, cells)
    run_repair(fa, frame, REPAIR_ROUNDS)  # re-hides what survives, re-injects what is not
    after = frame.after
    got = after.raw.cells
    fa.not_injected = [
        cid for (cid, _), c in zip(inject, cells, strict=True) if not (got == c).all(axis=1).any()
    ]
    fa.detections = after  # type: ignore[assignment]  # Decoded has what the tracker reads
    return fa


def _derived(
    det: LoadedDetector, x: np.ndarray, clean: Decoded, case: Case, step: int
) -> tuple[list[Hidden], list[tuple[str, np.ndarray]]]:
    """The detections to hide and the candidates (id, cell) to inject at ``step``; each
    candidate's position into ``case.known``."""
    nan = math.nan
    if case.forced is not None:
        hid, inj = case.forced.get(step, ([], []))
    else:
        taken = case.obs[step - 1]
        if taken is None:  # a skip: hide what the results record hidden there
            return forced_skip(case, step, clean.index), []
        cell = _candidate_cells(det, x, clean.index, [taken])[0] if ":c" in taken else None
        at = None if cell is None else _cell_position(det, cell)
        rows = single_forcing(case, step, clean.positions, None, taken, at)
        hid, inj = [f"{clean.index}:{int(j)}" for j in rows], [] if cell is None else [taken]
    cells = _candidate_cells(det, x, clean.index, inj)
    for cid, c in zip(inj, cells, strict=True):
        p = _cell_position(det, c)
        case.known[cid] = (float(p[0]), float(p[1]))
    hidden = [Hidden(step, clean.index, h, nan, nan, nan) for h in hid]
    return hidden, list(zip(inj, cells, strict=True))


def _candidate_cells(det: LoadedDetector, x: np.ndarray, index: int, ids: list[str]) -> np.ndarray:
    """(c, 2) the cells of candidates ``FRAME:cK`` of frame input ``x``: K-th, row-major,
    of its local maxima below the threshold (lesmc/perception/heatmap.py ``sub_peaks``)."""
    import torch

    from lesmc.perception.detector_file import score_of
    from lesmc.perception.heatmap import sub_peaks
    from lesmc.perception.to_scene import candidate_row

    if not ids:
        return np.zeros((0, 2), np.int64)
    with torch.no_grad():
        y = det.net.module(torch.from_numpy(np.ascontiguousarray(x, np.float32)))
    raw = det.score_maps(y)[0].double().numpy()
    subs = sub_peaks(score_of(raw, det.spec.score), det.spec.threshold, det.spec.nms_radius)
    keys = [candidate_row(cid) for cid in ids]
    for cid, k in zip(ids, keys, strict=True):
        if k is None or not 0 <= k < len(subs):
            raise InputError(
                f"frame {index} has {len(subs)} local maxima below the threshold, not {cid}: "
                "the frames or detector file are not those the results were made from",
                Location("--frames"),
            )
    out: np.ndarray = subs[np.array(keys, np.int64)]
    return out


def _cell_position(det: LoadedDetector, cell: np.ndarray) -> np.ndarray:
    """The input-pixel centre (x, y) of a cell (row, col)."""
    from lesmc.perception.heatmap import cell_positions

    out: np.ndarray = cell_positions(cell[None], det.spec.stride)[0]
    return out


def _inject(
    det: LoadedDetector,
    x: np.ndarray,
    clean: Decoded,
    fa: FrameAttack,
    inject: list[tuple[str, np.ndarray]],
    total: np.ndarray,
    cfg: AttackConfig,
) -> np.ndarray:
    """Each candidate's attack towards a detection at its cell, alone on ``x``
    (``price_candidates``), added into ``total``; costs and records into ``fa``. Returns
    the candidates' cells."""

    from lesmc.perception.heatmap_attack import price_candidates, pricing

    cells = np.array([c for _, c in inject], np.int64).reshape(-1, 2)
    if not len(cells):
        return cells
    deltas: dict[int, np.ndarray] = {}
    one = replace(clean.raw, cand_cells=cells, cand_keys=np.arange(len(cells)))
    pays = price_candidates(pricing(det, cfg), x, one, lambda k, d: deltas.__setitem__(k, d))
    for r, (cid, c) in enumerate(inject):
        delta = deltas.get(r)
        total += 0 if delta is None else delta
        rec = float(pays[r])
        fa.cost += rec
        fa.injected.append(cid)
        origin, crop = _crop(delta)
        p = _cell_position(det, c)
        fa.perturbations.append(
            perturbation_record(
                (fa.step, clean.index, cid),
                (p[0], p[1]),
                origin,
                (rec, rec),
                delta is not None,
                crop,
                inject=True,
            )
        )
    return cells
