"""Replaying injection counterexamples (``allow hide, inject``, issue 61) on the window
pipeline.

Under ``attack window L..U allow hide, inject`` the results list no
hidden detections the replay can use (the ranks are ordered by cost), so at each
window step of ``single``'s counterexample the replay derives the attack from the
model's path: the tracker's prediction from the model's state at the step before
(:func:`~lesmc.tracking.single.carried_prediction`) and the measurement the path
takes give the cheapest way to force it (:func:`~lesmc.tracking.parts.attacker.forcing_update`):
hide every detection before it, and if it is an injection candidate (``FRAME:cROW``,
a window of Q_bc that N_dr rejects) perturb that window towards "vehicle" until
N_dr accepts it. The frame's perturbations are applied together and the frame
detected again, as for hiding (lesmc/replay/perturbed.py); the recomputed cost of the
path's attacks must equal its optimum (``minimize payoff``). A skip that only an attack
forces is not derived: the replay then diverges there.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from lesmc.common.errors import InputError, Location
from lesmc.common.memory import release
from lesmc.perception.windows import cut, stack
from lesmc.replay.case import (
    DET_TOL_PX,
    PERTURBATION_DIGITS,
    Case,
    FrameAttack,
)
from lesmc.replay.perturbed import (
    Round,
    accepted_rows,
    diagnose,
    hidden_indices,
    nearest_within,
    perturb,
    perturbation,
    redetect,
    repair_frame,
)
from lesmc.results.read import HiddenDoc as Hidden
from lesmc.scene import tracker_from_dict

if TYPE_CHECKING:
    from lesmc.perception.attack_settings import AttackConfig
    from lesmc.perception.cnn import Nets
    from lesmc.perception.detector import Detector, FrameDetections
    from lesmc.perception.frontend import FrontEndOutput


def inject_frame(
    nets: Nets,
    det: Detector,
    out: FrontEndOutput,
    fd: FrameDetections,
    case: Case,
    step: int,
    cfg: AttackConfig,
    repair: bool = True,
) -> FrameAttack:
    """Step ``step`` of an ``allow hide, inject`` counterexample (``case``) on its clean
    frame: the cheapest attack that makes the tracker take the path's measurement there
    (hide the detections before it; inject it if it is a candidate), each window attacked
    alone, all perturbations applied together, the frame detected again (with ``repair``,
    detections the model does not have hidden too, as :func:`attack_frame` does)."""
    from lesmc.perception.cnn import DR_SIZE

    m_nets = nets.settings.m
    fa = FrameAttack(fd.index, step, fd)
    taken = case.obs[step - 1]
    if taken is None:  # a skip: not derived (the comparison says if the tracker skips too)
        return fa
    hidden, row = _forced(case, step, fd, out, taken)
    idx = hidden_indices(fd, hidden)
    rounds: list[Round] = []
    if idx:
        rounds.append(_hide_round(nets, det, out, fd, fa, hidden, idx, cfg))
    if row is not None:
        rounds.append(_inject_round(nets, out, fa, step, taken, row, cfg))
    release()
    if not rounds:
        return fa
    base = stack(out.frame, out.aligned.frames, m_nets)
    after, kept = redetect(det, out, perturb(base, rounds, DR_SIZE), m_nets)
    diagnose(fa, fd, after, idx)
    wanted = None if row is None else out.candidates.centroid[[row]]
    if repair:
        after = repair_frame(nets, det, out, fd, fa, idx, rounds, after, kept, cfg, wanted)
    if wanted is not None:  # the injected detection is wanted: not an extra one
        if nearest_within(wanted, after.positions, DET_TOL_PX)[0] < 0:
            fa.not_injected.append(taken)
        cx, cy = float(wanted[0, 0]), float(wanted[0, 1])
        fa.extra = [e for e in fa.extra if math.hypot(e[0] - cx, e[1] - cy) > DET_TOL_PX]
    fa.detections = after
    return fa


def _forced(
    case: Case, step: int, fd: FrameDetections, out: FrontEndOutput, taken: str
) -> tuple[list[Hidden], int | None]:
    """The detections to hide and the candidate (its row of Q_bc; None: none) to inject
    so that the tracker takes ``taken`` at ``step``: the cheapest way
    (tracking/parts/attacker.py ``forcing_update``), measured from the tracker's
    prediction out of the model's state at the step before."""
    from lesmc.perception.to_scene import candidate_row
    from lesmc.tracking.kalman import matrices, measure
    from lesmc.tracking.parts.attacker import forcing_update
    from lesmc.tracking.single import carried_prediction

    km = matrices(tracker_from_dict(case.tracker, "results: replay_inputs.tracker"), case.dt)
    at = measure(km, carried_prediction(km, case.states[step - 1][None], fd.from_prev))[0]
    det_dist = np.linalg.norm(fd.positions - at, axis=1)
    row = candidate_row(taken)
    cands = out.candidates.centroid
    if row is None:
        hid, _ = forcing_update(det_dist, np.zeros(0), int(taken.split(":")[1]), False)
    elif row < len(cands):
        case.known[taken] = (float(cands[row, 0]), float(cands[row, 1]))
        hid, _ = forcing_update(det_dist, np.linalg.norm(cands[[row]] - at, axis=1), 0, True)
    else:
        raise InputError(
            f"frame {fd.index} has {len(cands)} candidates, not {taken}: the frames are "
            "not those the results were made from",
            Location("--frames"),
        )
    nan = math.nan
    return [Hidden(step, fd.index, f"{fd.index}:{int(j)}", nan, nan, nan) for j in hid], row


