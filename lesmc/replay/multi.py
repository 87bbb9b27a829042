"""Replaying the counterexamples of a multi-target design (``sort``, ``gnn``) through the real
detector and tracker (issue 58; docs/trackers.md, "Replaying a multi-target
counterexample").

A ``lesmc-multi-check`` counterexample says: hide these detections (``"hidden":
["FRAME:K", ...]`` at each step) and the target's track ids are these, so the property's
constraint (``switches``, ``lost`` or a ``dist`` measure) is met at this cost.
:func:`replay_multi` checks it on the real frames, as the single-target replay
(lesmc/replay/run.py) does, with that module's functions:

1. the frames go through the real detector again; every detection of the scene the
   results were made from must come out where the scene says (else: an input error);
2. at each attacked frame the attack that priced each hidden detection is run again
   and the perturbations of the frame's hidden detections are applied together
   (:func:`~lesmc.replay.perturbed.attack_frame`, with its repair), and the frame is detected
   again;
3. the design's production tracker (lesmc/tracking/multi.py, the scene's tracker block)
   runs over the replayed detections, each with the box the scene gives its nearest
   clean detection (the WAMI front end's: its N_dr window);
4. the target's track at each step is identity's rule applied to the target's reference
   of the unattacked scene (:meth:`~lesmc.tracking.multi.ComposedDesign.references`), and
   the replayed run is checked as a one-path model (:class:`~lesmc.model.multi.MultiModel`)
   by the multi-target engine: the property's constraint through the kernel and
   lesmc/model/identity.py, its objective with the recomputed attack costs.

``confirmed``: the replayed run meets the constraint, its cost (or ``dist`` objective)
violates the property, and its target's track ids are the model's at every step;
otherwise ``diverged`` at the first step where the ids differ (or the last step), with
the reason.

A counterexample under ``allow hide, inject`` also lists ``"injected": ["FRAME:cROW",
...]`` at a step: the N_dr window of each such candidate (a candidate of Q_bc that N_dr
rejects) is perturbed towards "vehicle" and the frame's hidden detections' windows
away from it, all applied together and the frame detected again
(:func:`~lesmc.replay.inject.attack_listed`, the point designs' injection replay).

The front end runs with the settings the document's ``perception`` records (verify
writes them: :func:`perception_settings`); a document without them (made before they
were recorded) replays with the defaults, and the replay says so.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from lesmc.common.errors import InputError, Location
from lesmc.common.locations import error_in_file
from lesmc.engines.multi import check_multi, measure_value
from lesmc.model.identity import NONE, last_seen
from lesmc.model.kernel import COMPARE
from lesmc.model.multi import MultiModel
from lesmc.replay import run as single
from lesmc.replay.case import (
    DET_TOL_PX,
    TRACK_TOL_PX,
    FrameAttack,
    group_by_case,
    hidden_by_frame,
)
from lesmc.replay.multi_cases import MultiCase, multi_cases
from lesmc.replay.on_frames import frame_cost
from lesmc.replay.perturbed import attack_frame
from lesmc.replay.story import frame_story
from lesmc.results.read import HiddenDoc as Hidden
from lesmc.scene import Detection, Frame, Scene
from lesmc.tracking.multi import ComposedDesign, target_id, target_look

if TYPE_CHECKING:
    from lesmc.perception.attack_settings import AttackConfig
    from lesmc.perception.cnn import Nets
    from lesmc.perception.detector import FrameDetections
    from lesmc.perception.frontend import FrontEndConfig, FrontEndOutput
    from lesmc.perception.registration import Registration
    from lesmc.video.reader import FrameSet

#: A scene's detection and the detector's, on the clean frames, agree within this (px).
KNOWN_TOL_PX = 1e-3


#: Where the front end's settings come from, in words (:func:`frontend_record`'s ``from``).
_SETTINGS_FROM = {
    "results": "as the results' perception records them",
    "defaults": "the defaults: the results record no perception settings",
    "partly": "as the results' perception records them where it does, else the defaults",
}


def replay_multi(
    doc: Mapping[str, Any],
    scene: Scene,
    where: str,
    bound: Mapping[str, Any],
    frames: FrameSet,
    nets: Nets,
    prop: str | None = None,
    on_frame: Callable[[], None] | None = None,
    clean: Mapping[int, FrameDetections] | None = None,
    registrations: Mapping[int, Registration] | None = None,
    path: str = "<results>",
) -> single.Outcome:
    """Replay the counterexamples of ``doc`` (a ``lesmc-multi-check`` document made from
    ``scene``, read from ``where``) on ``frames`` through ``nets``: the replays by
    ``(0, result index)``. ``clean`` and ``registrations``: the perception of these frames
    (``lesmc verify`` hands over its own), as :func:`lesmc.replay.run.replay` takes them;
    ``path``: the results' file, for errors."""
    from lesmc.perception.attack_settings import attack_of
    from lesmc.perception.detector import Detector, DetectorConfig

    t0 = time.monotonic()
    todo = multi_cases(doc, scene, bound, prop, path, where)
    if not todo:
        return single.Outcome({}, 0.0)
    fe, recorded = perception_settings(doc)  # the front end as verify's perception ran it
    cfg = attack_of(dict(scene.meta), where)
    attacked: list[dict[int, FrameAttack]] = [{} for _ in todo]
    attack = _attacker(nets, todo, cfg, attacked)

    def detector() -> Any:
        det = Detector(nets, DetectorConfig(frontend=fe))
        det.frontend.known = registrations or {}
        return det

    last = max(c.steps[-1]["frame"] for c in todo)
    if clean is None:
        clean = single.detect_all_frames(frames, detector(), last, attack, on_frame)
    else:
        wanted = sorted({h.frame for c in todo for h in c.hidden} | _injecting(todo))
        single.detect_attacked_frames(frames, detector, wanted, fe.history, attack, on_frame)
    single.check_last_frame(clean, last)
    used = frontend_record(fe, recorded)
    for c in todo:
        _check_known(scene, c.end, clean, used)
    replays = {
        (0, c.result): {**replay_case(c, scene, where, clean, attacked[ci]), "frontend": used}
        for ci, c in enumerate(todo)
    }
    return single.Outcome(replays, time.monotonic() - t0)


