"""Replaying counterexamples through the real detector and tracker (issue 14; docs/semantics.md).

A counterexample of the model says: hide these detections at these steps (each
at the payoff an attack found) and the tracker takes this path. The model
assumes each perturbation works alone, that perturbations of one frame do not
interact, and that the tracker then does what the model's transitions say.
:func:`replay` checks all three on the real frames:

1. the video is run through the real detector (front end + N_dr + N_lp) again;
   every detection the results name must come out at the same position (else
   the frames are not the ones the results were made from: an input error);
2. at each attacked frame, the attack that priced each hidden detection is run
   again on the same window with the same settings (DeepFool is deterministic;
   the recomputed norm is compared with the recorded payoff), and the
   perturbations of all the frame's hidden detections are added *together* to
   the detector's inputs of that frame: the current frame and its aligned
   copies of the m previous frames, the images N_dr and N_lp see (real-valued,
   not rounded to 8 bits; a pixel two windows share gets both changes);
3. the detector's step for that frame is run again on the perturbed inputs:
   background median, subtraction, blobs, N_dr on every candidate, N_lp on the
   crowded blobs; registration is kept from the clean frames;
4. the tracker (the run's design and configuration) runs over the video with
   the replayed detections, unattacked, and its track is compared with the
   counterexample's: the same associated detection at every step (within
   :data:`DET_TOL_PX`) and positions within :data:`TRACK_TOL_PX`.

Under ``attack window L..U allow hide, inject`` (issue 61) the replay derives each
attacked frame's attack from the model's path (lesmc/replay/inject.py).

The first step where they differ, and why (a hidden detection still detected,
a neighbour's detection lost or moved by an overlapping window, an extra
detection), is reported. When a hidden detection survives because windows
interact (or an injected candidate is not detected), the attack is *repaired*:
the still-detected windows are attacked again on the perturbed inputs (jointly
with the rest of the frame's perturbation), the missed candidates' windows
towards "vehicle", for up to :data:`REPAIR_ROUNDS` rounds
(:func:`~lesmc.replay.perturbed.repair_frame`), the cost of the extra
perturbations is added to the payoff, and the track is replayed again.
"""

from __future__ import annotations

__all__ = [
    "Outcome",
    "apply",
    "cases",
    "check_known",
    "check_last_frame",
    "detect_all_frames",
    "detect_attacked_frames",
    "frontend_note",
    "frontend_settings",
    "recorded_frontend",
    "replay",
    "replay_case",
    "replay_file",
    "shared_attacks",
    "verdict_after",
    "verdict_rows",
]

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import astuple, dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from lesmc.common.errors import InputError, Location, UsageError
from lesmc.common.memory import release
from lesmc.model import kernel
from lesmc.perception import DELTA_BC, HISTORY, NetFiles
from lesmc.replay import on_frames
from lesmc.replay.case import (
    DET_TOL_PX,
    PAYOFF_RTOL,
    TRACK_TOL_PX,
    Case,
    FrameAttack,
    Replayed,
    cases,
    footage,
    group_by_case,
    hidden_by_frame,
)
from lesmc.replay.inject import inject_by_frame, inject_cases
from lesmc.replay.joint_forcing import check_joint_cases, derive_joint
from lesmc.replay.perturbed import attack_frame
from lesmc.replay.story import frame_story
from lesmc.results.document import record_replays
from lesmc.results.read import HiddenDoc as Hidden
from lesmc.results.read import ResultsDoc
from lesmc.results.result_doc import ReplayDoc, read_replay
from lesmc.scene import Scene
from lesmc.tracking.monitor import track
from lesmc.tracking.trackers import make_tracker

if TYPE_CHECKING:
    from lesmc.common.progress import Bar
    from lesmc.perception.attack_settings import AttackConfig
    from lesmc.perception.cnn import Nets
    from lesmc.perception.detector import FrameDetections
    from lesmc.perception.frontend import FrontEndConfig, FrontEndOutput
    from lesmc.perception.registration import Registration
    from lesmc.results.record import Results
    from lesmc.video.reader import FrameSet


# ---------------------------------------------------------------- the tracker


