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

Under ``attack window L..U allow hide, inject`` (issue 61) the results list no
hidden detections the replay can use (the ranks are ordered by cost), so at each
window step of ``single``'s counterexample the replay derives the attack from the
model's path: the tracker's prediction from the model's state at the step before
(:func:`~lesmc.tracking.single.carried_prediction`) and the measurement the path
takes give the cheapest way to force it (:func:`~lesmc.tracking.parts.attacker.forcing_update`):
hide every detection before it, and if it is an injection candidate (``FRAME:cROW``,
a window of Q_bc that N_dr rejects) perturb that window towards "vehicle" until
N_dr accepts it. The frame's perturbations are applied together and the frame
detected again, as for hiding; the recomputed cost of the path's attacks must
equal its optimum (``minimize payoff``). A skip that only an attack forces is not
derived: the replay then diverges there.

The first step where they differ, and why (a hidden detection still detected,
a neighbour's detection lost or moved by an overlapping window, an extra
detection), is reported. When a hidden detection survives because windows
interact, the attack is *repaired*: the still-detected windows are attacked
again on the perturbed inputs (jointly with the rest of the frame's
perturbation) for up to :data:`REPAIR_ROUNDS` rounds, the cost of the extra
perturbations is added to the payoff, and the track is replayed again.
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Callable, Mapping
from dataclasses import astuple, dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from lesmc.common.errors import InputError, Location, UsageError
from lesmc.common.memory import release
from lesmc.model import kernel
from lesmc.perception import HISTORY, NetFiles
from lesmc.perception.windows import cut, origins, stack
from lesmc.results.document import record_replays
from lesmc.results.read import HiddenDoc as Hidden
from lesmc.results.read import ResultsDoc, RunDoc, number, read_replay
from lesmc.scene import Detection, Frame, Scene, Target, tracker_from_dict
from lesmc.tracking.monitor import track
from lesmc.tracking.trackers import make_tracker

if TYPE_CHECKING:
    from lesmc.common.progress import Bar
    from lesmc.perception.attack_settings import AttackConfig
    from lesmc.perception.cnn import Nets
    from lesmc.perception.detector import Detector, FrameDetections
    from lesmc.perception.frontend import FrontEndConfig, FrontEndOutput
    from lesmc.perception.registration import Registration
    from lesmc.results.record import Results
    from lesmc.video.reader import FrameSet

#: A replayed detection is "the same" as the model's when within this many pixels.
DET_TOL_PX = 1.0
#: The replayed track confirms the counterexample when every position is within this.
TRACK_TOL_PX = 0.5
#: Rounds of the repaired (joint) attack on a frame whose hidden detections survive.
REPAIR_ROUNDS = 4
#: A recorded payoff and its recomputation agree within this relative error.
PAYOFF_RTOL = 1e-3
#: Digits kept of each perturbation value written into the results (the report draws them).
PERTURBATION_DIGITS = 6


@dataclass
class Case:
    """One violated property's counterexample of one design run, as the results file holds it."""

    run: int  # index into the document's runs
    result: int  # index into the run's results
    design: str
    prop: str
    first_frame: int
    obs: list[str | None]  # the detection taken entering step k (k = 1..), None: no update
    positions: np.ndarray  # (n, 2) estimated position at steps 0..n-1
    halted: bool
    hidden: list[Hidden]
    known: dict[str, tuple[float, float]]  # detection id -> position, as the results list them
    tracker: Mapping[str, Any]
    dt: float
    target: Target
    objective_is_payoff: bool
    threshold: float
    holds_op: str
    optimum: float
    #: the attacker's actions of the property (``allow hide, inject``: :func:`inject_frame`)
    actions: tuple[str, ...] = ("hide",)
    #: (n, dim) the model's whole state at steps 0..n-1 (predictions are made from it)
    states: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    window: tuple[int, int] = (0, -1)  #: the run's attack window (steps; the model's)

    @property
    def injects(self) -> bool:
        """Whether the attacker may inject (the replay derives the attack itself)."""
        return "inject" in self.actions


@dataclass(frozen=True)
class Replayed:
    """How a counterexample's track replayed: confirmed, or the first step where it
    diverges (``step``) and why; the largest distance from the model's positions (None:
    infinite)."""

    status: str
    step: int | None
    max_error_px: float | None
    reason: str | None