def _attacker(
    nets: Nets, todo: list[MultiCase], cfg: AttackConfig, attacked: list[dict[int, FrameAttack]]
) -> Callable[[Any, FrontEndOutput, FrameDetections], None]:
    """What attacks a frame for the cases ``todo`` (their attacks into ``attacked``): the
    hiding attacks of each case that only hides there (shared by cases that hide the same,
    :func:`~lesmc.replay.perturbed.attack_frame`), and :func:`_inject` for each case that
    injects there."""
    by_frame = hidden_by_frame(todo)

    def attack(det: Any, out: FrontEndOutput, fd: FrameDetections) -> None:
        def one(group: list[Hidden]) -> FrameAttack:
            return attack_frame(nets, det, out, fd, group, cfg)

        groups = group_by_case(by_frame.get(fd.index, []))
        plain = [(ci, g) for ci, g in groups if not todo[ci].injects_at(fd.index)]
        for ci, fa in single.shared_attacks(plain, one).items():
            attacked[ci][fd.index] = fa
        for ci, c in enumerate(todo):
            if c.injects_at(fd.index):
                attacked[ci][fd.index] = _inject(nets, det, (out, fd), c, cfg)

    return attack


def _injecting(todo: list[MultiCase]) -> set[int]:
    """The frames where some case of ``todo`` injects a candidate."""
    return {f for c in todo for _, f, _, _ in c.injected}


def perception_settings(doc: Mapping[str, Any]) -> tuple[FrontEndConfig, tuple[str, ...]]:
    """The front end's settings verify's perception ran with, as the document's
    ``perception`` records them (``history``, ``delta_bc``; lesmc/experiment/multi_verify.py
    writes it), and which it records: the defaults for those it does not (made before
    they were recorded, or from a scene that does not say), as the point designs' replay
    reads them (:func:`lesmc.replay.run.recorded_frontend`)."""
    p = doc.get("perception")
    return single.recorded_frontend(p if isinstance(p, Mapping) else {})