def _compare(
    case: Case,
    points: list[Any],
    scene: Any,
    attacks: dict[int, FrameAttack],
) -> Replayed:
    """The replay: confirmed, or the first step where the track diverges and why."""
    n_model = len(case.positions)
    err = 0.0
    first = case.first_frame
    loc = list(scene.tracker.measured)
    for k in range(max(n_model, len(points))):
        if k >= n_model or k >= len(points):
            why = (
                "the replayed track halts earlier"
                if k >= len(points)
                else "the model's track halts here; the replayed one goes on"
            )
            return _diverged(k, err, why, attacks.get(first + k))
        e = float(np.linalg.norm(points[k].x[list(loc)] - case.positions[k]))
        if k >= 1:
            want = case.obs[k - 1]
            got = points[k].obs
            wp = None if want is None else case.known.get(want)
            gp = None
            if got is not None:
                d = scene.frame(first + k).detections[int(got.split(":")[1])]
                gp = (d.x, d.y)
            same = (wp is None and gp is None) or (
                wp is not None
                and gp is not None
                and math.hypot(wp[0] - gp[0], wp[1] - gp[1]) <= DET_TOL_PX
            )
            if want is not None and wp is None:
                same = got is not None and e <= TRACK_TOL_PX  # position unknown: judge by track
            if not same:
                theirs = "none" if want is None else want + (" " + _at(wp) if wp else "")
                what = (
                    f"the tracker takes {'no detection' if gp is None else _at(gp)} where the "
                    f"model takes {theirs}"
                )
                return _diverged(k, max(err, e), what, attacks.get(first + k))
        if e > TRACK_TOL_PX:
            return _diverged(
                k,
                max(err, e),
                f"the position is {e:.3g} px from the model's (tolerance {TRACK_TOL_PX} px)",
                attacks.get(first + k),
            )
        err = max(err, e)
    return Replayed("confirmed", None, round(err, 6), None)


def _at(p: tuple[float, float]) -> str:
    return f"the detection at ({p[0]:.1f}, {p[1]:.1f})"


def _diverged(k: int, err: float, what: str, fa: FrameAttack | None) -> Replayed:
    why = [what]
    if fa is not None:
        why.append(frame_story(fa))
    return Replayed(
        "diverged", k, round(err, 6) if math.isfinite(err) else None, "; ".join(w for w in why if w)
    )


# ---------------------------------------------------------------- the whole replay


@dataclass
class Outcome:
    """Replay objects per (run, result), and each frame's perturbations for the report."""

    replays: dict[tuple[int, int], dict[str, Any]]
    seconds: float


def replay(
    doc: ResultsDoc,
    frames: FrameSet,
    nets: Nets,
    prop: str | None = None,
    history: int = HISTORY,
    delta_bc: int = DELTA_BC,
    on_frame: Callable[[], None] | None = None,
    repair: bool = True,
    clean: Mapping[int, FrameDetections] | None = None,
    registrations: Mapping[int, Registration] | None = None,
    scene: Scene | None = None,
) -> Outcome:
    """Replay every violated property's counterexample of ``doc`` (or ``prop``'s) on ``frames``.

    ``clean``: each frame's detections as the perception of these frames with these
    networks made them (``lesmc verify`` hands over its own): then only the attacked
    frames, after the ``history`` frames before each that the front end needs, go
    through the detector; ``registrations``, that perception's (``PerceiveRun``), spare
    the front end describing and matching those frames again (tests/test_replay.py
    checks that every way agrees). ``scene``: the scene the results were checked on, for
    ``joint``'s injections (None: the file they name; replay/joint_forcing.py).
    """
    from lesmc.perception.detector import Detector, DetectorConfig

    t0 = time.monotonic()
    todo = cases(doc, prop)
    if not todo:
        return Outcome({}, 0.0)
    derive_joint(doc.meta, todo, scene)
    fe, attack_cfg = _settings(doc, history, delta_bc)
    last = max(c.first_frame + len(c.positions) - 1 for c in todo)
    by_frame, by_inject = hidden_by_frame(todo), inject_by_frame(todo)
    attacked: list[dict[int, FrameAttack]] = [{} for _ in todo]

    def attack(det: Any, out: FrontEndOutput, fd: FrameDetections) -> None:
        def one(group: list[Hidden]) -> FrameAttack:
            return attack_frame(nets, det, out, fd, group, attack_cfg, repair)

        for ci, fa in shared_attacks(group_by_case(by_frame.get(fd.index, [])), one).items():
            attacked[ci][fd.index] = fa
        inject_cases(nets, det, out, fd, todo, by_inject, attacked, attack_cfg, repair)
        release()  # the frame's temporaries go back to the system (common/memory.py)

    def detector() -> Any:
        det = Detector(nets, DetectorConfig(frontend=fe))
        det.frontend.known = registrations or {}
        return det

    if clean is None:  # every frame through the detector
        clean = detect_all_frames(frames, detector(), last, attack, on_frame)
    else:  # the clean frames' detections are given: only the attacked ones are detected
        clean = dict(clean)
        wanted = sorted(set(by_frame) | set(by_inject))
        detect_attacked_frames(frames, detector, wanted, fe.history, attack, on_frame)
    check_last_frame(clean, last)
    for c in todo:
        check_known(c, clean)
    replays = {(c.run, c.result): replay_case(c, clean, attacked[ci]) for ci, c in enumerate(todo)}
    return Outcome(replays, time.monotonic() - t0)


