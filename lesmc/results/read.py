"""The results documents as typed, frozen objects: what the readers (the campaign summary,
the replay, the report) read, instead of string keys into the JSON.

The documents stay the file format (``results.json``, written by
lesmc/results/document.py; a campaign's ``results.jsonl`` rows, written by
lesmc/campaign/work.py). Their schemas (lesmc/schemas) have validated them
before they come here: the functions below only convert, and each key of a
document is spelled once, in this module.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lesmc.results.load import load_results
from lesmc.scene import Target as SceneTarget

#: A number as the documents write it: a JSON number, "inf"/"-inf", or "unknown" (optima).
Num = float | int | str


@dataclass(frozen=True)
class Target:
    """A campaign target: its position (pixels) at step ``step``."""

    step: int
    x: float
    y: float

    def to_dict(self) -> dict[str, Any]:
        """The target as the row writes it."""
        return {"step": self.step, "x": self.x, "y": self.y}


@dataclass(frozen=True)
class CampaignRow:
    """One line of a campaign's ``results.jsonl`` (lesmc/schemas/campaign-row.json): what the
    summary reads of it. ``optimum`` as written (a number, "inf" or "unknown");
    ``payoffs`` None for the attack's payoffs (the row omits it)."""

    key: str
    video: str
    target: Target
    window: tuple[int, int]
    design: str
    property: str
    verdict: str
    status: str
    vacuous: bool
    optimum: Num
    payoffs: str | None
    objective_source: str | None
    attacked_frames: int | None


def read_row(row: Mapping[str, Any]) -> CampaignRow:
    """The typed row of a (validated) ``results.jsonl`` object."""
    t = row["target"]
    w = row["window"]
    return CampaignRow(
        key=row["key"],
        video=row["video"],
        target=Target(step=t["step"], x=t["x"], y=t["y"]),
        window=(w[0], w[1]),
        design=row["design"],
        property=row["property"],
        verdict=row["verdict"],
        status=row["status"],
        vacuous=bool(row.get("vacuous", False)),
        optimum=row["optimum"],
        payoffs=row.get("payoffs"),
        objective_source=row.get("objective_source"),
        attacked_frames=row.get("attacked_frames"),
    )


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
class ReplayDoc:
    """A result's replay (``replay``): its status, and where and why it diverged."""

    status: str
    step: int | None
    reason: str | None


@dataclass(frozen=True)
class ResultDoc:
    """One property's result in a design run (``runs[].results[]``). ``optimum`` as written
    (a number, "inf" or "unknown"); ``payoffs`` the payoff mode."""

    property: str
    verdict: str
    status: str
    vacuous: bool
    optimum: Num
    threshold: float
    holds_op: str
    objective_source: str
    payoffs: str
    notes: tuple[str, ...]
    replay: ReplayDoc | None


@dataclass(frozen=True)
class PathDoc:
    """A path of the model (``runs[].paths[]``): its states, the detection taken entering each
    step after the first (None: no update) and whether the track halted."""

    no: int
    states: tuple[str, ...]
    obs: tuple[str | None, ...]
    halted: bool


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


@dataclass(frozen=True)
class ReplayInputs:
    """What the tracker of a replay is made from (``runs[].replay_inputs``): the scene's
    tracker block (as scene/io reads it), its time step and the track's start."""

    tracker: Mapping[str, Any]
    dt: float
    target: SceneTarget


@dataclass(frozen=True)
class SceneDetection:
    """A detection near a listed track (``runs[].scene.detections``): its position, id and
    payoff (None: unpriced)."""

    x: float
    y: float
    id: str
    payoff: float | None