def frontend_record(fe: FrontEndConfig, recorded: tuple[str, ...]) -> dict[str, Any]:
    """What a replay object says of the front end it ran (``frontend``): its ``history``,
    its blobs' ``delta_bc``, the settings the results record (``recorded``) and where
    they come from (``from``: the results, the defaults, or partly each)."""
    every = set(recorded) == set(single.FRONTEND_FIELDS)
    return {
        "history": fe.history,
        "delta_bc": fe.blobs.delta_bc,
        "recorded": list(recorded),
        "from": "results" if every else "partly" if recorded else "defaults",
    }


def _inject(
    nets: Nets,
    det: Any,
    seen: tuple[FrontEndOutput, FrameDetections],
    c: MultiCase,
    cfg: AttackConfig,
) -> FrameAttack:
    """Case ``c``'s attack on a frame where it injects candidates: its hidden detections
    and injected candidates there, as the point designs' injection replay runs them
    (:func:`~lesmc.replay.inject.attack_listed`). Each candidate must be one of the
    front end's candidates of the frame, where the scene says (else an input error)."""
    from lesmc.replay.inject import attack_listed, candidate_at

    out, fd = seen
    listed = c.injects_at(fd.index)
    rows = []
    for _, cid, (x, y) in listed:
        row = candidate_at(fd, out, cid)
        cx, cy = (float(v) for v in out.candidates.centroid[row])
        if math.hypot(cx - x, cy - y) > KNOWN_TOL_PX:
            raise InputError(
                f"injection candidate {cid} is at ({cx:.2f}, {cy:.2f}) on these frames, the "
                f"scene says ({x:.2f}, {y:.2f}): they are not the frames (or front-end "
                "settings) the results were made from",
                Location("--frames"),
            )
        rows.append((cid, row))
    hidden = [h for h in c.hidden if h.frame == fd.index]
    return attack_listed(nets, det, seen, listed[0][0], (hidden, rows), cfg)


def replay_case(
    c: MultiCase,
    scene: Scene,
    where: str,
    clean: Mapping[int, FrameDetections],
    attacked: Mapping[int, FrameAttack],
) -> dict[str, Any]:
    """One counterexample: the production tracker on the frames' detections with the
    attacked frames' replayed ones, its target's track at each step, and the property
    checked on that one run (the replay object ``lesmc replay --json`` prints)."""
    from lesmc.tracking.trackers import make_multi

    design = make_multi(scene, where)
    assert isinstance(design, ComposedDesign)
    run = design.run(c.end)
    refs = design.references([s.tracks for s in run])
    me = target_id([s.target_id for s in run])
    frames = tuple(_replayed_frame(f, attacked.get(f.step)) for f in scene.frames[: c.end + 1])
    again = make_multi(replace(scene, frames=frames), where)
    assert isinstance(again, ComposedDesign)
    state, fts, looks = again.tracker.initial(), [], []
    for f in frames:
        state, ft = again.tracker.step(state, again.measurements(f))
        fts.append(ft)
        looks.append(target_look(ft, state, me))
    tid = [NONE if r is None else again.target_of(ft, r) for ft, r in zip(fts, refs, strict=True)]
    model = _chain(c, frames, tid, refs, looks, me, attacked)
    return _verdict(c, model, fts, attacked)


def _check_known(
    scene: Scene, end: int, clean: Mapping[int, FrameDetections], used: Mapping[str, Any]
) -> None:
    """The detector must reproduce every detection of the scene's steps 0..``end`` where the
    scene says (else the frames, networks or front-end settings, ``used``
    (:func:`frontend_record`), are not those the results were made from)."""
    for f in scene.frames[: end + 1]:
        fd = clean.get(f.step)
        have = np.zeros((0, 2)) if fd is None else fd.positions
        for j, d in enumerate(f.detections):
            ok = j < len(have) and math.hypot(have[j, 0] - d.x, have[j, 1] - d.y) <= KNOWN_TOL_PX
            if not ok:
                raise InputError(
                    f"the detector does not reproduce detection {d.id} at ({d.x:.2f}, "
                    f"{d.y:.2f}) on these frames with history {used['history']} and delta_bc "
                    f"{used['delta_bc']} ({_SETTINGS_FROM[used['from']]}): they are not the "
                    "frames, networks or front-end settings the results were made from",
                    Location("--frames"),
                )