def check_last_frame(clean: Mapping[int, FrameDetections], last: int) -> None:
    """The frames must reach ``last``, the last step of a counterexample."""
    if last not in clean:
        raise InputError(
            f"the frames stop before frame {last}, the last step of a counterexample",
            Location("--frames"),
        )


def _settings(doc: ResultsDoc, history: int, delta_bc: int) -> tuple[FrontEndConfig, AttackConfig]:
    """The front end's and the attack's settings, as the results' perception recorded them
    (``history`` and ``delta_bc`` where it did not)."""
    from lesmc.perception.attack_settings import AttackConfig

    p = doc.perception
    fe, _ = recorded_frontend(
        {"history": history if p.history is None else p.history,
         "delta_bc": delta_bc if p.delta_bc is None else p.delta_bc}
    )  # fmt: skip
    return fe, AttackConfig(**p.attack)


#: The front end's settings a results document's ``perception`` may record.
FRONTEND_FIELDS = ("history", "delta_bc")


def recorded_frontend(perception: Any) -> tuple[FrontEndConfig, tuple[str, ...]]:
    """The front end a replay runs and which of its settings the results record: the
    results' ``perception`` (a document's object, or :class:`~lesmc.results.read.Perception`)
    gives ``history`` and ``delta_bc`` where it records them, the defaults the others
    (:func:`frontend_settings`). Both replays read it (this module's and
    lesmc/replay/multi.py's), and ``lesmc replay``'s note (:func:`frontend_note`)."""
    if isinstance(perception, Mapping):
        history, delta_bc = (perception.get(k) for k in FRONTEND_FIELDS)
    else:
        history, delta_bc = (getattr(perception, k, None) for k in FRONTEND_FIELDS)
    values = dict(zip(FRONTEND_FIELDS, (history, delta_bc), strict=True))
    recorded = tuple(k for k, v in values.items() if v is not None)
    return frontend_settings(history, delta_bc), recorded


def frontend_note(results: str, used: Mapping[str, Any]) -> str | None:
    """``lesmc replay``'s note on stderr when the front end ran with some default settings:
    ``used``, a replay's ``frontend`` object (lesmc.replay.multi.frontend_record); None
    when the results record every setting."""
    recorded = used.get("recorded")
    if recorded is None:  # a replay object from before ``recorded``
        recorded = FRONTEND_FIELDS if used.get("from") == "results" else ()
    defaulted = [k for k in FRONTEND_FIELDS if k not in recorded]
    if not defaulted:
        return None
    fields = ", ".join(f"perception.{k}" for k in defaulted)
    values = ", ".join(f"{k} {used[k]}" for k in defaulted)
    kept = ", ".join(f"{k} {used[k]}" for k in FRONTEND_FIELDS if k not in defaulted)
    return (
        f"lesmc replay: {results} records no front-end settings ({fields}): the frames "
        f"were detected with the defaults ({values})"
        + (f" and the recorded ({kept})" if kept else "")
    )


def frontend_settings(history: int | None = None, delta_bc: int | None = None) -> FrontEndConfig:
    """The front end's settings a perception ran with: its ``history`` (frames) and its
    blobs' ``delta_bc`` (grey levels) as recorded, the defaults where not (None:
    :data:`lesmc.perception.HISTORY`, :class:`~lesmc.perception.blobs.BlobConfig`'s)."""
    from lesmc.perception.blobs import BlobConfig
    from lesmc.perception.frontend import FrontEndConfig

    blobs = BlobConfig() if delta_bc is None else BlobConfig(delta_bc=int(delta_bc))
    return FrontEndConfig(history=HISTORY if history is None else int(history), blobs=blobs)