@dataclass
class FrameAttack:
    """What the replay did to one attacked frame of one case."""

    frame: int
    step: int
    detections: FrameDetections
    perturbations: list[dict[str, Any]] = field(default_factory=list)
    still: list[str] = field(default_factory=list)  # hidden ids still detected
    lost: list[str] = field(default_factory=list)  # other ids no longer detected
    moved: list[tuple[str, float]] = field(default_factory=list)
    extra: list[tuple[float, float]] = field(default_factory=list)
    overlaps: list[tuple[str, str]] = field(default_factory=list)
    shared: list[str] = field(default_factory=list)  # lost ids from a hidden one's N_dr window
    repaired_rounds: int = 0
    extra_cost: float = 0.0
    injected: list[str] = field(default_factory=list)  # candidate ids injected
    not_injected: list[str] = field(default_factory=list)  # injected ids not detected after
    cost: float = 0.0  # the recomputed cost of the frame's attack (allow hide, inject)


def cases(doc: ResultsDoc, prop: str | None = None) -> list[Case]:
    """The counterexamples to replay: every violated result (or property ``prop``'s)."""
    out = []
    names = set()
    for i, run in enumerate(doc.runs):
        for j, res in enumerate(run.results):
            names.add(res.property)
            if prop is not None and res.property != prop:
                continue
            replayed = res.replay is not None and res.replay.status in ("confirmed", "diverged")
            if res.verdict != "violated" and not replayed:
                continue
            if res.payoffs == "certified":
                continue  # violated with lower payoffs proves nothing (docs/semantics.md)
            cex_no = run.counterexamples[j]
            if cex_no is None or _not_derivable(run, res.property):
                continue
            out.append(_case(run, i, j, cex_no))
    if prop is not None and prop not in names:
        raise UsageError(
            f"no property named {prop}; the results hold {', '.join(sorted(names)) or 'none'}"
        )
    return out


def _not_derivable(run: RunDoc, prop: str) -> bool:
    """Whether ``prop``'s counterexample has no replay built: it injects on a design whose
    tracker is not ``single`` (``monitor`` is single's), or on an ``inject grid`` (points
    around the prediction, a modelling device, not places on the frames). It stays
    violated, not replayed."""
    from lesmc.designs import registry

    p = next((p for p in run.properties if p.name == prop), None)
    if p is None or "inject" not in p.actions:
        return False
    tracker = registry.get(run.design).tracker if run.design in registry.names() else ""
    return p.inject_grid or tracker != "single"


def _case(run: RunDoc, i: int, j: int, cex_no: int) -> Case:
    res = run.results[j]
    rp = run.replay_inputs
    if rp is None or run.scene is None:
        raise UsageError(
            f"design run '{run.design}' was checked on a model without its scene: there is "
            "nothing to replay through the detector (write the results with lesmc verify)"
        )
    path = run.path(cex_no)
    loc = list(tracker_from_dict(rp.tracker, "results: replay_inputs.tracker").measured)
    full = np.array([np.array(run.states[q].s, float) for q in path.states], float)
    pos = full[:, loc]
    known = {d.id: (d.x, d.y) for step in run.scene.detections for d in step}
    opt = res.optimum
    prop = next((p for p in run.properties if p.name == res.property), None)
    actions = prop.actions if prop is not None else ("hide",)
    return Case(
        run=i,
        result=j,
        design=run.label,
        prop=res.property,
        first_frame=run.first_frame,
        obs=list(path.obs),
        positions=pos,
        halted=path.halted,
        hidden=[] if "inject" in actions else [e.hidden for e in run.hidden.get(res.property, ())],
        known=known,
        tracker=rp.tracker,
        dt=rp.dt,
        target=rp.target,
        objective_is_payoff=res.objective_source == "payoff",
        threshold=res.threshold,
        holds_op=res.holds_op,
        optimum=number(opt) if opt != "unknown" else math.nan,
        actions=actions,
        states=full,
        window=run.window,
    )


# ---------------------------------------------------------------- the detector, perturbed


#: One round of an attack on a frame: the centres of the windows and their perturbations.
Round = tuple[np.ndarray, np.ndarray]


