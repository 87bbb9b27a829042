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
detected again, as for hiding (lesmc/replay/perturbed.py), and repaired as hiding is:
detections that survive are hidden again and injected candidates not detected are
injected again, on the perturbed frame (``repair_frame``); the recomputed cost of the
path's attacks must equal its optimum (``minimize payoff``). A skip that only an attack
forces hides what the results record hidden at that step
(:func:`~lesmc.replay.case.forced_skip`).
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
    forced_skip,
    perturbation_record,
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
    frame: the cheapest attack that forces the path's outcome there (:func:`_derived`),
    each window attacked alone, all perturbations applied together, the frame detected
    again (with ``repair``, detections the model does not have hidden too, as
    :func:`~lesmc.replay.perturbed.attack_frame` does)."""
    hidden, injected = _derived(case, step, fd, out)
    return attack_listed(nets, det, (out, fd), step, (hidden, injected), cfg, repair)


def attack_listed(
    nets: Nets,
    det: Detector,
    seen: tuple[FrontEndOutput, FrameDetections],
    step: int,
    attack: tuple[list[Hidden], list[tuple[str, int]]],
    cfg: AttackConfig,
    repair: bool = True,
) -> FrameAttack:
    """Step ``step``'s attack on its clean frame (``seen``: the front end's output and the
    frame's detections): hide the detections and inject the candidates (id, row of Q_bc)
    of ``attack``, each window attacked alone, all perturbations applied together, the
    frame detected again (with ``repair``, detections the model does not have hidden too);
    :func:`inject_frame` derives the attack from a point design's path, a multi-target
    counterexample lists it (lesmc/replay/multi.py)."""
    from lesmc.perception.cnn import DR_SIZE

    out, fd = seen
    hidden, injected = attack
    m_nets = nets.settings.m
    fa = FrameAttack(fd.index, step, fd)
    idx = hidden_indices(fd, hidden)
    rounds: list[Round] = []
    if idx:
        rounds.append(_hide_round(nets, det, out, fd, fa, hidden, idx, cfg))
    if injected:
        rounds.append(_inject_round(nets, out, fa, step, injected, cfg))
    release()
    if not rounds:
        return fa
    base = stack(out.frame, out.aligned.frames, m_nets)
    after, cands = redetect(det, out, perturb(base, rounds, DR_SIZE), m_nets)
    diagnose(fa, fd, after, idx)
    wanted = out.candidates.centroid[[row for _, row in injected]] if injected else None
    if repair:  # re-hides what survives and re-injects what is not detected
        after, cands = repair_frame(
            nets, det, out, fd, fa, idx, rounds, (after, cands), cfg, wanted
        )
    if wanted is not None:  # the injected detections are wanted: not extra ones
        fa.overlaps += window_overlaps(fd, idx, injected, wanted)
        missing = nearest_within(wanted, after.positions, DET_TOL_PX) < 0
        fa.not_injected += [cid for (cid, _), m in zip(injected, missing, strict=True) if m]
        gone = missing & (nearest_within(wanted, cands, DET_TOL_PX) < 0)
        fa.no_blob += [cid for (cid, _), g in zip(injected, gone, strict=True) if g]
        near = nearest_within(np.array(fa.extra, float).reshape(-1, 2), wanted, DET_TOL_PX)
        fa.extra = [e for e, j in zip(fa.extra, near, strict=True) if j < 0]
    fa.detections = after
    return fa


def window_overlaps(
    fd: FrameDetections,
    idx: list[int],
    injected: list[tuple[str, int]],
    at: np.ndarray,
) -> list[tuple[str, str]]:
    """The pairs (hidden detection, injected candidate) of one frame whose 21 x 21 N_dr
    windows share pixels (``idx``: the hidden detections' indices, ``at``: the
    candidates' centroids), in :func:`~lesmc.replay.perturbed.diagnose`'s measure: the
    perturbations add up there, and the replay says so rather than pricing them apart."""
    from lesmc.perception.cnn import DR_SIZE

    pairs = []
    for j in sorted(set(idx)):
        for (cid, _), c in zip(injected, at, strict=True):
            if np.all(np.abs(fd.positions[j] - c) <= 2 * (DR_SIZE // 2)):
                pairs.append((f"{fd.index}:{j}", cid))
    return pairs


def _derived(
    case: Case, step: int, fd: FrameDetections, out: FrontEndOutput
) -> tuple[list[Hidden], list[tuple[str, int]]]:
    """The detections to hide and the candidates to inject (id, row of Q_bc) at ``step``:
    on ``joint`` those the walk along the path found (``case.forced``,
    lesmc/replay/joint_forcing.py), on ``single`` the cheapest way to take the path's
    measurement (:func:`_forced`; a skip: :func:`~lesmc.replay.case.forced_skip`)."""
    nan = math.nan
    if case.forced is not None:
        hid, inj = case.forced.get(step, ([], []))
        hidden = [Hidden(step, fd.index, h, nan, nan, nan) for h in hid]
        return hidden, [(cid, _candidate(case, fd, out, cid)) for cid in inj]
    taken = case.obs[step - 1]
    if taken is None:  # a skip: hide what the results record hidden there
        return forced_skip(case, step, fd.index), []
    hidden, row = _forced(case, step, fd, out, taken)
    return hidden, [] if row is None else [(taken, row)]


def _candidate(case: Case, fd: FrameDetections, out: FrontEndOutput, cid: str) -> int:
    """The row of Q_bc of injection candidate ``cid`` (``FRAME:cROW``), its position recorded
    in ``case.known``; refused if the frame has no such candidate."""
    row = candidate_at(fd, out, cid)
    cands = out.candidates.centroid
    case.known[cid] = (float(cands[row, 0]), float(cands[row, 1]))
    return row


def candidate_at(fd: FrameDetections, out: FrontEndOutput, cid: str) -> int:
    """The row of Q_bc of injection candidate ``cid`` (``FRAME:cROW``) on the frame the
    front end made ``out`` of; an input error if the frame has no such candidate."""
    from lesmc.perception.to_scene import candidate_row

    row = candidate_row(cid)
    cands = out.candidates.centroid
    if row is None or not 0 <= row < len(cands):
        raise InputError(
            f"frame {fd.index} has {len(cands)} candidates, not {cid}: the frames are "
            "not those the results were made from",
            Location("--frames"),
        )
    return row


def _forced(
    case: Case, step: int, fd: FrameDetections, out: FrontEndOutput, taken: str
) -> tuple[list[Hidden], int | None]:
    """The detections to hide and the candidate (its row of Q_bc; None: none) to inject
    so that ``single`` takes ``taken`` at ``step`` (:func:`single_forcing`)."""
    from lesmc.perception.to_scene import candidate_row

    row = None if candidate_row(taken) is None else _candidate(case, fd, out, taken)
    at = None if row is None else out.candidates.centroid[row]
    hid = single_forcing(case, step, fd.positions, fd.from_prev, taken, at)
    nan = math.nan
    return [Hidden(step, fd.index, f"{fd.index}:{int(j)}", nan, nan, nan) for j in hid], row


def single_forcing(
    case: Case,
    step: int,
    positions: np.ndarray,
    from_prev: np.ndarray | None,
    taken: str,
    cand_at: np.ndarray | None,
) -> np.ndarray:
    """The detections (indices into the frame's ``positions``) to hide so that ``single``
    takes ``taken`` at ``step``: the cheapest way (tracking/parts/attacker.py
    ``forcing_update``), measured from the tracker's prediction out of the model's state
    at the step before (carried by ``from_prev``, None: a still camera); ``cand_at``: the
    position of ``taken`` when it is an injection candidate (None: a detection)."""
    from lesmc.tracking.kalman import matrices, measure
    from lesmc.tracking.parts.attacker import forcing_update
    from lesmc.tracking.single import carried_prediction

    km = matrices(tracker_from_dict(case.tracker, "results: replay_inputs.tracker"), case.dt)
    at = measure(km, carried_prediction(km, case.states[step - 1][None], from_prev))[0]
    det_dist = np.linalg.norm(positions - at, axis=1)
    if cand_at is None:
        hid, _ = forcing_update(det_dist, np.zeros(0), int(taken.split(":")[1]), False)
    else:
        hid, _ = forcing_update(det_dist, np.linalg.norm(cand_at[None] - at, axis=1), 0, True)
    return hid


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
    injected: list[tuple[str, int]],
    cfg: AttackConfig,
) -> Round:
    """The attacks towards "vehicle" on the injected candidates' N_dr windows (id, row of
    Q_bc: the windows that priced them), each alone; their costs and perturbations into
    ``fa``."""
    from lesmc.perception.attacks import payoffs
    from lesmc.perception.cnn import DR_SIZE

    frames = stack(out.frame, out.aligned.frames, nets.settings.m)
    centres = out.candidates.centroid[[row for _, row in injected]]
    inj = payoffs(nets.dr, cut(frames, centres, DR_SIZE), nets.settings.delta_dr, cfg, "inject")
    for r, (cid, _) in enumerate(injected):
        rec, ok = float(inj.payoff[r]), bool(inj.flipped[r])
        fa.cost += rec
        fa.injected.append(cid)
        fa.perturbations.append(
            perturbation_record(
                (step, fa.frame, cid),
                (centres[r, 0], centres[r, 1]),
                np.rint(centres[r]).astype(int) - DR_SIZE // 2,
                (rec, rec),
                ok,
                np.round(inj.perturbation[r], PERTURBATION_DIGITS).tolist(),
                inject=True,
            )
        )
    return centres, inj.perturbation


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