def detect_all_frames(
    frames: FrameSet,
    det: Any,
    last: int,
    attack: Callable[[Any, FrontEndOutput, FrameDetections], None],
    on_frame: Callable[[], None] | None,
) -> dict[int, FrameDetections]:
    """Frames 0..last through the detector, the attacked ones attacked: the clean
    detections of every frame."""
    clean: dict[int, FrameDetections] = {}
    for i in range(min(len(frames), last + 1)):
        got = _pushed(det, frames, i)
        if on_frame:
            on_frame()
        if got is None:
            continue
        out, fd = got
        clean[fd.index] = _light(fd)
        attack(det, out, fd)
    return clean


def detect_attacked_frames(
    frames: FrameSet,
    detector: Callable[[], Any],
    wanted: list[int],
    history: int,
    attack: Callable[[Any, FrontEndOutput, FrameDetections], None],
    on_frame: Callable[[], None] | None,
) -> None:
    """Only the frames in ``wanted`` through the detector and attacked: each run of them
    (gaps of at most ``history`` frames) from a fresh front end fed the ``history`` frames
    before it, whose state then equals a pass over the whole video (registration and the
    background read only the last ``history`` frames)."""
    runs: list[list[int]] = []
    for k in wanted:
        if runs and k - runs[-1][-1] <= history:
            runs[-1].append(k)
        else:
            runs.append([k])
    for run in runs:
        start = max(0, run[0] - history)
        det = detector()
        det.frontend.index = start - 1
        for i in range(start, min(len(frames), run[-1] + 1)):
            got = _pushed(det, frames, i)
            if on_frame:
                on_frame()
            if got is not None and got[1].index in run:
                attack(det, *got)


def _pushed(det: Any, frames: FrameSet, i: int) -> Any:
    """Frame ``i`` through the detector ``det``; a frame the front end cannot register with
    the one before (too few features: not the video the results were made from) is an
    input error at that frame's file, as perception says it."""
    from lesmc.perception.registration import RegistrationError

    try:
        return det.push(frames.read(i))
    except RegistrationError as exc:
        raise InputError(
            f"cannot register with the previous frame: {exc}", Location(str(frames.paths[i]))
        ) from None


def replay_case(
    c: Case, clean: dict[int, FrameDetections], attacked: dict[int, FrameAttack]
) -> dict[str, Any]:
    """One counterexample: the tracker on the frames' detections with the attacked frames'
    ones, compared with the model's path; a repaired attack that costs enough for the
    property to hold (Eq. 5 + the repair) is no counterexample. A diverged one is judged on
    the replayed run (lesmc/replay/on_frames.py: ``on_frames``)."""

    first = c.first_frame
    if c.injects and c.derived and c.objective_is_payoff and math.isfinite(c.optimum):
        cost = sum(fa.cost for fa in attacked.values())
        if not abs(cost - c.optimum) <= PAYOFF_RTOL * max(c.optimum, 1e-9):
            raise InputError(
                f"the attack of {c.design}'s counterexample of {c.prop} now costs {cost:g}, "
                f"the results say {c.optimum:g}: the frames, networks or attack settings "
                "differ from the run that wrote the results",
                Location("--frames"),
            )
    dets = {k: v for k, v in clean.items() if first <= k <= first + len(c.positions) - 1}
    scene = footage(dets, c, {k: fa.detections for k, fa in attacked.items()})
    points = track(make_tracker(scene), len(c.positions) - 1)
    got = _compare(c, points, scene, attacked)
    fas = list(attacked.values())
    repaired = sum(fa.repaired_rounds for fa in fas)
    extra = sum(fa.extra_cost for fa in fas)
    if repaired and got.status == "confirmed" and c.objective_is_payoff:
        cost = c.optimum + extra
        if kernel.holds(c.holds_op, cost, c.threshold):
            got = replace(
                got,
                status="diverged",
                step=min(attacked) - first,
                reason=f"the repaired joint attack replays, but costs {cost:.4g}: the property "
                f"holds for it (optimum {c.holds_op} {c.threshold:g})",
            )
    out = {
        "status": got.status,
        "step": got.step,
        "max_error_px": got.max_error_px,
        "reason": got.reason,
        "attack": "repaired" if repaired else "as modelled",
        "repair_cost": round(extra, 6),
        "frames": [f"frame {fa.frame}: {frame_story(fa)}" for fa in fas if frame_story(fa)],
        "tolerance_px": {"detection": DET_TOL_PX, "track": TRACK_TOL_PX},
        "perturbations": [p for fa in fas for p in fa.perturbations],
    }
    if got.status == "diverged":  # another path: does it violate the property all the same?
        out["on_frames"] = on_frames.judge(c, clean, attacked)
    return out


