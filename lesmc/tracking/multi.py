"""Multi-target trackers composed of parts (lesmc/tracking/parts; docs/trackers.md), and
the ``sort`` preset: Bewley et al.'s SORT (2016).

One frame of :class:`MultiTargetTracker`: the predictor predicts every track; the deleter
drops tracks whose predicted box is not a box; the hypothesiser scores every (detection,
track) pair; the associator assigns detections to tracks; the updater updates the matched
tracks; every unmatched detection starts a track (ids from a counter, 1 first); the
initiator says which tracks are output (``confirmed``); the deleter ends the tracks
missed too long. Step 0 is the scene's first frame: every object is tracked from there.

``lesmc track`` runs it unattacked; ``lesmc check`` unfolds its attacked runs
(lesmc/unfold/multi.py) for the identity and ``dist`` measures, as does
``lesmc.check`` (lesmc/pipeline/multi.py); ``lesmc build`` writes that model and
``lesmc export --format drn|prism`` exports it; ``verify`` refuses a multi-target design
so far (lesmc/designs/registry.py ``not_yet``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar, Protocol

import numpy as np

from lesmc.common.errors import UsageError
from lesmc.model.identity import NONE, target_track
from lesmc.scene import Footage, Frame, Scene
from lesmc.scene.located import scene_error
from lesmc.tracking.parts.associator import GlobalAssociator
from lesmc.tracking.parts.box_filter import BoxFilter
from lesmc.tracking.parts.boxes import iou
from lesmc.tracking.parts.deleter import MaxAgeDeleter
from lesmc.tracking.parts.hypothesiser import IouHypothesiser
from lesmc.tracking.parts.initiator import MinHitsInitiator
from lesmc.tracking.parts.tracks import Tracks


@dataclass(frozen=True)
class MultiState:
    """A multi-target tracker between frames: its tracks, the next id, the frames seen."""

    tracks: Tracks
    next_id: int = 1
    frames: int = 0


@dataclass(frozen=True)
class FrameTracks:
    """The tracks after one frame: boxes (n, 4) (a point tracker's: positions (n, 2)),
    ids, whether each is output, the detection each was updated with or started from
    (−1: none, it coasted)."""

    boxes: np.ndarray
    ids: np.ndarray
    confirmed: np.ndarray
    det: np.ndarray
    since: np.ndarray

    def status(self, i: int) -> str:
        """``confirmed`` (output), ``coasting`` (not updated at this frame) or
        ``tentative`` (updated, not output yet)."""
        if self.confirmed[i]:
            return "confirmed"
        return "coasting" if self.since[i] > 0 else "tentative"


@dataclass(frozen=True)
class MultiTargetTracker:
    """A tracker composed of a predictor/updater, a hypothesiser, an associator, an
    initiator and a deleter."""

    filter: BoxFilter = field(default_factory=BoxFilter.sort)
    hypothesiser: IouHypothesiser = field(default_factory=IouHypothesiser)
    associator: GlobalAssociator = field(default_factory=GlobalAssociator)
    initiator: MinHitsInitiator = field(default_factory=MinHitsInitiator)
    deleter: MaxAgeDeleter = field(default_factory=MaxAgeDeleter)

    def initial(self) -> MultiState:
        """No tracks before the first frame."""
        return MultiState(Tracks.empty(self.filter.m.dim))

    def step(self, state: MultiState, boxes: np.ndarray) -> tuple[MultiState, FrameTracks]:
        """One frame with detections ``boxes`` (k, 4): the next state and its tracks."""
        frames = state.frames + 1
        t = self.filter.predict(state.tracks)
        t = t.take(self.deleter.valid(self.filter.boxes(t)))
        score = self.hypothesiser.scores(boxes, self.filter.boxes(t))
        a = self.associator.assign(score, self.hypothesiser.threshold)
        t = self.filter.update(t, a.pairs[:, 1], boxes[a.pairs[:, 0]])
        t = t.concat(self.filter.start(boxes[a.new], state.next_id))
        det = np.full(len(t), -1, dtype=np.int64)
        det[a.pairs[:, 1]] = a.pairs[:, 0]
        det[len(t) - len(a.new) :] = a.new
        out = FrameTracks(
            self.filter.boxes(t), t.id, self.initiator.confirmed(t, frames), det, t.since
        )
        alive = self.deleter.alive(t)
        nxt = MultiState(t.take(alive), state.next_id + len(a.new), frames)
        return nxt, _take(out, alive)


def _take(f: FrameTracks, keep: np.ndarray) -> FrameTracks:
    return FrameTracks(f.boxes[keep], f.ids[keep], f.confirmed[keep], f.det[keep], f.since[keep])


def sort_tracker(
    min_hits: int = 3, max_age: int = 1, iou_threshold: float = 0.3
) -> MultiTargetTracker:
    """The ``sort`` preset: SORT's box filter, IoU hypothesiser, global assignment,
    ``min_hits`` initiator and ``max_age`` deleter (defaults: SORT's)."""
    return MultiTargetTracker(
        BoxFilter.sort(),
        IouHypothesiser(iou_threshold),
        GlobalAssociator(),
        MinHitsInitiator(min_hits),
        MaxAgeDeleter(max_age),
    )


def need_boxes(frames: tuple[Frame, ...], design: str, path: str) -> None:
    """A box tracker needs a box on every detection and injection candidate: a located
    error at the first without."""
    for f in frames:
        if not (f.has_boxes and f.candidates_have_boxes):
            d, kind = next(
                (d, kind)
                for kind, ds in (("detection", f.detections), ("candidate", f.candidates))
                for d in ds
                if d.w is None or d.h is None
            )
            raise scene_error(
                path,
                None,
                [
                    (
                        f"frame {f.step}, {kind} '{d.id}'",
                        f"has no box (w, h): the {design} design's IoU cost needs a box on "
                        f"every {kind} (scene format 2; `lesmc import mot` keeps them, "
                        "with --point center)",
                    )
                ],
            )


@dataclass(frozen=True)
class MultiStep:
    """One step of a multi-target run: the frame, its tracks and the target's track id."""

    step: int
    frame: int
    tracks: FrameTracks
    target_id: int | None


class MultiDesign(Protocol):
    """What the registry makes of a multi-target design: its unattacked run."""

    def run(self, end: int | None = None) -> list[MultiStep]:
        """The steps from the scene's first frame to ``end`` (default: the last)."""
        ...

    def reference_kind(self) -> str:
        """What the target's reference is: ``truth`` or ``unattacked``."""
        ...


class ComposedDesign:
    """A multi-target design: a composed tracker run on a scene's frames. Subclasses say
    what a frame's detections are to the tracker (:meth:`measurements`), where the
    target's reference is (:meth:`references`) and which track is the target's
    (:meth:`target_of`). Not a :class:`~lesmc.tracking.design.Design`: its attacked runs
    are unfolded by lesmc/unfold/multi.py, not by the batched unfolder."""

    #: the design reads a box on every detection (SORT's IoU); False: points suffice
    needs_boxes: ClassVar[bool] = False

    scene: Scene | Footage
    tracker: Any

    def measurements(self, frame: Frame) -> np.ndarray:
        """The frame's detections as the tracker reads them."""
        raise NotImplementedError

    def candidate_measurements(self, frame: Frame) -> np.ndarray:
        """The frame's injection candidates as the tracker would read them, were they
        injected (scene format 3; issue 61)."""
        raise NotImplementedError

    def references(self, steps: list[FrameTracks]) -> list[np.ndarray | None]:
        """The target's reference at each step of the unattacked run ``steps``."""
        raise NotImplementedError

    def target_of(self, ft: FrameTracks, ref: np.ndarray) -> int:
        """The target's track id among ``ft``'s tracks (NONE: none)."""
        raise NotImplementedError

    def reference_kind(self) -> str:
        """What :meth:`references` follows: ``truth`` or ``unattacked`` (the target's
        unattacked track)."""
        return "unattacked"

    def no_reference(self) -> str:
        """Why :meth:`references` finds none, for an error message."""
        return "no detection of its frame is at its start, or its track is never output"

    def run(self, end: int | None = None) -> list[MultiStep]:
        """The unattacked run from the scene's first frame to step ``end`` (default: its
        last frame), with the target's track id at each step."""
        frames = self.scene.frames
        last = len(frames) - 1 if end is None else end
        if not 0 <= last < len(frames):
            raise UsageError(
                f"end {last} is beyond the scene: its frames allow steps 0..{len(frames) - 1} "
                f"from its first frame {frames[0].step}"
            )
        state = self.tracker.initial()
        out: list[FrameTracks] = []
        for f in frames[: last + 1]:
            state, ft = self.tracker.step(state, self.measurements(f))
            out.append(ft)
        refs = self.references(out)
        ids = [
            NONE if r is None else self.target_of(ft, r) for ft, r in zip(out, refs, strict=True)
        ]
        return [
            MultiStep(k, frames[k].step, ft, None if tid == NONE else tid)
            for k, (ft, tid) in enumerate(zip(out, ids, strict=True))
        ]


class SortDesign(ComposedDesign):
    """The ``sort`` design: SORT on a scene's boxes (the tracker file's ``min_hits``,
    ``max_age``, ``iou_threshold``)."""

    #: every detection needs a box (:func:`need_boxes`): a point detector cannot feed it
    needs_boxes: ClassVar[bool] = True

    def __init__(self, scene: Scene | Footage, path: str = "<scene>") -> None:
        cfg = scene.tracker
        need_boxes(scene.frames, cfg.design, path)
        self.scene = scene
        self.tracker = sort_tracker(cfg.min_hits, cfg.max_age, cfg.iou_threshold)

    def measurements(self, frame: Frame) -> np.ndarray:
        """The detections' boxes (k, 4)."""
        return frame.boxes()

    def candidate_measurements(self, frame: Frame) -> np.ndarray:
        """The injection candidates' boxes (m, 4)."""
        return frame.candidate_boxes()

    def references(self, steps: list[FrameTracks]) -> list[np.ndarray | None]:
        """:func:`reference_boxes`."""
        return reference_boxes(self.scene, steps)

    def target_of(self, ft: FrameTracks, ref: np.ndarray) -> int:
        """:func:`target_of` (module-level)."""
        return target_of(ft, ref)

    def reference_kind(self) -> str:
        """:func:`reference_kind` (module-level)."""
        return reference_kind(self.scene)

    def no_reference(self) -> str:
        """Why :func:`reference_boxes` finds none (its rules)."""
        if self.reference_kind() == "truth":
            return "no ground-truth box of its frame holds its start"
        return "no detection box of its frame holds its start, or its track is never output"


def reference_kind(scene: Scene | Footage) -> str:
    """What the target's reference is: ``truth`` (its ground-truth track) when the scene's
    truth has boxes (``lesmc import mot --gt`` with ``--point center``), else
    ``unattacked`` (its unattacked track)."""
    return "truth" if any(t.sizes is not None for t in scene.truth) else "unattacked"


def reference_boxes(scene: Scene | Footage, steps: list[FrameTracks]) -> list[np.ndarray | None]:
    """The target's reference box at each step of the unattacked run ``steps`` (None: it
    does not exist there).

    When the scene's truth has boxes (:func:`reference_kind`), the reference is the target's
    ground-truth track: the truth track whose box, at the target's frame, holds the target's
    start (the nearest such centre, the first of equals); it exists at the frames where that
    track has a box. Else it is the target's unattacked track: the track that took, at the
    target's frame, the detection whose box holds the target's start (the same rule); it
    exists at the steps where the tracker outputs it (confirmed).
    """
    none: list[np.ndarray | None] = [None] * len(steps)
    if not isinstance(scene, Scene):
        return none
    k0 = scene.target.step - scene.frames[0].step
    if not 0 <= k0 < len(steps):
        return none
    if reference_kind(scene) == "truth":
        return _truth_reference(scene, len(steps))
    boxes = scene.frames[k0].boxes()
    j = _holding(boxes, scene.frames[k0].positions(), scene.target.start)
    return none if j is None else follow(steps, k0, j)


def follow(steps: list[FrameTracks], k0: int, det: int) -> list[np.ndarray | None]:
    """The box (or position) of the track that took detection ``det`` at step ``k0``, at
    each step where the tracker outputs it (confirmed); None elsewhere."""
    out: list[np.ndarray | None] = [None] * len(steps)
    took = np.nonzero(steps[k0].det == det)[0]
    if not took.size:
        return out
    ref = int(steps[k0].ids[took[0]])
    for k, ft in enumerate(steps):
        mine = np.nonzero((ft.ids == ref) & ft.confirmed)[0]
        if mine.size:
            out[k] = ft.boxes[mine[0]].copy()
    return out


def _holding(boxes: np.ndarray, centres: np.ndarray, start: tuple[float, float]) -> int | None:
    """Of ``boxes`` (n, 4) around ``centres`` (n, 2), the one that holds ``start`` with
    the nearest centre (the first of equals); None when none holds it."""
    if not len(boxes):
        return None
    x, y = start
    inside = (boxes[:, 0] <= x) & (x <= boxes[:, 2]) & (boxes[:, 1] <= y) & (y <= boxes[:, 3])
    if not inside.any():
        return None
    d2 = np.where(inside, (centres[:, 0] - x) ** 2 + (centres[:, 1] - y) ** 2, np.inf)
    return int(np.argmin(d2))


def _truth_reference(scene: Scene, n: int) -> list[np.ndarray | None]:
    """The boxes of the truth track holding the target's start at its frame, per step."""
    out: list[np.ndarray | None] = [None] * n
    tracks = [t.boxes() for t in scene.truth]
    k = scene.target.step
    at = [i for i, b in enumerate(tracks) if k in b]
    boxes = np.array([tracks[i][k] for i in at], dtype=float).reshape(-1, 4)
    centres = np.array([dict((s, (x, y)) for s, x, y in scene.truth[i].positions)[k] for i in at])
    j = _holding(boxes, centres.reshape(-1, 2), scene.target.start)
    if j is None:
        return out
    first = scene.frames[0].step
    for step, box in tracks[at[j]].items():
        if 0 <= step - first < n:
            out[step - first] = np.array(box, dtype=float)
    return out


def target_id(ids: list[int | None]) -> int:
    """The target's id: its track's id at the first step where it has one on the unattacked
    run (``ids``: :attr:`MultiStep.target_id` of each step of :meth:`ComposedDesign.run`);
    NONE when it never has one. The ``dist`` measures read the
    track of this id on every attacked path."""
    return next((i for i in ids if i is not None), NONE)


def target_of(ft: FrameTracks, box: np.ndarray) -> int:
    """The target's track id among ``ft``'s tracks, given the reference box (identity's
    rule: the confirmed track of largest IoU ≥ 0.5, the lower id of equals; NONE: none)."""
    return int(targets_of(ft.boxes[None], ft.ids[None], ft.confirmed[None], box)[0])


def targets_of(
    boxes: np.ndarray, ids: np.ndarray, confirmed: np.ndarray, box: np.ndarray
) -> np.ndarray:
    """:func:`target_of` for n sets of tracks at once, padded: boxes (n, T, 4), ids (n, T)
    (−1: padding), confirmed (n, T) (False on padding); the IoU of every box computed in one
    array (elementwise: the same values as one set at a time)."""
    n, T = ids.shape
    score = iou(boxes.reshape(-1, 4), box[None, :]).reshape(n, T)
    return np.array(
        [target_track(score[i], ids[i], confirmed[i]) for i in range(n)], dtype=np.int64
    )


#: What a state shows the ``dist`` measures: the box of the track with the target's id
#: (nan: no such track now) and whether that track was deleted (born, and gone since).
TargetLook = tuple[np.ndarray, bool]


def target_look(ft: FrameTracks, state: MultiState, me: int) -> TargetLook:
    """The track of id ``me`` after a frame whose tracks are ``ft`` (the state after it:
    ``state``): its box, and whether it was deleted."""
    mine = np.nonzero(ft.ids == me)[0]
    if mine.size:
        return as_box(ft.boxes[mine[0]]).copy(), False
    return np.full(4, np.nan), bool(me != NONE and me < state.next_id)


def as_box(v: np.ndarray) -> np.ndarray:
    """A box [x1, y1, x2, y2]; a point tracker's position (x, y) is the box of size 0 at
    it, so the ``dist`` measures read a point design's w and h as 0."""
    v = np.asarray(v, dtype=float)
    return np.concatenate([v, v]) if v.shape[-1] == 2 else v