def _hide_round(
    nets: Nets,
    det: Detector,
    out: FrontEndOutput,
    fd: FrameDetections,
    fa: FrameAttack,
    hidden: list[Hidden],
    idx: list[int],
    cfg: AttackConfig,
) -> Round:
    """The hiding attacks of one frame of an injection counterexample, each blob once; their
    costs and perturbations into ``fa`` (each detection costs its blob's payoff)."""
    from lesmc.perception.attacks import payoffs

    blobs_used = sorted({int(fd.source[j]) for j in idx})
    res = payoffs(nets.dr, fd.windows[blobs_used], nets.settings.delta_dr, cfg)
    accepted = fd.accepted if fd.accepted is not None else accepted_rows(det, out)
    centres = out.candidates.centroid[accepted[blobs_used]]
    by_blob = dict(zip(blobs_used, range(len(blobs_used)), strict=True))
    for h, j in zip(hidden, idx, strict=True):
        r = by_blob[int(fd.source[j])]
        rec, ok = float(res.payoff[r]), bool(res.flipped[r])
        fa.cost += rec
        # the results record no per-detection payoff under inject: the recomputed one
        # stands in, and the path's cost is checked as a whole (_replay_case)
        h = replace(h, payoff=rec)
        fa.perturbations.append(perturbation(h, j, fd, centres[r], rec, ok, res.perturbation[r]))
    return centres, res.perturbation


def _inject_round(
    nets: Nets,
    out: FrontEndOutput,
    fa: FrameAttack,
    step: int,
    taken: str,
    row: int,
    cfg: AttackConfig,
) -> Round:
    """The attack towards "vehicle" on candidate ``row``'s N_dr window (the one that priced
    it); its cost and perturbation into ``fa``."""
    from lesmc.perception.attacks import payoffs
    from lesmc.perception.cnn import DR_SIZE

    frames = stack(out.frame, out.aligned.frames, nets.settings.m)
    centre = out.candidates.centroid[[row]]
    inj = payoffs(nets.dr, cut(frames, centre, DR_SIZE), nets.settings.delta_dr, cfg, "inject")
    rec, ok = float(inj.payoff[0]), bool(inj.flipped[0])
    fa.cost += rec
    fa.injected.append(taken)
    shown: float | str = rec if math.isfinite(rec) else "inf"
    fa.perturbations.append(
        {
            "step": step,
            "frame": fa.frame,
            "obs": taken,
            "x": float(centre[0, 0]),
            "y": float(centre[0, 1]),
            "window_origin": [int(v) for v in np.rint(centre[0]).astype(int) - DR_SIZE // 2],
            "payoff": shown,
            "payoff_recomputed": shown,
            "flipped_alone": ok,
            "action": "inject",
            "delta": np.round(inj.perturbation[0], PERTURBATION_DIGITS).tolist(),
        }
    )
    return centre, inj.perturbation


def inject_cases(
    nets: Nets,
    det: Detector,
    out: FrontEndOutput,
    fd: FrameDetections,
    todo: list[Case],
    by_inject: dict[int, list[tuple[int, int]]],
    attacked: list[dict[int, FrameAttack]],
    cfg: AttackConfig,
    repair: bool,
) -> None:
    """The ``allow hide, inject`` cases' attacks of frame ``fd`` (:func:`inject_frame`) into
    ``attacked``, where they attack it."""
    for ci, step in by_inject.get(fd.index, []):
        fa = inject_frame(nets, det, out, fd, todo[ci], step, cfg, repair)
        if fa.perturbations:
            attacked[ci][fd.index] = fa


def inject_by_frame(todo: list[Case]) -> dict[int, list[tuple[int, int]]]:
    """Per frame, the ``allow hide, inject`` cases attacked there: (case number, step), one
    for every step of the case's window (:func:`inject_frame` derives the attack)."""
    out: dict[int, list[tuple[int, int]]] = {}
    for ci, c in enumerate(todo):
        if not c.injects:
            continue
        for k in range(max(c.window[0], 1), min(c.window[1], len(c.positions) - 1) + 1):
            out.setdefault(c.first_frame + k, []).append((ci, k))
    return out
