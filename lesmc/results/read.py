"""The results documents as typed, frozen objects: what the readers (the campaign summary,
the replay, the report) read, instead of string keys into the JSON.

The documents stay the file format (``results.json``, written by
lesmc/results/document.py; a campaign's ``results.jsonl`` rows, written by
lesmc/campaign/work.py). Their schemas (lesmc/schemas) have validated them
before they come here: the functions below only convert, and each key of a
document is spelled once, in this module or in the two it is split into: one
property's result (lesmc/results/result_doc.py) and a campaign's row
(lesmc/results/campaign_row.py).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lesmc.results.load import load_results
from lesmc.results.result_doc import Num, ResultDoc, number, read_result
from lesmc.scene import Target as SceneTarget

# ---------------------------------------------------------------- results.json


@dataclass(frozen=True)
class Perception:
    """The detector and attack settings a replay reruns (``perception``; None: not recorded)."""

    history: int | None
    delta_bc: int | None
    nets: str | None
    frames: str | None
    attack: Mapping[str, Any]


@dataclass(frozen=True)
class Judged:
    """One property's judgement of a listed path (``paths[].judged[]``)."""

    violates: bool
    admissible: bool
    alarms: tuple[int, ...]


@dataclass(frozen=True)
class PathDoc:
    """A listed path of the model (``runs[].paths[]``): its states, step labels, the detection
    taken entering each step after the first (None: no update), whether the track halted,
    its measures (as written) and each property's judgement."""

    no: int
    states: tuple[str, ...]
    labels: tuple[str, ...]
    obs: tuple[str | None, ...]
    halted: bool
    payoff: Num
    dist_sum: Num
    dist_max: Num
    dist_end: Num
    judged: tuple[Judged, ...]


@dataclass(frozen=True)
class StateDoc:
    """A state of the model (``runs[].states``): its step, estimate ``s``, covariance trace
    ``tau`` (as written; None: none) and position in the reference frame (None: not known)."""

    step: int
    s: tuple[float, ...]
    tau: Num | None
    ref: tuple[float, float] | None


@dataclass(frozen=True)
class HiddenDoc:
    """A detection a property's counterexamples hide (``runs[].hidden``): where (x, y: NaN
    when not recorded) and its payoff."""

    step: int
    frame: int
    obs: str
    x: float
    y: float
    payoff: float

    @property
    def placed(self) -> bool:
        """Whether the document gives its position."""
        return not (math.isnan(self.x) or math.isnan(self.y))


@dataclass(frozen=True)
class HiddenEntry:
    """A hidden detection as the report shows it: ``payoff`` and ``payoff_lower`` (its
    certified lower bound; None: not certified) as written."""

    hidden: HiddenDoc
    payoff: Num
    payoff_lower: Num | None


@dataclass(frozen=True)
class ReplayInputs:
    """What the tracker of a replay is made from (``runs[].replay_inputs``): the scene's
    tracker block (as scene/io reads it), its time step and the track's start."""

    tracker: Mapping[str, Any]
    dt: float
    target: SceneTarget
    #: the frames directory's index of scene frame f is f + frames_offset (``import mot
    #: --detector``: -1, MOT frames count from 1)
    frames_offset: int = 0


@dataclass(frozen=True)
class SceneDetection:
    """A detection near a listed track (``runs[].scene.detections``): its position, id,
    payoff (None: unpriced) and position in the reference frame."""

    x: float
    y: float
    id: str
    payoff: Num | None
    x_ref: float
    y_ref: float


@dataclass(frozen=True)
class SceneDoc:
    """What the report draws of the scene (``runs[].scene``): per step its detections, the
    reference step, and the target's ground truth in the reference frame (None: none)."""

    first_frame: int
    ref_step: int
    detections: tuple[tuple[SceneDetection, ...], ...]
    truth_ref: tuple[tuple[float, ...] | None, ...] | None


