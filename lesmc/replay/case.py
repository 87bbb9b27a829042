"""What a replay replays: the violated results' counterexamples of a results document
(docs/semantics.md, "Replay"), and what the replay records of one attacked frame."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from lesmc.common.errors import InputError, Location, UsageError
from lesmc.results.read import HiddenDoc as Hidden
from lesmc.results.read import ResultsDoc, RunDoc, SceneDoc
from lesmc.results.replay_measures import Judged, judged_measures
from lesmc.results.result_doc import number
from lesmc.scene import Detection, Frame, Scene, Target, tracker_from_dict

if TYPE_CHECKING:
    from lesmc.perception.detector import FrameDetections


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
    #: the tracker of the run's design (lesmc/designs: ``single``, ``joint``, ...)
    tracker_kind: str = "single"
    #: under inject on ``joint``: per step, the ids the cheapest way along the path hides
    #: and injects (lesmc/replay/joint_forcing.py; None: derived per step, ``single``)
    forced: dict[int, tuple[list[str], list[str]]] | None = None
    #: whether the attack of every step was derived (not: the path leaves the design on
    #: the scene, the replay diverges there and the path's cost is not compared)
    derived: bool = True
    #: the listed path of the counterexample (``runs[run].paths[path_no - 1]``)
    path_no: int = 0
    #: the detections the results record near the listed paths (``runs[run].scene``)
    recorded: SceneDoc | None = None
    #: the property as a diverged replay judges it on the replayed run, or why it cannot
    #: (lesmc/results/replay_measures.py; lesmc/replay/on_frames.py)
    judged: Judged | str = "the results record no property for it"
    #: the model's last step and its state components' names
    end: int = 0
    state_names: tuple[str, ...] = ()
    #: the constraint as the results spell it (``dist.sum(0..end) > 120``)
    constraint: str = ""
    #: under inject on ``single``: per step the path skips, the ids of the detections the
    #: results record hidden there (``runs[].hidden``: every gated detection, the skip the
    #: attack forces; :func:`forced_skip`)
    skips: dict[int, list[str]] = field(default_factory=dict)

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
    #: the windows the repair perturbed (each counted once, as in ``extra_cost``)
    extra_windows: int = 0
    injected: list[str] = field(default_factory=list)  # candidate ids injected
    not_injected: list[str] = field(default_factory=list)  # injected ids not detected after
    #: of those, the ids whose blob the perturbed frame no longer has (no candidate of its
    #: Q_bc within DET_TOL_PX): nothing there for the repair to perturb towards vehicle
    no_blob: list[str] = field(default_factory=list)
    cost: float = 0.0  # the recomputed cost of the frame's attack (allow hide, inject)


class Hides(Protocol):
    """A counterexample that hides detections (a :class:`Case`, a multi-target one)."""

    @property
    def hidden(self) -> Sequence[Hidden]:
        """The detections it hides, each with its step and frame."""
        ...


def hidden_by_frame(todo: Sequence[Hides]) -> dict[int, list[tuple[int, Hidden]]]:
    """Per frame, the detections the cases ``todo`` hide there: (case number, detection)."""
    out: dict[int, list[tuple[int, Hidden]]] = {}
    for ci, c in enumerate(todo):
        for h in c.hidden:
            out.setdefault(h.frame, []).append((ci, h))
    return out


def group_by_case(items: list[tuple[int, Hidden]]) -> list[tuple[int, list[Hidden]]]:
    """One frame's hidden detections (``hidden_by_frame``'s list) grouped by case: each
    case number, in order, with the detections it hides there."""
    out: dict[int, list[Hidden]] = {}
    for ci, h in items:
        out.setdefault(ci, []).append(h)
    return sorted(out.items())


def check_payoff(h: Hidden, rec: float, inputs: str) -> None:
    """An input error unless ``rec``, the recomputed payoff of hiding ``h``, is the one the
    results record (within :data:`PAYOFF_RTOL`; an infinite recorded payoff is not
    compared); ``inputs``: what else the replay reads (networks, a detector file)."""
    if math.isfinite(h.payoff) and not (
        math.isfinite(rec) and abs(rec - h.payoff) <= PAYOFF_RTOL * max(h.payoff, 1e-9)
    ):
        raise InputError(
            f"the attack on detection {h.obs} now costs {rec:g}, the results say "
            f"{h.payoff:g}: the frames, {inputs} or attack settings differ from the run "
            "that wrote the results",
            Location("--frames"),
        )


def perturbation_record(
    at: tuple[int, int, str],
    position: tuple[float, float],
    origin: Sequence[int],
    payoffs: tuple[float, float],
    flipped: bool,
    delta: list[Any],
    inject: bool = False,
) -> dict[str, Any]:
    """One perturbation as the replay records it (lesmc/schemas/replay.json,
    ``perturbation``): ``at`` its step, frame and detection (or candidate) id, the
    detection's ``position``, the ``origin`` of the window perturbed, the recorded and
    the recomputed payoff (``"inf"`` for infinity), whether it alone flips the network's
    decision, the perturbation and, for a candidate injected, ``"action": "inject"``."""
    step, frame, obs = at
    payoff, recomputed = payoffs
    out: dict[str, Any] = {
        "step": step,
        "frame": frame,
        "obs": obs,
        "x": float(position[0]),
        "y": float(position[1]),
        "window_origin": [int(v) for v in origin],
        "payoff": payoff if math.isfinite(payoff) else "inf",
        "payoff_recomputed": recomputed if math.isfinite(recomputed) else "inf",
        "flipped_alone": flipped,
    }
    if inject:
        out["action"] = "inject"
    out["delta"] = delta
    return out


def footage(
    dets: Mapping[int, FrameDetections], case: Case, attacked: Mapping[int, FrameDetections]
) -> Scene:
    """The scene of the frames' detections ``dets`` (the attacked frames' replaced by
    ``attacked``'s), with the case's tracker: what the production tracker runs on."""
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
    tracker is neither ``single`` (``monitor`` is single's) nor ``joint`` (``improved`` is
    joint's), or on an ``inject grid`` (points around the prediction, a modelling device,
    not places on the frames). It stays violated, not replayed."""
    p = next((p for p in run.properties if p.name == prop), None)
    if p is None or "inject" not in p.actions:
        return False
    return p.inject_grid or _tracker_kind(run) not in ("single", "joint")