def _replayed_frame(f: Frame, fa: FrameAttack | None) -> Frame:
    """Frame ``f`` with the replayed detections of its attack ``fa`` (None: unattacked),
    each with the box of the frame's nearest clean detection (the WAMI front end's N_dr
    window; a point detection stays a point)."""
    if fa is None:
        return f
    pos = fa.detections.positions
    near = [int(np.argmin(((f.positions() - p) ** 2).sum(axis=1))) for p in pos]
    ds = tuple(
        Detection(
            f"{f.step}:{j}",
            float(p[0]),
            float(p[1]),
            math.nan,
            None,
            f.detections[i].w if f.detections else None,
            f.detections[i].h if f.detections else None,
        )
        for j, (p, i) in enumerate(zip(pos, near or [0] * len(pos), strict=True))
    )
    return replace(f, detections=ds)


def _chain(
    c: MultiCase,
    frames: tuple[Frame, ...],
    tid: list[int],
    refs: list[np.ndarray | None],
    looks: list[tuple[np.ndarray, bool]],
    me: int,
    attacked: Mapping[int, FrameAttack],
) -> MultiModel:
    """The replayed run as a model of one path (lesmc/model/multi.py): its states' target
    track ids, references and what the ``dist`` measures read; each transition at the
    recomputed cost of its frame's attack (the repair's included) and its count."""
    from lesmc.tracking.multi import as_box

    n = len(frames)
    t = np.array(tid, dtype=np.int64)
    last = t.copy()
    for k in range(1, n):
        last[k] = last_seen(last[k - 1 : k], t[k : k + 1])[0]
    names = tuple(tuple(d.id for d in f.detections) for f in frames)
    hidden = [tuple(int(h.split(":")[1]) for h in s["hidden"]) for s in c.steps]
    acts = [len(s["hidden"]) + len(s.get("injected") or ()) for s in c.steps]
    cost = [frame_cost(attacked.get(f.step)) for f in frames]
    refbox = [np.full(4, np.nan) if r is None else as_box(r) for r in refs]
    return MultiModel(
        step=np.arange(n, dtype=np.int64),
        tid=t,
        ref=np.array([r is not None for r in refs], dtype=bool),
        last=last,
        src=np.arange(n - 1, dtype=np.int64),
        dst=np.arange(1, n, dtype=np.int64),
        payoff=np.array(cost[1:], dtype=float),
        count=np.array(acts[1:], dtype=np.int64),
        by_payoff=tuple(hidden[1:]),
        by_count=tuple(hidden[1:]),
        frames=tuple(f.step for f in frames),
        names=names,
        end=n - 1,
        window=(int(c.prop.l), int(c.prop.u)),
        box=np.array([lk[0] for lk in looks], dtype=float).reshape(-1, 4),
        gone=np.array([lk[1] for lk in looks], dtype=bool),
        refbox=np.array(refbox, dtype=float).reshape(-1, 4),
        target=me,
        detections=tuple(len(f.detections) for f in frames),
    )