@dataclass(frozen=True)
class Monitor:
    """A property's monitor (``properties[].monitor``; documents before the monitor
    registry hold only Eq. 13's: kind ``tau_rise``, its tolerance the parameter)."""

    components: tuple[str, ...]
    tolerance: float
    except_original: bool
    kind: str = "tau_rise"
    parameter: float = 0.0
    window: int = 1

    def clause(self) -> str:
        """The monitor as its spec clause reads (docs/language.md)."""
        if self.kind == "tau_rise":
            return (
                f"monitor uncertainty on {', '.join(self.components)}, tolerance {self.parameter:g}"
            )
        more = f" window {self.window}" if self.window != 1 else ""
        return f"monitor {self.kind} {self.parameter:g}{more}"


@dataclass(frozen=True)
class PropertyDoc:
    """A bound property (``runs[].properties[]``): what the report reads of it."""

    name: str
    constraint_source: str
    constraint_aggregate: str
    constraint_range: tuple[int, ...]
    bound: float
    monitor: Monitor | None
    #: the attacker's actions (``allow hide, inject``); hide only when the document omits them
    actions: tuple[str, ...] = ("hide",)
    #: whether the property injects on an ``inject grid`` (a modelling device: not replayed)
    inject_grid: bool = False
    #: the constraint's comparison (None: not recorded), Eq. 4's norm, the state
    #: components the deviation reads and the attack window L..U (None: not recorded)
    constraint_op: str | None = None
    norm: float = 2.0
    components: tuple[str, ...] = ()
    window: tuple[int, ...] | None = None


@dataclass(frozen=True)
class ModelDoc:
    """The run's model (``runs[].model``)."""

    states: int
    transitions: int
    end: int
    first_frame: int
    components: tuple[str, ...]
    sha256: str


@dataclass(frozen=True)
class RunDoc:
    """One design run (``runs[]``). ``counterexamples`` and ``witnesses``: per property the
    path number of its role (None: none); ``hidden``: per property the detections its
    counterexample hides; ``faults``: the properties under component failures."""

    design: str
    label: str
    model: ModelDoc
    window: tuple[int, int]
    properties: tuple[PropertyDoc, ...]
    results: tuple[ResultDoc, ...]
    original: int | None
    counterexamples: tuple[int | None, ...]
    witnesses: tuple[int | None, ...]
    paths_total: int
    paths: tuple[PathDoc, ...]
    states: Mapping[str, StateDoc]
    hidden: Mapping[str, tuple[HiddenEntry, ...]]
    scene: SceneDoc | None
    replay_inputs: ReplayInputs | None
    faults: tuple[tuple[PropertyDoc, ResultDoc], ...]

    @property
    def first_frame(self) -> int:
        """The frame of step 0."""
        return self.model.first_frame

    def path(self, no: int) -> PathDoc:
        """The path numbered ``no`` (1-based, as the roles name them)."""
        return self.paths[no - 1]


@dataclass(frozen=True)
class FalseAlarmRow:
    """One monitor's false alarms on the unattacked tracks."""

    monitor: str
    tracks: int
    steps: int
    alarms: int
    tracks_alarmed: int


@dataclass(frozen=True)
class FalseAlarms:
    """The monitors on unattacked tracks (``monitor_false_alarms``)."""

    what: str
    rows: tuple[FalseAlarmRow, ...]


@dataclass(frozen=True)
class SearchResult:
    """One property of a searched design: its status and optimum (None: unknown)."""

    property: str
    status: str
    optimum: float | None
    threshold: float


@dataclass(frozen=True)
class SearchedDesign:
    """One design of a design search (``design_search.designs[]``)."""

    label: str
    results: tuple[SearchResult, ...]
    alarms: int
    steps: int
    tracking_error: float | None
    front: bool


@dataclass(frozen=True)
class DesignSearch:
    """``lesmc verify --space``'s design search (``design_search``): the front's designs
    and the best under the budget (``best``), or the closest to it (``closest``)."""

    what: str
    budget: float
    designs: tuple[SearchedDesign, ...]
    best: int | None
    closest: int | None


@dataclass(frozen=True)
class SpecText:
    """A spec file the properties came from (``provenance.specs[]``)."""

    path: str
    text: str