def shared_attacks(
    groups: list[tuple[int, list[Hidden]]], attack: Callable[[list[Hidden]], FrameAttack]
) -> dict[int, FrameAttack]:
    """Each case's attack of one frame. Cases that hide the same detections there (two
    designs' counterexamples often do) share one: an attack depends on the frame and the
    group only, and its FrameAttack is only read afterwards."""
    done: dict[tuple[tuple[Any, ...], ...], FrameAttack] = {}
    out = {}
    for ci, group in groups:
        key = tuple(astuple(h) for h in group)
        if key not in done:
            done[key] = attack(group)
        out[ci] = done[key]
    return out


def _light(fd: FrameDetections) -> FrameDetections:
    """The detections without their windows (the tracker needs positions only)."""
    return replace(fd, windows=fd.windows[:0])


def check_known(c: Case, clean: dict[int, FrameDetections]) -> None:
    """Every detection the results list must come out of the detector where they say."""
    for did, (x, y) in c.known.items():
        f, _, j = did.partition(":")
        if not (f.isdigit() and j.isdigit()):
            continue
        fd = clean.get(int(f))
        if fd is None:
            continue
        ok = (
            int(j) < len(fd.positions)
            and math.hypot(fd.positions[int(j), 0] - x, fd.positions[int(j), 1] - y) <= 1e-3
        )
        if not ok:
            raise InputError(
                f"the detector does not reproduce detection {did} at ({x:.2f}, {y:.2f}) on "
                "these frames: they are not the frames (or networks) the results were made from",
                Location("--frames"),
            )


def apply(doc: dict[str, Any], outcome: Outcome, results: Results | None = None) -> None:
    """Record each replay in the document ``doc`` (and in the typed ``results`` it was
    written from, if given): lesmc.results.document.record_replays."""
    record_replays(doc, outcome.replays, outcome.seconds, results)


def replay_file(
    doc: ResultsDoc,
    frames_dir: str,
    nets: NetFiles,
    prop: str | None,
    bar: Bar,
) -> Outcome:
    """``lesmc replay``: the frames and networks (``--nets``, ``--detector``, ``--locator``) of
    a results document, then :func:`replay` (``bar`` counts the frames). The networks must
    be those the results were made with."""
    # an unknown property, or results that do not fit their scene, are refused before the
    # video is read and torch imported
    check_joint_cases(doc.meta, cases(doc, prop))
    from lesmc.perception.cnn import load_nets
    from lesmc.video.reader import open_frames

    fe, _ = recorded_frontend(doc.perception)
    frames = open_frames(frames_dir, fe.history + 1)
    loaded = load_nets(*nets)
    want = doc.perception.nets
    if want and want != loaded.settings.trained_on:
        raise UsageError(
            f"the results were made with the networks trained on '{want}', these were "
            f"trained on '{loaded.settings.trained_on}': give the same --nets, --detector "
            "and --locator"
        )
    bar.update(total=len(frames))
    return replay(doc, frames, loaded, prop, on_frame=bar.advance)


def verdict_after(rp: ReplayDoc) -> str:
    """A violated counterexample's verdict after its replay: ``violated`` when it replays
    ``confirmed`` or its replayed run violates the property all the same (``on_frames``:
    another path), else ``unknown``."""
    on = rp.on_frames
    return "violated" if rp.status == "confirmed" or (on is not None and on.violated) else "unknown"


def verdict_rows(
    doc: ResultsDoc, outcome: Outcome, prop: str | None
) -> tuple[list[dict[str, Any]], set[str]]:
    """One row per replayed counterexample (model verdict, verdict after the replay, the
    replay), and every verdict the results hold after it (for the exit status)."""
    rows: list[dict[str, Any]] = []
    verdicts: set[str] = set()
    for c in cases(doc, prop):
        obj = outcome.replays[(c.run, c.result)]
        verdict = verdict_after(read_replay(obj))
        verdicts.add(verdict)
        rows.append(
            {
                "design": c.design,
                "property": c.prop,
                "verdict_model": "violated",
                "verdict": verdict,
                "replay": obj,
            }
        )
    others: set[str] = {
        res.verdict
        for run in doc.runs
        for res in run.results
        if (prop is None or res.property == prop)
        and res.replay is None
        and res.verdict != "violated"
    }
    return rows, verdicts | others