@dataclass
class _Perturbed:
    """A frame's detector inputs with the attack's perturbations (0..255 grey levels).

    ``frames``: the m aligned previous frames and the current frame in float32 (16 MB
    at 2048x2048 instead of 32), the precision :func:`~lesmc.perception.windows.cut`
    gives the CNNs' windows anyway. ``exact``: each of them in float64 inside ``box``
    (the windows' bounding box; None: nothing perturbed), where the front end's
    arithmetic reads them: the same numbers as whole float64 frames would give.
    """

    frames: list[np.ndarray]
    box: tuple[slice, slice] | None
    exact: list[np.ndarray]


def _apply(base: list[np.ndarray], rounds: list[Round], size: int) -> _Perturbed:
    """The clean detector inputs ``base`` with each round's window perturbations (pixel
    scale [0, 1]) added at the pixels :func:`lesmc.perception.windows.cut` took them from
    and clipped to [0, 255], round after round (a repair adds rounds)."""
    frames = [s.astype(np.float32) for s in base]
    h, w = base[0].shape
    offs = np.arange(size)
    places = []
    for centres, deltas in rounds:
        org = origins(centres, size)
        ys = np.clip(org[:, 1, None] + offs, 0, h - 1)  # (windows, size): as cut() takes them
        xs = np.clip(org[:, 0, None] + offs, 0, w - 1)
        places.append((ys, xs, deltas))
    if not any(len(ys) for ys, _, _ in places):
        return _Perturbed(frames, None, [])
    y0 = min(int(ys.min()) for ys, _, _ in places if len(ys))
    y1 = max(int(ys.max()) for ys, _, _ in places if len(ys))
    x0 = min(int(xs.min()) for _, xs, _ in places if len(xs))
    x1 = max(int(xs.max()) for _, xs, _ in places if len(xs))
    box = (slice(y0, y1 + 1), slice(x0, x1 + 1))
    exact = []
    for c, s in enumerate(base):
        f = s[box].astype(np.float64)
        for ys, xs, deltas in places:
            for y, x, d in zip(ys - y0, xs - x0, deltas, strict=True):
                np.add.at(f, np.ix_(y, x), 255.0 * d[c].astype(np.float64))
            np.clip(f, 0.0, 255.0, out=f)
        frames[c][box] = f
        exact.append(f)
    return _Perturbed(frames, box, exact)


def _redetect(
    det: Detector, out: FrontEndOutput, p: _Perturbed, m: int
) -> tuple[FrameDetections, np.ndarray]:
    """The detector's step on perturbed inputs: background, subtraction, blobs, N_dr, N_lp.

    ``p`` holds the m aligned previous frames and the current frame, perturbed;
    the older aligned frames that only enter the background stay as they were.
    The background's median moves by exactly the perturbation's effect on it
    (with no perturbation everything equals the clean run, bit for bit). Outside
    ``p.box`` nothing moved, so the difference image there is the clean one; inside,
    it is computed from the float64 values.
    Returns the detections and the centres of the candidates N_dr accepted (the
    rows of their ``windows``).
    """
    import cv2

    from lesmc.perception.background import Aligned
    from lesmc.perception.blobs import blobs
    from lesmc.perception.frontend import FrontEndOutput

    clean = out.aligned.frames
    old = len(clean) - m  # the aligned frames only the background reads
    diff = _difference(out, p, m)
    cfg = det.frontend.cfg.blobs
    mask: np.ndarray = ((diff > cfg.delta_bc) & (out.aligned.valid > 0)).astype(np.uint8)
    mask *= 255
    if cfg.close_px > 1:
        kernel = cv2.getStructuringElement(cv2.MORPH_CROSS, (cfg.close_px, cfg.close_px))
        mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, kernel)
    cands = blobs(mask, diff, cfg)
    del diff, mask  # 20 MB at 2048x2048 that the CNNs do not read
    release()  # and what the subtraction freed goes back before the CNNs run
    pert_out = FrontEndOutput(
        out.index,
        p.frames[-1],
        cands,
        Aligned([*clean[:old], *p.frames[:-1]], out.aligned.valid),
        out.background,  # not read by detect(): the clean one stands in for the perturbed
        out.registration,
    )
    fd = det.detect(pert_out)
    assert fd.accepted is not None  # detect() records the rows N_dr accepted
    return fd, cands.centroid[fd.accepted]