@dataclass(frozen=True)
class Provenance:
    """Who made the document, how and when (``provenance``)."""

    tool: str
    tool_version: str
    python: str | None
    command: tuple[str, ...]
    date: str
    seeds: Mapping[str, Any]
    specs: tuple[SpecText, ...]
    model_sha256: Mapping[str, str]


@dataclass(frozen=True)
class ResultsDoc:
    """A results document (``lesmc-results`` v2) as the readers read it."""

    format: str
    version: int
    provenance: Provenance
    meta: Mapping[str, str]
    timings: Mapping[str, float]
    perception: Perception
    runs: tuple[RunDoc, ...]
    monitor_false_alarms: FalseAlarms | None
    design_search: DesignSearch | None = None


def _path(p: Mapping[str, Any]) -> PathDoc:
    return PathDoc(
        no=p["no"],
        states=tuple(p["states"]),
        labels=tuple(p["labels"]),
        obs=tuple(p["obs"]),
        halted=bool(p["halted"]),
        payoff=p["payoff"],
        dist_sum=p["dist_sum"],
        dist_max=p["dist_max"],
        dist_end=p["dist_end"],
        judged=tuple(
            Judged(violates=j["violates"], admissible=j["admissible"], alarms=tuple(j["alarms"]))
            for j in p["judged"]
        ),
    )


def _state(v: Mapping[str, Any]) -> StateDoc:
    ref = v.get("ref")
    return StateDoc(
        step=v["step"],
        s=tuple(v["s"]),
        tau=v["tau"],
        ref=None if ref is None else (ref[0], ref[1]),
    )


def _hidden(h: Mapping[str, Any]) -> HiddenEntry:
    return HiddenEntry(
        hidden=HiddenDoc(
            step=int(h["step"]),
            frame=int(h["frame"]),
            obs=h["obs"],
            x=float(h.get("x", math.nan)),
            y=float(h.get("y", math.nan)),
            payoff=number(h["payoff"]),
        ),
        payoff=h["payoff"],
        payoff_lower=h.get("payoff_lower"),
    )


def _target(t: Mapping[str, Any]) -> SceneTarget:
    return SceneTarget(int(t["step"]), tuple(t["start"]), tuple(t["velocity"]))


def _scene(scene: Mapping[str, Any]) -> SceneDoc:
    truth = scene["truth_ref"]
    return SceneDoc(
        first_frame=int(scene["first_frame"]),
        ref_step=int(scene["ref_step"]),
        detections=tuple(
            tuple(
                SceneDetection(float(d[0]), float(d[1]), d[2], d[3], float(d[4]), float(d[5]))
                for d in step
            )
            for step in scene["detections"]
        ),
        truth_ref=None if truth is None else tuple(None if t is None else tuple(t) for t in truth),
    )


def _property(p: Mapping[str, Any]) -> PropertyDoc:
    mon = p["monitor"]
    return PropertyDoc(
        name=p["name"],
        constraint_source=p["constraint_source"],
        constraint_aggregate=p["constraint_aggregate"],
        constraint_range=tuple(p["constraint_range"]),
        bound=float(p["bound"]),
        actions=tuple(p.get("actions", ("hide",))),
        inject_grid=p.get("inject_grid") is not None,
        constraint_op=p.get("constraint_op"),
        norm=number(p.get("norm", 2.0)),
        components=tuple(p.get("components", ())),
        window=tuple(p["window"]) if "window" in p else None,
        monitor=None
        if mon is None
        else Monitor(
            components=tuple(mon["components"]),
            tolerance=float(mon["tolerance"]),
            except_original=bool(mon["except_original"]),
            kind=str(mon.get("kind", "tau_rise")),
            parameter=float(mon.get("parameter", mon["tolerance"])),
            window=int(mon.get("window", 1)),
        ),
    )