def _verdict(
    c: MultiCase,
    model: MultiModel,
    fts: list[Any],
    attacked: Mapping[int, FrameAttack],
) -> dict[str, Any]:
    """The replay object: the property checked on the replayed run (``model``), and its
    target's track ids against the counterexample's."""
    holds = check_multi(model, c.prop).holds
    value = measure_value(model, c.prop.constraint, c.prop)
    objective = measure_value(model, c.prop.objective, c.prop)
    ids = [None if t == NONE else int(t) for t in model.tid.tolist()]
    step, reason = _why(c, ids, value, objective, holds)
    fas = [attacked[f] for f in sorted(attacked) if f <= c.steps[-1]["frame"]]
    if reason is not None and step is not None:
        near = [fa for fa in fas if fa.frame <= c.steps[step]["frame"]]
        story = frame_story(near[-1]) if near else ""
        reason = "; ".join(w for w in (reason, story) if w)
    repaired = sum(fa.repaired_rounds for fa in fas)
    return {
        "status": "confirmed" if reason is None else "diverged",
        "step": step,
        "max_error_px": _box_error(c, fts),
        "reason": reason,
        "attack": "repaired" if repaired else "as modelled",
        "repair_cost": round(sum(fa.extra_cost for fa in fas), 6),
        "frames": [f"frame {fa.frame}: {s}" for fa in fas if (s := frame_story(fa))],
        "tolerance_px": {"detection": DET_TOL_PX, "track": TRACK_TOL_PX},
        "perturbations": [p for fa in fas for p in fa.perturbations],
        "target_ids": ids,
        "detections": [
            {"frame": fa.frame, "positions": fa.detections.positions.tolist()} for fa in fas
        ],
        "constraint_value": value if math.isfinite(value) else "inf",
        "objective": objective if math.isfinite(objective) else "inf",
    }


def _why(
    c: MultiCase, ids: list[int | None], value: float, objective: float, holds: bool
) -> tuple[int | None, str | None]:
    """Where and why the replayed run differs from the counterexample (None, None: it
    confirms it): a target's track id that differs, the constraint not met, or an
    attack that costs enough for the property to hold."""
    want = [s.get("target_id") for s in c.steps]
    differ = next((k for k, (a, b) in enumerate(zip(ids, want, strict=True)) if a != b), None)
    prop = c.prop.prop
    if differ is not None:
        got, theirs = ids[differ], want[differ]
        return differ, (
            f"at step {differ} the target's track is {'none' if got is None else f'id {got}'} "
            f"where the model's is {'none' if theirs is None else f'id {theirs}'}"
        )
    if not COMPARE[c.prop.op](value, c.prop.bound):
        return c.end, (
            f"{prop.constraint.measure.text()} is {value:g} on the replayed run: the "
            f"constraint ({c.prop.op} {c.prop.bound:g}) is not met"
        )
    if holds:
        return c.end, (
            f"the replayed attack's {prop.objective.text()} is {objective:g}: the property "
            f"holds for it (optimum {prop.holds_op} {prop.threshold:g})"
        )
    return None, None


def _place_problem(
    c: MultiCase, s: Mapping[str, Any], t: Mapping[str, Any], n: int
) -> tuple[str, str]:
    """A listed track whose place is not of the replayed tracker's shape (``n`` numbers):
    the results were made with another design than their ``design``."""
    i, k = c.steps.index(s), list(s["tracks"]).index(t)
    key = "box" if "box" in t else "position"
    return (
        f"results[{c.result}].counterexample[{i}].tracks[{k}].{key}",
        f"a track of {len(t[key])} numbers, where the document's design tracks "
        f"{'boxes [x1, y1, x2, y2]' if n == 4 else 'positions [x, y]'}: the results were "
        "made with another design",
    )


def _box_error(c: MultiCase, fts: list[Any]) -> float | None:
    """The largest difference (px) between a replayed track's box and the counterexample's
    track of the same id at the same step, over the tracks the results list (None: they
    list none, a results file of version 1)."""
    err: float | None = None
    for s, ft in zip(c.steps, fts, strict=True):
        for t in s.get("tracks", []):
            place = t.get("box", t.get("position"))
            mine = np.nonzero(ft.ids == t["id"])[0]
            if place is None or not mine.size:
                continue
            if len(place) != ft.boxes.shape[1]:
                raise error_in_file(c.path, [_place_problem(c, s, t, ft.boxes.shape[1])])
            e = float(np.abs(np.asarray(place, dtype=float) - ft.boxes[mine[0]]).max())
            err = e if err is None else max(err, e)
    return None if err is None else round(err, 6)