@dataclass(frozen=True)
class RunDoc:
    """One design run (``runs[]``). ``states``: each state's estimate ``s``; ``detections``:
    per step, the scene's detections (None: checked on a model without its scene)."""

    design: str
    label: str
    first_frame: int
    results: tuple[ResultDoc, ...]
    counterexamples: tuple[int | None, ...]
    paths: tuple[PathDoc, ...]
    states: Mapping[str, tuple[float, ...]]
    hidden: Mapping[str, tuple[HiddenDoc, ...]]
    detections: tuple[tuple[SceneDetection, ...], ...] | None
    replay_inputs: ReplayInputs | None

    def path(self, no: int) -> PathDoc:
        """The path numbered ``no`` (1-based, as the roles name them)."""
        return self.paths[no - 1]


@dataclass(frozen=True)
class ResultsDoc:
    """A results document (``lesmc-results`` v2) as the readers read it."""

    perception: Perception
    runs: tuple[RunDoc, ...]


def number(x: Num) -> float:
    """A number as the documents write it: "inf" and "-inf" are infinite."""
    if x == "inf":
        return math.inf
    if x == "-inf":
        return -math.inf
    return float(x)


def read_replay(obj: Mapping[str, Any]) -> ReplayDoc:
    """The typed replay object of a result."""
    return ReplayDoc(status=obj["status"], step=obj.get("step"), reason=obj.get("reason"))


def _result(res: Mapping[str, Any]) -> ResultDoc:
    rp = res["replay"]
    return ResultDoc(
        property=res["property"],
        verdict=res["verdict"],
        status=res["status"],
        vacuous=res["vacuous"],
        optimum=res["optimum"],
        threshold=float(res["threshold"]),
        holds_op=res["holds_op"],
        objective_source=res["objective_source"],
        payoffs=res["payoffs"],
        notes=tuple(res["notes"]),
        replay=None if rp is None else read_replay(rp),
    )


def _path(p: Mapping[str, Any]) -> PathDoc:
    return PathDoc(
        no=p["no"], states=tuple(p["states"]), obs=tuple(p["obs"]), halted=bool(p["halted"])
    )


def _hidden(h: Mapping[str, Any]) -> HiddenDoc:
    return HiddenDoc(
        step=int(h["step"]),
        frame=int(h["frame"]),
        obs=h["obs"],
        x=float(h.get("x", math.nan)),
        y=float(h.get("y", math.nan)),
        payoff=number(h["payoff"]),
    )


def _target(t: Mapping[str, Any]) -> SceneTarget:
    return SceneTarget(int(t["step"]), tuple(t["start"]), tuple(t["velocity"]))


def _run(run: Mapping[str, Any]) -> RunDoc:
    scene = run["scene"]
    rp = run.get("replay_inputs")
    return RunDoc(
        design=run["design"],
        label=run["label"],
        first_frame=int(run["model"]["first_frame"]),
        results=tuple(_result(r) for r in run["results"]),
        counterexamples=tuple(run["roles"]["counterexample"]),
        paths=tuple(_path(p) for p in run["paths"]),
        states={q: tuple(v["s"]) for q, v in run["states"].items()},
        hidden={p: tuple(_hidden(h) for h in hs) for p, hs in run["hidden"].items()},
        detections=None
        if scene is None
        else tuple(
            tuple(SceneDetection(float(d[0]), float(d[1]), d[2], d[3]) for d in step)
            for step in scene["detections"]
        ),
        replay_inputs=None
        if rp is None
        else ReplayInputs(tracker=rp["tracker"], dt=float(rp["dt"]), target=_target(rp["target"])),
    )


def results_of(doc: Mapping[str, Any]) -> ResultsDoc:
    """The typed document of a validated results document (lesmc.results.load.load_results,
    or the one lesmc.results.document wrote in memory)."""
    p = doc.get("perception", {})
    return ResultsDoc(
        perception=Perception(
            history=p.get("history"),
            delta_bc=p.get("delta_bc"),
            nets=p.get("nets"),
            frames=p.get("frames"),
            attack=p.get("attack", {}),
        ),
        runs=tuple(_run(r) for r in doc["runs"]),
    )


def read_results(path: str | Path) -> ResultsDoc:
    """The results file at ``path``, validated (an InputError otherwise) and typed."""
    return results_of(load_results(path))
