"""One attacked frame through the window pipeline's detector (docs/semantics.md, "Replay").

The attacks' perturbations of a frame (:data:`Round`) are added together to the
detector's inputs of that frame (:func:`perturb`), the detector's step is run again on
them (:func:`redetect`), the detections after are compared with the clean ones
(:func:`diagnose`) and, when hidden detections survive because windows interact, the
attack is repaired (:func:`repair_frame`). :func:`attack_frame` does all of it for the
hidden detections of a hide-only counterexample; lesmc/replay/inject.py for injections.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from lesmc.common.errors import InputError, Location
from lesmc.common.memory import release
from lesmc.perception.windows import cut, origins, stack
from lesmc.replay.case import (
    DET_TOL_PX,
    PERTURBATION_DIGITS,
    REPAIR_ROUNDS,
    FrameAttack,
    check_payoff,
    perturbation_record,
)
from lesmc.replay.repair import run_repair
from lesmc.results.read import HiddenDoc as Hidden

if TYPE_CHECKING:
    from lesmc.perception.attack_settings import AttackConfig
    from lesmc.perception.attacks import AttackResult, Towards
    from lesmc.perception.cnn import Nets
    from lesmc.perception.detector import Detector, FrameDetections
    from lesmc.perception.frontend import FrontEndOutput


#: One round of an attack on a frame: the centres of the windows and their perturbations.
Round = tuple[np.ndarray, np.ndarray]


@dataclass
class Perturbed:
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


def perturb(base: list[np.ndarray], rounds: list[Round], size: int) -> Perturbed:
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
        return Perturbed(frames, None, [])
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
    return Perturbed(frames, box, exact)


def redetect(
    det: Detector, out: FrontEndOutput, p: Perturbed, m: int
) -> tuple[FrameDetections, np.ndarray]:
    """The detector's step on perturbed inputs: background, subtraction, blobs, N_dr, N_lp.

    ``p`` holds the m aligned previous frames and the current frame, perturbed;
    the older aligned frames that only enter the background stay as they were.
    The background's median moves by exactly the perturbation's effect on it
    (with no perturbation everything equals the clean run, bit for bit). Outside
    ``p.box`` nothing moved, so the difference image there is the clean one; inside,
    it is computed from the float64 values.
    Returns the detections and the centroids of every candidate of Q_bc (those N_dr
    accepted are the rows ``fd.accepted``, in the order of the detections' ``windows``).
    """
    import cv2

    from lesmc.perception.background import Aligned
    from lesmc.perception.blobs import blobs
    from lesmc.perception.frontend import FrontEndOutput

    clean = out.aligned.frames
    old = len(clean) - m  # the aligned frames only the background reads
    diff = difference(out, p, m)
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
    return fd, cands.centroid


def difference(out: FrontEndOutput, p: Perturbed, m: int) -> np.ndarray:
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


def nearest_within(a: np.ndarray, b: np.ndarray, tol: float) -> np.ndarray:
    """For each row of ``a``, the nearest row of ``b`` within ``tol`` (−1: none)."""
    if not len(a) or not len(b):
        return np.full(len(a), -1)
    d = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=-1)
    j = d.argmin(axis=1)
    return np.where(d[np.arange(len(a)), j] <= tol, j, -1)


def hidden_indices(fd: FrameDetections, hidden: list[Hidden]) -> list[int]:
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


def perturbation(
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

    check_payoff(h, rec, "networks")
    return perturbation_record(
        (h.step, fd.index, h.obs),
        (fd.positions[j, 0], fd.positions[j, 1]),
        np.rint(centre).astype(int) - DR_SIZE // 2,
        (h.payoff, rec),
        flipped,
        np.round(delta, PERTURBATION_DIGITS).tolist(),
    )


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
    idx = hidden_indices(fd, hidden)
    blobs_used = sorted({int(fd.source[j]) for j in idx})
    res = payoffs(nets.dr, fd.windows[blobs_used], nets.settings.delta_dr, cfg)
    release()  # what the attack freed goes back before the frames are copied
    by_blob = dict(zip(blobs_used, range(len(blobs_used)), strict=True))
    # the clean candidate centres of the blobs, where cut() took the windows
    # candidate rows of Q_dr, in order: as the detection of this frame found them
    accepted = fd.accepted if fd.accepted is not None else accepted_rows(det, out)
    assert len(accepted) == len(fd.windows)
    centres = out.candidates.centroid[accepted[blobs_used]]
    fa = FrameAttack(fd.index, hidden[0].step if hidden else 0, fd)
    for h, j in zip(hidden, idx, strict=True):
        r = by_blob[int(fd.source[j])]
        rec, flipped = float(res.payoff[r]), bool(res.flipped[r])
        fa.perturbations.append(
            perturbation(h, j, fd, centres[r], rec, flipped, res.perturbation[r])
        )
    rounds = [(centres, res.perturbation)]
    after, cands = redetect(
        det, out, perturb(stack(out.frame, out.aligned.frames, m), rounds, DR_SIZE), m
    )
    diagnose(fa, fd, after, idx)
    if repair:
        after, _ = repair_frame(nets, det, out, fd, fa, idx, rounds, (after, cands), cfg)
    fa.detections = after
    return fa


def repair_frame(
    nets: Nets,
    det: Detector,
    out: FrontEndOutput,
    fd: FrameDetections,
    fa: FrameAttack,
    idx: list[int],
    applied: list[Round],
    seen: tuple[FrameDetections, np.ndarray],
    cfg: AttackConfig,
    wanted: np.ndarray | None = None,
) -> tuple[FrameDetections, np.ndarray]:
    """The repaired attack, for hiding and injecting alike: on the frame as the
    perturbations ``applied`` leave it (``seen``: its detections and the centroids of its
    Q_bc, :func:`redetect`), hide every detection the model does not have (hidden ones
    that survive, extra ones; not those at ``wanted``, the injected ones), detect again,
    then perturb towards "vehicle" the N_dr window of every ``wanted`` position not
    detected (priced as the first injection), detect again; up to REPAIR_ROUNDS rounds
    (a round in which no window flips ends the repair and is not counted). Each round's
    perturbations are cut from the already perturbed inputs and added to them; ``fa``
    records the rounds and their cost (``extra_cost``: each extra window's norm once,
    where it overlaps another window too). Returns the detections after it and the
    centroids of the perturbed frame's Q_bc."""
    w = _WindowFrame(nets, det, (out, fd), fa, idx, applied, seen, cfg, wanted)
    run_repair(fa, w, REPAIR_ROUNDS)
    return w.after, w.cands


class _WindowFrame:
    """A frame of the window pipeline as :func:`~lesmc.replay.repair.run_repair` sees it:
    its detections and Q_bc centroids as the perturbations ``applied`` leave it."""

    def __init__(
        self,
        nets: Nets,
        det: Detector,
        clean: tuple[FrontEndOutput, FrameDetections],
        fa: FrameAttack,
        idx: list[int],
        applied: list[Round],
        seen: tuple[FrameDetections, np.ndarray],
        cfg: AttackConfig,
        wanted: np.ndarray | None,
    ) -> None:
        self.nets, self.det, (self.out, self.fd), self.fa = nets, det, clean, fa
        self.idx, self.applied, self.cfg, self.wanted = idx, applied, cfg, wanted
        self.after, self.cands = seen
        self.frames = _perturbed(self.out, applied, nets.settings.m)

    def wrong(self) -> bool:
        """A detection the model does not have, or a wanted position not detected."""
        unwanted = _unwanted(self.fd, self.after, self.idx, self.wanted)
        return bool(unwanted) or _missing(self.wanted, self.after)

    def attack(self, towards: Towards) -> tuple[float, int, Round] | None:
        """:func:`_rehide` or :func:`_reinject` on the perturbed frame (and the number of
        windows they perturb)."""
        act = _rehide if towards == "hide" else _reinject
        seen = (self.after, self.cands, self.frames)
        got = act(self.nets, seen, self.fd, self.idx, self.wanted, self.cfg)
        return None if got is None else (got[0], len(got[1][0]), got[1])

    def apply(self, more: Round) -> None:
        """``more`` added to the rounds, the frame detected again and diagnosed."""
        m = self.nets.settings.m
        self.applied.append(more)
        self.frames = _perturbed(self.out, self.applied, m)
        self.after, self.cands = redetect(self.det, self.out, self.frames, m)
        diagnose(self.fa, self.fd, self.after, self.idx)


#: What a repair round sees of the perturbed frame: its detections, the centroids of its
#: Q_bc and the perturbed detector inputs.
Seen = tuple["FrameDetections", np.ndarray, Perturbed]


def _perturbed(out: FrontEndOutput, applied: list[Round], m: int) -> Perturbed:
    """The frame's detector inputs with every round of ``applied``."""
    from lesmc.perception.cnn import DR_SIZE

    return perturb(stack(out.frame, out.aligned.frames, m), applied, DR_SIZE)


def _rehide(
    nets: Nets,
    seen: Seen,
    fd: FrameDetections,
    idx: list[int],
    wanted: np.ndarray | None,
    cfg: AttackConfig,
) -> tuple[float, Round] | None:
    """The repair's hiding step: the N_dr windows (of the perturbed inputs) of the
    detections the model does not have, attacked away from "vehicle"; their cost and
    the perturbations that flip (None: nothing to hide, or no window flips)."""
    from lesmc.perception.attacks import payoffs

    after, cands, _ = seen
    unwanted = _unwanted(fd, after, idx, wanted)
    if not unwanted:
        return None
    rows = sorted({int(after.source[j]) for j in unwanted})
    more = payoffs(nets.dr, after.windows[rows], nets.settings.delta_dr, cfg)
    assert after.accepted is not None  # redetect() keeps the rows N_dr accepts
    return _flipped(more, cands[after.accepted[rows]])


def _reinject(
    nets: Nets,
    seen: Seen,
    fd: FrameDetections,
    idx: list[int],
    wanted: np.ndarray | None,
    cfg: AttackConfig,
) -> tuple[float, Round] | None:
    """The repair's injecting step: each ``wanted`` position not detected whose blob the
    perturbed frame still has in Q_bc (a centroid within DET_TOL_PX) gets that blob's
    N_dr window, cut from the perturbed inputs, attacked towards "vehicle"; their cost
    and the perturbations that flip (None: nothing missing, no such blob, or none flips)."""
    from lesmc.perception.attacks import payoffs
    from lesmc.perception.cnn import DR_SIZE

    after, cands, frames = seen
    if wanted is None or not len(wanted):
        return None
    gone = wanted[nearest_within(wanted, after.positions, DET_TOL_PX) < 0]
    at = nearest_within(gone, cands, DET_TOL_PX)
    centres = cands[at[at >= 0]]
    if not len(centres):  # nothing missing, or no blob left where it is
        return None
    res = payoffs(
        nets.dr, cut(frames.frames, centres, DR_SIZE), nets.settings.delta_dr, cfg, "inject"
    )
    return _flipped(res, centres)


def _flipped(res: AttackResult, centres: np.ndarray) -> tuple[float, Round] | None:
    """A repair step's windows at ``centres`` attacked (``res``): the cost and the
    perturbations of those that flip N_dr; None when none does."""
    ok = res.flipped
    if not ok.any():
        return None
    return float(res.payoff[ok].sum()), (centres[ok], res.perturbation[ok])


def _missing(wanted: np.ndarray | None, after: FrameDetections) -> bool:
    """Whether a ``wanted`` position (an injected candidate) has no detection within
    DET_TOL_PX in ``after``."""
    if wanted is None or not len(wanted):
        return False
    return bool((nearest_within(wanted, after.positions, DET_TOL_PX) < 0).any())


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
    back = nearest_within(after.positions, ok, DET_TOL_PX)
    return [int(j) for j in np.flatnonzero(back < 0)]


def accepted_rows(det: Detector, out: FrontEndOutput) -> np.ndarray:
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


def diagnose(
    fa: FrameAttack,
    fd: FrameDetections,
    after: FrameDetections,
    hidden_idx: list[int],
) -> None:
    """What the perturbed frame's detections are compared with the clean ones."""
    from lesmc.perception.cnn import DR_SIZE

    clean, now = fd.positions, after.positions
    fwd = nearest_within(clean, now, DET_TOL_PX)
    back = nearest_within(now, clean, DET_TOL_PX)
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