def _difference(out: FrontEndOutput, p: _Perturbed, m: int) -> np.ndarray:
    """|I_k - I_bg| (Eq. 16) of the perturbed frame, float32, against the median background
    moved by the perturbed aligned frames (the clean run's gain kept)."""
    import cv2

    from lesmc.perception.background import gain, median

    clean = out.aligned.frames
    old = len(clean) - m
    diff = cv2.absdiff(out.frame, out.background).astype(np.float32)
    if p.box is None:
        return diff
    alpha = gain(median(clean), out.frame, out.aligned.valid)
    was_box = [c[p.box] for c in clean]
    now_box = [*was_box[:old], *p.exact[:-1]]
    changed = np.zeros(was_box[0].shape, bool)
    for a, b in zip(now_box, was_box, strict=True):
        changed |= a != b
    bg = out.background[p.box].astype(np.float64)
    if changed.any():
        ys, xs = np.nonzero(changed)
        sl = (slice(ys.min(), ys.max() + 1), slice(xs.min(), xs.max() + 1))
        now = np.median(np.stack([a[sl] for a in now_box]), axis=0)
        was = np.median(np.stack([b[sl].astype(np.float64) for b in was_box]), axis=0)
        bg[sl] += alpha * (now - was)
    diff[p.box] = np.abs(p.exact[-1] - bg)
    return diff


def _match(a: np.ndarray, b: np.ndarray, tol: float) -> np.ndarray:
    """For each row of ``a``, the nearest row of ``b`` within ``tol`` (−1: none)."""
    if not len(a) or not len(b):
        return np.full(len(a), -1)
    d = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=-1)
    j = d.argmin(axis=1)
    return np.where(d[np.arange(len(a)), j] <= tol, j, -1)


def _hidden_indices(fd: FrameDetections, hidden: list[Hidden]) -> list[int]:
    """The detection index of each hidden observation ``t:j``, refused if the frame lacks it."""
    for h in hidden:
        if re.fullmatch(r"[0-9]+:[0-9]+", h.obs, re.ASCII) is None:
            raise InputError(
                f"hidden detection '{h.obs}' is not FRAME:INDEX: these results were not made "
                "from perceived frames (lesmc verify), so there is nothing to replay",
                Location("--frames"),
            )
    idx = [int(h.obs.split(":")[1]) for h in hidden]
    for h, j in zip(hidden, idx, strict=True):
        if not 0 <= j < len(fd.positions):
            raise InputError(
                f"frame {fd.index} has {len(fd.positions)} detections, not {h.obs}: the frames "
                "are not those the results were made from",
                Location("--frames"),
            )
    return idx