def _tracker_kind(run: RunDoc) -> str:
    """The tracker of the run's design ("": a design this lesmc does not know)."""
    from lesmc.designs import registry

    return registry.get(run.design).tracker if run.design in registry.names() else ""


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
        tracker_kind=_tracker_kind(run),
        path_no=cex_no,
        recorded=run.scene,
        judged="the results record no property for it"
        if prop is None
        else judged_measures(prop, res.objective_source, res.objective, _tracker_kind(run)),
        end=run.model.end,
        state_names=run.model.components,
        constraint=res.constraint,
        skips=_skips(run, res.property, list(path.obs)) if "inject" in actions else {},
    )


def _skips(run: RunDoc, prop: str, obs: list[str | None]) -> dict[int, list[str]]:
    """Per step the path skips (``obs[step - 1]`` None), the ids of the detections the
    results record ``prop``'s counterexample hiding there."""
    out: dict[int, list[str]] = {}
    for e in run.hidden.get(prop, ()):
        k = e.hidden.step
        if 1 <= k <= len(obs) and obs[k - 1] is None:
            out.setdefault(k, []).append(e.hidden.obs)
    return out


def forced_skip(case: Case, step: int, frame: int) -> list[Hidden]:
    """The detections to hide at ``step`` of an ``allow hide, inject`` counterexample on
    ``single`` whose path skips there: those the results record hidden at the step (the
    cheapest way to force a skip hides every gated detection; none: the tracker skips
    unattacked). Their payoffs are recomputed by the replay (NaN here)."""
    nan = math.nan
    return [Hidden(step, frame, h, nan, nan, nan) for h in case.skips.get(step, [])]