def _run(run: Mapping[str, Any]) -> RunDoc:
    scene = run["scene"]
    rp = run.get("replay_inputs")
    m = run["model"]
    roles = run["roles"]
    return RunDoc(
        design=run["design"],
        label=run["label"],
        model=ModelDoc(
            states=m["states"],
            transitions=m["transitions"],
            end=int(m["end"]),
            first_frame=int(m["first_frame"]),
            components=tuple(m["components"]),
            sha256=m["sha256"],
        ),
        window=(int(run["window"][0]), int(run["window"][1])),
        properties=tuple(_property(p) for p in run["properties"]),
        results=tuple(read_result(r) for r in run["results"]),
        original=roles["original"],
        counterexamples=tuple(roles["counterexample"]),
        witnesses=tuple(roles["witness"]),
        paths_total=run["paths_total"],
        paths=tuple(_path(p) for p in run["paths"]),
        states={q: _state(v) for q, v in run["states"].items()},
        hidden={p: tuple(_hidden(h) for h in hs) for p, hs in run["hidden"].items()},
        scene=None if scene is None else _scene(scene),
        replay_inputs=None
        if rp is None
        else ReplayInputs(
            tracker=rp["tracker"],
            dt=float(rp["dt"]),
            target=_target(rp["target"]),
            frames_offset=int(rp.get("frames_offset", 0)),
        ),
        faults=tuple(
            (_property(f["property"]), read_result(f["result"])) for f in run.get("faults", [])
        ),
    )


def _provenance(prov: Mapping[str, Any]) -> Provenance:
    return Provenance(
        tool=prov["tool"],
        tool_version=prov["tool_version"],
        python=prov.get("python"),
        command=tuple(prov["command"]),
        date=prov["date"],
        seeds=prov["seeds"],
        specs=tuple(SpecText(path=s["path"], text=s["text"]) for s in prov["specs"]),
        model_sha256=prov.get("model_sha256", {}),
    )


def _false_alarms(fa: Mapping[str, Any] | None) -> FalseAlarms | None:
    if not fa:
        return None
    return FalseAlarms(
        what=fa["what"],
        rows=tuple(
            FalseAlarmRow(
                monitor=r["monitor"],
                tracks=r["tracks"],
                steps=r["steps"],
                alarms=r["alarms"],
                tracks_alarmed=r["tracks_alarmed"],
            )
            for r in fa["rows"]
        ),
    )


def results_of(doc: Mapping[str, Any]) -> ResultsDoc:
    """The typed document of a validated results document (lesmc.results.load.load_results,
    or the one lesmc.results.document wrote in memory)."""
    p = doc.get("perception", {})
    return ResultsDoc(
        format=doc["format"],
        version=doc["version"],
        provenance=_provenance(doc["provenance"]),
        meta=doc["meta"],
        timings=doc["timings"],
        perception=Perception(
            history=p.get("history"),
            delta_bc=p.get("delta_bc"),
            nets=p.get("nets"),
            frames=p.get("frames"),
            attack=p.get("attack", {}),
        ),
        runs=tuple(_run(r) for r in doc["runs"]),
        monitor_false_alarms=_false_alarms(doc.get("monitor_false_alarms")),
        design_search=_design_search(doc.get("design_search")),
    )


def _design_search(ds: Mapping[str, Any] | None) -> DesignSearch | None:
    if not ds:
        return None
    return DesignSearch(
        what=ds["what"],
        budget=ds["budget"],
        designs=tuple(
            SearchedDesign(
                label=d["label"],
                results=tuple(
                    SearchResult(
                        property=r["property"],
                        status=r["status"],
                        optimum=None if r["optimum"] == "unknown" else number(r["optimum"]),
                        threshold=r["threshold"],
                    )
                    for r in d["results"]
                ),
                alarms=d["false_alarms"]["alarms"],
                steps=d["false_alarms"]["steps"],
                tracking_error=d["tracking_error"],
                front=d["front"],
            )
            for d in ds["designs"]
        ),
        best=ds["best"],
        closest=ds["closest"],
    )


def read_results(path: str | Path) -> ResultsDoc:
    """The results file at ``path``, validated (an InputError otherwise) and typed."""
    return results_of(load_results(path))