def _perturbation(
    h: Hidden,
    j: int,
    fd: FrameDetections,
    centre: np.ndarray,
    rec: float,
    flipped: bool,
    delta: np.ndarray,
) -> dict[str, Any]:
    """One hidden detection's recomputed attack, refused if its payoff differs from the results."""
    from lesmc.perception.cnn import DR_SIZE

    if math.isfinite(h.payoff) and not (
        math.isfinite(rec) and abs(rec - h.payoff) <= PAYOFF_RTOL * max(h.payoff, 1e-9)
    ):
        raise InputError(
            f"the attack on detection {h.obs} now costs {rec:g}, the results say "
            f"{h.payoff:g}: the frames, networks or attack settings differ from the run "
            "that wrote the results",
            Location("--frames"),
        )
    return {
        "step": h.step,
        "frame": fd.index,
        "obs": h.obs,
        "x": float(fd.positions[j, 0]),
        "y": float(fd.positions[j, 1]),
        "window_origin": [int(v) for v in np.rint(centre).astype(int) - DR_SIZE // 2],
        "payoff": h.payoff,
        "payoff_recomputed": rec if math.isfinite(rec) else "inf",
        "flipped_alone": flipped,
        "delta": np.round(delta, PERTURBATION_DIGITS).tolist(),
    }


def attack_frame(
    nets: Nets,
    det: Detector,
    out: FrontEndOutput,
    fd: FrameDetections,
    hidden: list[Hidden],
    cfg: AttackConfig,
    repair: bool = True,
) -> FrameAttack:
    """Recompute the hidden detections' perturbations, apply them together, detect again."""
    from lesmc.perception.attacks import payoffs
    from lesmc.perception.cnn import DR_SIZE

    m = nets.settings.m
    idx = _hidden_indices(fd, hidden)
    blobs_used = sorted({int(fd.source[j]) for j in idx})
    res = payoffs(nets.dr, fd.windows[blobs_used], nets.settings.delta_dr, cfg)
    release()  # what the attack freed goes back before the frames are copied
    by_blob = dict(zip(blobs_used, range(len(blobs_used)), strict=True))
    # the clean candidate centres of the blobs, where cut() took the windows
    # candidate rows of Q_dr, in order: as the detection of this frame found them
    accepted = fd.accepted if fd.accepted is not None else _accepted(det, out)
    assert len(accepted) == len(fd.windows)
    centres = out.candidates.centroid[accepted[blobs_used]]
    fa = FrameAttack(fd.index, hidden[0].step if hidden else 0, fd)
    for h, j in zip(hidden, idx, strict=True):
        r = by_blob[int(fd.source[j])]
        rec, flipped = float(res.payoff[r]), bool(res.flipped[r])
        fa.perturbations.append(
            _perturbation(h, j, fd, centres[r], rec, flipped, res.perturbation[r])
        )
    rounds = [(centres, res.perturbation)]
    after, kept = _redetect(
        det, out, _apply(stack(out.frame, out.aligned.frames, m), rounds, DR_SIZE), m
    )
    _diagnose(fa, fd, after, idx)
    if repair:
        after = _repair(nets, det, out, fd, fa, idx, rounds, after, kept, cfg)
    fa.detections = after
    return fa


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
    idx = _hidden_indices(fd, hidden)
    rounds: list[Round] = []
    if idx:
        rounds.append(_hide_round(nets, det, out, fd, fa, hidden, idx, cfg))
    if row is not None:
        rounds.append(_inject_round(nets, out, fa, step, taken, row, cfg))
    release()
    if not rounds:
        return fa
    base = stack(out.frame, out.aligned.frames, m_nets)
    after, kept = _redetect(det, out, _apply(base, rounds, DR_SIZE), m_nets)
    _diagnose(fa, fd, after, idx)
    wanted = None if row is None else out.candidates.centroid[[row]]
    if repair:
        after = _repair(nets, det, out, fd, fa, idx, rounds, after, kept, cfg, wanted)
    if wanted is not None:  # the injected detection is wanted: not an extra one
        if _match(wanted, after.positions, DET_TOL_PX)[0] < 0:
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
    accepted = fd.accepted if fd.accepted is not None else _accepted(det, out)
    centres = out.candidates.centroid[accepted[blobs_used]]
    by_blob = dict(zip(blobs_used, range(len(blobs_used)), strict=True))
    for h, j in zip(hidden, idx, strict=True):
        r = by_blob[int(fd.source[j])]
        rec, ok = float(res.payoff[r]), bool(res.flipped[r])
        fa.cost += rec
        # the results record no per-detection payoff under inject: the recomputed one
        # stands in, and the path's cost is checked as a whole (_replay_case)
        h = replace(h, payoff=rec)
        fa.perturbations.append(_perturbation(h, j, fd, centres[r], rec, ok, res.perturbation[r]))
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


def _repair(
    nets: Nets,
    det: Detector,
    out: FrontEndOutput,
    fd: FrameDetections,
    fa: FrameAttack,
    idx: list[int],
    applied: list[Round],
    after: FrameDetections,
    kept: np.ndarray,
    cfg: AttackConfig,
    wanted: np.ndarray | None = None,
) -> FrameDetections:
    """The repaired attack: hide, jointly with the frame's perturbation (``applied``), every
    detection the model does not have (hidden ones that survive, extra ones; not those
    at ``wanted``, the injected ones), up to REPAIR_ROUNDS times; the detections after it
    (``fa`` records the rounds and the extra cost)."""
    from lesmc.perception.attacks import payoffs
    from lesmc.perception.cnn import DR_SIZE

    m = nets.settings.m
    rounds = 0
    while (fa.still or fa.extra) and rounds < REPAIR_ROUNDS:
        unwanted = _unwanted(fd, after, idx, wanted)
        if not unwanted:
            break
        rounds += 1
        rows = sorted({int(after.source[j]) for j in unwanted})
        more = payoffs(nets.dr, after.windows[rows], nets.settings.delta_dr, cfg)
        if not more.flipped.any():
            break
        ok = more.flipped
        fa.extra_cost += float(more.payoff[ok].sum())
        cs = kept[rows][ok]
        applied.append((cs, more.perturbation[ok]))
        base = stack(out.frame, out.aligned.frames, m)
        after, kept = _redetect(det, out, _apply(base, applied, DR_SIZE), m)
        _diagnose(fa, fd, after, idx)
    fa.repaired_rounds = rounds
    return after


def _unwanted(
    fd: FrameDetections,
    after: FrameDetections,
    hidden_idx: list[int],
    wanted: np.ndarray | None = None,
) -> list[int]:
    """Rows of ``after`` that match no clean detection the attack keeps (nor a position of
    ``wanted``: injected detections)."""
    keep = np.array([j for j in range(len(fd.positions)) if j not in set(hidden_idx)], int)
    ok = fd.positions[keep] if wanted is None else np.vstack([fd.positions[keep], wanted])
    back = _match(after.positions, ok, DET_TOL_PX)
    return [int(j) for j in np.flatnonzero(back < 0)]


def _accepted(det: Detector, out: FrontEndOutput) -> np.ndarray:
    """Rows of Q_bc that N_dr accepts (in the order of ``FrameDetections.windows``)."""
    from lesmc.perception.cnn import DR_SIZE
    from lesmc.perception.detector import dr_probability

    nets = det.nets
    frames = stack(out.frame, out.aligned.frames, nets.settings.m)
    win = cut(frames, out.candidates.centroid, DR_SIZE)
    keep: np.ndarray = np.flatnonzero(
        dr_probability(nets, win, det.cfg.batch) > nets.settings.delta_dr
    )
    return keep


def _diagnose(
    fa: FrameAttack,
    fd: FrameDetections,
    after: FrameDetections,
    hidden_idx: list[int],
) -> None:
    """What the perturbed frame's detections are compared with the clean ones."""
    from lesmc.perception.cnn import DR_SIZE

    clean, now = fd.positions, after.positions
    fwd = _match(clean, now, DET_TOL_PX)
    back = _match(now, clean, DET_TOL_PX)
    hid = set(hidden_idx)
    fa.still = [f"{fd.index}:{j}" for j in sorted(hid) if fwd[j] >= 0]
    fa.lost = [f"{fd.index}:{j}" for j in range(len(clean)) if j not in hid and fwd[j] < 0]
    shared = {int(fd.source[j]) for j in hid}
    fa.shared = [d for d in fa.lost if int(fd.source[int(d.split(":")[1])]) in shared]
    fa.moved = [
        (f"{fd.index}:{j}", float(np.linalg.norm(clean[j] - now[fwd[j]])))
        for j in range(len(clean))
        if j not in hid and fwd[j] >= 0 and np.linalg.norm(clean[j] - now[fwd[j]]) > 1e-6
    ]
    fa.extra = [(float(p[0]), float(p[1])) for p, b in zip(now, back, strict=True) if b < 0]
    half = DR_SIZE // 2
    near = []
    for j in sorted(hid):
        for k in range(len(clean)):
            if k == j:
                continue
            if np.all(np.abs(clean[k] - clean[j]) <= 2 * half):
                near.append((f"{fd.index}:{j}", f"{fd.index}:{k}"))
    fa.overlaps = near


# ---------------------------------------------------------------- the tracker


def _footage(dets: dict[int, FrameDetections], case: Case, attacked: dict[int, FrameDetections]):  # type: ignore[no-untyped-def]
    """The scene of the replayed detections (attacked frames replaced), the case's tracker."""

    steps = sorted(dets)
    frames = []
    for k in steps:
        fd = attacked.get(k, dets[k])
        to_next = dets[k + 1].from_prev if k + 1 in dets else None
        ds = tuple(
            Detection(f"{k}:{j}", float(x), float(y), 1.0) for j, (x, y) in enumerate(fd.positions)
        )
        frames.append(Frame(k, ds, to_next))
    tracker = tracker_from_dict(case.tracker, "results: replay_inputs.tracker")
    return Scene(case.dt, tuple(frames), case.target, tracker, {})


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


def frame_story(fa: FrameAttack) -> str:
    """What the perturbations did to one frame's detections, in words."""
    parts = []
    if fa.still:
        ov = sorted({b for a, b in fa.overlaps if a in fa.still})
        parts.append(
            f"hidden detection{'s' if len(fa.still) > 1 else ''} {', '.join(fa.still)} still "
            "detected with all perturbations of the frame applied"
            + (f" (21x21 windows overlap {', '.join(ov)})" if ov else "")
        )
    if fa.shared:
        parts.append(
            f"detection{'s' if len(fa.shared) > 1 else ''} {', '.join(fa.shared)} lost as well: "
            "N_lp found it in the same Q_dr blob as a hidden detection, and hiding that blob's "
            "N_dr window hides both (the model prices them as separate attacks)"
        )
    other = [d for d in fa.lost if d not in fa.shared]
    if other:
        parts.append(
            f"detection{'s' if len(other) > 1 else ''} {', '.join(other)} lost as well "
            "(overlapping windows interact)"
        )
    moved = [(d, e) for d, e in fa.moved if e > 0.05]
    if moved:
        parts.append(
            "detection"
            + ("s " if len(moved) > 1 else " ")
            + ", ".join(f"{d} moved {e:.2f} px" for d, e in moved[:4])
            + (f" and {len(moved) - 4} more" if len(moved) > 4 else "")
        )
    if fa.extra:
        parts.append(
            "extra detection"
            + ("s " if len(fa.extra) > 1 else " ")
            + ", ".join(f"({x:.1f}, {y:.1f})" for x, y in fa.extra)
        )
    if fa.injected:
        parts.append(
            f"injected {', '.join(fa.injected)} (its N_dr window perturbed until N_dr accepts it)"
        )
    if fa.not_injected:
        parts.append(f"injected {', '.join(fa.not_injected)} not detected after all")
    if fa.repaired_rounds:
        parts.append(f"after {fa.repaired_rounds} round(s) of the repaired joint attack")
    return "; ".join(parts)


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
    delta_bc: int = 12,
    on_frame: Callable[[], None] | None = None,
    repair: bool = True,
    clean: Mapping[int, FrameDetections] | None = None,
    registrations: Mapping[int, Registration] | None = None,
) -> Outcome:
    """Replay every violated property's counterexample of ``doc`` (or ``prop``'s) on ``frames``.

    ``clean``: each frame's detections as the perception of these frames with these
    networks made them (``lesmc verify`` hands over its own): then only the attacked
    frames, after the ``history`` frames before each that the front end needs, go
    through the detector; ``registrations``, that perception's (``PerceiveRun``), spare
    the front end describing and matching those frames again (tests/test_replay.py
    checks that every way agrees).
    """
    from lesmc.perception.detector import Detector, DetectorConfig

    t0 = time.monotonic()
    todo = cases(doc, prop)
    if not todo:
        return Outcome({}, 0.0)
    fe, attack_cfg = _settings(doc, history, delta_bc)
    history = fe.history
    last = max(c.first_frame + len(c.positions) - 1 for c in todo)
    by_frame = _hidden_by_frame(todo)
    by_inject = _inject_by_frame(todo)
    attacked: list[dict[int, FrameAttack]] = [{} for _ in todo]

    def attack(det: Any, out: FrontEndOutput, fd: FrameDetections) -> None:
        def one(group: list[Hidden]) -> FrameAttack:
            return attack_frame(nets, det, out, fd, group, attack_cfg, repair)

        for ci, fa in _shared(_groups(by_frame.get(fd.index, [])), one).items():
            attacked[ci][fd.index] = fa
        _inject_cases(nets, det, out, fd, todo, by_inject, attacked, attack_cfg, repair)
        release()  # the frame's temporaries go back to the system (common/memory.py)

    def detector() -> Any:
        det = Detector(nets, DetectorConfig(frontend=fe))
        det.frontend.known = registrations or {}
        return det

    if clean is None:  # every frame through the detector
        clean = _all_frames(frames, detector(), last, attack, on_frame)
    else:  # the clean frames' detections are given: only the attacked ones are detected
        clean = dict(clean)
        wanted = sorted(set(by_frame) | set(by_inject))
        _attacked_frames(frames, detector, wanted, history, attack, on_frame)
    _check_last(clean, last)
    for c in todo:
        _check_known(c, clean)
    replays = {(c.run, c.result): _replay_case(c, clean, attacked[ci]) for ci, c in enumerate(todo)}
    return Outcome(replays, time.monotonic() - t0)


def _check_last(clean: Mapping[int, FrameDetections], last: int) -> None:
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
    from lesmc.perception.blobs import BlobConfig
    from lesmc.perception.frontend import FrontEndConfig

    perception = doc.perception
    history = int(history if perception.history is None else perception.history)
    delta_bc = int(delta_bc if perception.delta_bc is None else perception.delta_bc)
    fe = FrontEndConfig(history=history, blobs=BlobConfig(delta_bc=delta_bc))
    return fe, AttackConfig(**perception.attack)


def _hidden_by_frame(todo: list[Case]) -> dict[int, list[tuple[int, Hidden]]]:
    """Per frame, the detections the cases hide there: (case number, detection)."""
    out: dict[int, list[tuple[int, Hidden]]] = {}
    for ci, c in enumerate(todo):
        for h in c.hidden:
            out.setdefault(h.frame, []).append((ci, h))
    return out


def _inject_cases(
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


def _inject_by_frame(todo: list[Case]) -> dict[int, list[tuple[int, int]]]:
    """Per frame, the ``allow hide, inject`` cases attacked there: (case number, step), one
    for every step of the case's window (:func:`inject_frame` derives the attack)."""
    out: dict[int, list[tuple[int, int]]] = {}
    for ci, c in enumerate(todo):
        if not c.injects:
            continue
        for k in range(max(c.window[0], 1), min(c.window[1], len(c.positions) - 1) + 1):
            out.setdefault(c.first_frame + k, []).append((ci, k))
    return out


def _all_frames(
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
        got = det.push(frames.read(i))
        if on_frame:
            on_frame()
        if got is None:
            continue
        out, fd = got
        clean[fd.index] = _light(fd)
        attack(det, out, fd)
    return clean


def _attacked_frames(
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
            got = det.push(frames.read(i))
            if on_frame:
                on_frame()
            if got is not None and got[1].index in run:
                attack(det, *got)


def _replay_case(
    c: Case, clean: dict[int, FrameDetections], attacked: dict[int, FrameAttack]
) -> dict[str, Any]:
    """One counterexample: the tracker on the frames' detections with the attacked frames'
    ones, compared with the model's path; a repaired attack that costs enough for the
    property to hold (Eq. 5 + the repair) is no counterexample."""

    first = c.first_frame
    if c.injects and c.objective_is_payoff and math.isfinite(c.optimum):
        cost = sum(fa.cost for fa in attacked.values())
        if not abs(cost - c.optimum) <= PAYOFF_RTOL * max(c.optimum, 1e-9):
            raise InputError(
                f"the attack of {c.design}'s counterexample of {c.prop} now costs {cost:g}, "
                f"the results say {c.optimum:g}: the frames, networks or attack settings "
                "differ from the run that wrote the results",
                Location("--frames"),
            )
    dets = {k: v for k, v in clean.items() if first <= k <= first + len(c.positions) - 1}
    scene = _footage(dets, c, {k: fa.detections for k, fa in attacked.items()})
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
    return {
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


def _shared(
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


def _groups(items: list[tuple[int, Hidden]]) -> list[tuple[int, list[Hidden]]]:
    out: dict[int, list[Hidden]] = {}
    for ci, h in items:
        out.setdefault(ci, []).append(h)
    return sorted(out.items())


def _light(fd: FrameDetections) -> FrameDetections:
    """The detections without their windows (the tracker needs positions only)."""
    return replace(fd, windows=fd.windows[:0])


def _check_known(c: Case, clean: dict[int, FrameDetections]) -> None:
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
    from lesmc.perception.cnn import load_nets
    from lesmc.video.reader import open_frames

    cases(doc, prop)  # an unknown property is an error before the video is read
    history = 4 if doc.perception.history is None else doc.perception.history
    frames = open_frames(frames_dir, history + 1)
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


def verdict_rows(
    doc: ResultsDoc, outcome: Outcome, prop: str | None
) -> tuple[list[dict[str, Any]], set[str]]:
    """One row per replayed counterexample (model verdict, verdict after the replay, the
    replay), and every verdict the results hold after it (for the exit status)."""
    rows: list[dict[str, Any]] = []
    verdicts: set[str] = set()
    for c in cases(doc, prop):
        obj = outcome.replays[(c.run, c.result)]
        verdict = "violated" if read_replay(obj).status == "confirmed" else "unknown"
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
