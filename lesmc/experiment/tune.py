"""``lesmc tune``: search a declared space of tracker and monitor settings for designs that
verifiably hold, at a measured false-alarm cost (docs/cli.md, "lesmc tune").

A design is a tracker (``single``, ``joint``) with parameter values (the gate, the noise
σ_q, σ_r or scalings of a declared model's Q, R) and a runtime monitor (a kind of
lesmc/language/monitors.py and its parameter) or none. The space file, and every
parameter it may name (:data:`~lesmc.experiment.tune_space.PARAMETERS`), is
lesmc/experiment/tune_space.py's.

Each design is checked exactly through the one check pipeline (lesmc/pipeline/check.py),
as ``lesmc check --design D --tracker T`` would check it; its false alarms are counted on
the unattacked tracks started at every moving truth vehicle (lesmc/experiment/alarms.py,
the same tracks as ``lesmc alarms``), and its tracking error measured on them against the
truth. A monitor filters paths and never changes the model: the designs that differ only
in their monitor are one *group*, checked in one job whose one model (per tracker) serves
every monitor, and whose unattacked tracks are run once.
"""

from __future__ import annotations

import builtins
import itertools
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any, Protocol

import numpy as np

from lesmc.common.budget import Budget
from lesmc.common.errors import UsageError
from lesmc.designs import registry
from lesmc.experiment.false_alarms import Series, TruthStart, truth_starts, unattacked_tracks
from lesmc.experiment.tune_space import DEFAULT_BUDGET, PARAMETERS, Space, read_space
from lesmc.language.properties import Monitor, SpecFile
from lesmc.model.kernel import track_alarms
from lesmc.perception.quality import TruthFrame
from lesmc.pipeline.check import run
from lesmc.pipeline.job import Job
from lesmc.scene import Scene
from lesmc.scene.scene import TrackerConfig

FORMAT = "lesmc-tune"
VERSION = 1


class CheckResult(Protocol):
    """What a design search reads of a check's result (lesmc/engines/result.py's
    ``CheckResult``, which the experiment layer sees through the pipeline)."""

    @builtins.property
    def property(self) -> str: ...
    @builtins.property
    def verdict(self) -> str: ...
    @builtins.property
    def optimum(self) -> float | None: ...
    @builtins.property
    def optimum_known(self) -> bool: ...
    @builtins.property
    def vacuous(self) -> bool: ...
    @builtins.property
    def threshold(self) -> float: ...
    @builtins.property
    def status(self) -> str: ...
    def optimum_json(self) -> float | str: ...


# ------------------------------------------------------------------ designs and groups


@dataclass(frozen=True)
class Design:
    """One point of the space: a tracker, its parameters' values and a monitor (or none)."""

    tracker: str
    parameters: tuple[tuple[str, float], ...]
    monitor: Monitor | None

    def label(self) -> str:
        """``joint gate=2 sigma_q=3 + nis 0.99`` (``+ no monitor``)."""
        words = [self.tracker, *(f"{k}={v:g}" for k, v in self.parameters)]
        return " ".join(words) + " + " + (self.monitor.text() if self.monitor else "no monitor")

    def check_design(self) -> str:
        """The design ``lesmc check --design`` names for it: the tracker, or the registry's
        monitored design of the tracker (whose monitor is the tracker file's)."""
        if self.monitor is None:
            return self.tracker
        return monitored_design(self.tracker)

    def config(self, base: TrackerConfig) -> TrackerConfig:
        """``base`` with this design's tracker, parameters and monitor."""
        cfg = replace(base, design=self.tracker, monitor=None)
        for k, v in self.parameters:
            cfg = PARAMETERS[k].apply(cfg, v)
        if self.monitor is not None:
            cfg = replace(cfg, monitor=f"{self.monitor.kind} {self.monitor.parameter!r}")
        return cfg


def monitored_design(tracker: str) -> str:
    """The registry's design that is ``tracker`` with the runtime monitor."""
    for name in registry.names():
        d = registry.get(name)
        if d.monitor and d.tracker == tracker:
            return name
    raise UsageError(f"no design of the registry adds a monitor to the {tracker} tracker")


def designs(space: Space) -> list[Design]:
    """Every design of the space, the monitors innermost (a group's designs are adjacent)."""
    names = [k for k, _ in space.values]
    out: list[Design] = []
    for t in space.trackers:
        for combo in itertools.product(*(vs for _, vs in space.values)):
            params = tuple(zip(names, combo, strict=True))
            out.extend(Design(t, params, m) for m in space.monitors)
    return out


# ------------------------------------------------------------------ evaluation


@dataclass(frozen=True)
class Group:
    """The designs that share a tracker configuration (they differ in their monitor only),
    with what checking them needs; picklable, for a Dask worker."""

    scene: Scene
    specs: tuple[SpecFile, ...]
    designs: tuple[Design, ...]
    starts: tuple[TruthStart, ...]
    #: per start, its true position at each step after the start (None: no truth)
    truth: tuple[Mapping[int, tuple[float, float]], ...] | None
    steps: int
    engine: str | None  #: None: the pipeline's default
    payoffs: str
    max_states: int | None
    timeout: float | None
    source: str = "<scene>"


@dataclass(frozen=True)
class Outcome:
    """One design evaluated: its check results (the specs' properties, in order), its
    false alarms on the unattacked tracks and its tracking error there."""

    design: Design
    results: tuple[CheckResult, ...]
    steps: int
    alarms: int
    tracks: int
    tracks_with_alarm: int
    tracking_error: float | None
    front: bool = False

    @property
    def rate(self) -> float:
        """False alarms per step of the unattacked tracks."""
        return self.alarms / self.steps if self.steps else 0.0

    @property
    def holding(self) -> int:
        """How many properties hold, non-vacuously."""
        return sum(r.verdict == "holds" and not r.vacuous for r in self.results)


def groups(
    scene: Scene,
    specs: Sequence[SpecFile],
    space: Space,
    starts: Sequence[TruthStart],
    truth: Sequence[Mapping[int, tuple[float, float]]] | None,
    steps: int,
    engine: str | None,
    payoffs: str,
    max_states: int | None,
    timeout: float | None,
    source: str,
) -> list[Group]:
    """The space's designs in groups of one tracker configuration each."""
    out: list[Group] = []
    ds = designs(space)
    per = len(space.monitors)
    for i in range(0, len(ds), per):
        chunk = tuple(ds[i : i + per])
        sc = replace(scene, tracker=chunk[0].config(scene.tracker))
        out.append(
            Group(
                sc, tuple(specs), chunk, tuple(starts), None if truth is None else tuple(truth),
                steps, engine, payoffs, max_states, timeout, source,
            )
        )  # fmt: skip
    return out


#: What joins a property's name and its monitor's index in a group's one job.
_SEP = "~"


def evaluate(group: Group) -> list[Outcome]:
    """Check every design of ``group`` in one job (one model per tracker serves every
    monitor) and run its unattacked tracks once; one outcome per design, in order."""
    specs: list[SpecFile] = []
    for i, d in enumerate(group.designs):
        for s in group.specs:
            s = s.with_monitor(d.monitor) if d.monitor is not None else s
            props = tuple(replace(p, name=f"{p.name}{_SEP}{i}") for p in s.properties)
            specs.append(replace(s, properties=props))
    tracker = group.designs[0].tracker
    job = Job(
        tuple(specs),
        scene=group.scene,
        designs=(tracker,),
        payoffs=group.payoffs,
        budget=Budget(group.timeout, group.max_states),
        source=group.source,
    )
    if group.engine is not None:
        job = replace(job, engine=group.engine)
    results = run(job).results
    series = unattacked_tracks(group.scene, group.starts, tracker, group.steps)
    error = tracking_error(series, group.truth)
    out: list[Outcome] = []
    for i, d in enumerate(group.designs):
        mine = tuple(
            replace(r, property=r.property.rsplit(_SEP, 1)[0])
            for r in results
            if r.property.rsplit(_SEP, 1)[1] == str(i)
        )
        steps, alarms, alarmed = alarm_counts(series, d.monitor)
        out.append(Outcome(d, mine, steps, alarms, len(series), alarmed, error))
    return out


def alarm_counts(series: Sequence[Series], monitor: Monitor | None) -> tuple[int, int, int]:
    """Steps 1.. of the unattacked tracks, the alarms ``monitor`` raises at them (none
    without a monitor) and the tracks with at least one."""
    steps = alarms = alarmed = 0
    for s in series:
        n = len(s.tau) - 1
        steps += n
        if monitor is None or n < 1:
            continue
        fired = track_alarms(monitor.kind, monitor.parameter, monitor.window, s.tau, s.nis)
        hits = int(fired[1:].sum())
        alarms += hits
        alarmed += int(hits > 0)
    return steps, alarms, alarmed


def tracking_error(
    series: Sequence[Series], truth: Sequence[Mapping[int, tuple[float, float]]] | None
) -> float | None:
    """The mean distance (px) between each unattacked track's position and its vehicle's
    true one, over steps 1.. where both exist; None without truth (or no such step)."""
    if truth is None:
        return None
    dists = []
    for s, t in zip(series, truth, strict=True):
        for j in range(1, len(s.xy)):
            if j in t:
                dists.append(math.hypot(s.xy[j][0] - t[j][0], s.xy[j][1] - t[j][1]))
    return float(np.mean(dists)) if dists else None


def scene_truth(scene: Scene, starts: Iterable[TruthStart]) -> list[dict[int, tuple[float, float]]]:
    """Per start of :func:`lesmc.experiment.alarms.scene_starts` (``vid``: the index of its
    truth track), its true positions by step after the scene's target frame."""
    k0 = scene.target.step
    return [{k - k0: (x, y) for k, x, y in scene.truth[s.vid].positions} for s in starts]


# ------------------------------------------------------------------ the front and the best


def objectives(o: Outcome) -> tuple[float, ...]:
    """The design's objectives, each to maximise: every property's optimum (−∞ when it is
    unknown or the verdict vacuous: nothing is verified), minus the false-alarm rate and
    minus the tracking error (when known)."""
    vals = [
        -math.inf if r.optimum is None or r.vacuous or not r.optimum_known else r.optimum
        for r in o.results
    ]
    vals.append(-o.rate)
    if o.tracking_error is not None:
        vals.append(-o.tracking_error)
    return tuple(vals)


def pareto(outcomes: Sequence[Outcome]) -> list[Outcome]:
    """``outcomes`` with ``front`` set on those no other design dominates (at least as
    good in every objective of :func:`objectives`, better in one)."""
    objs = [objectives(o) for o in outcomes]

    def dominated(i: int) -> bool:
        a = objs[i]
        return any(
            all(x >= y for x, y in zip(b, a, strict=True)) and b != a
            for j, b in enumerate(objs)
            if j != i
        )

    return [replace(o, front=not dominated(i)) for i, o in enumerate(outcomes)]


def margin(r: CheckResult) -> float:
    """How far the optimum clears ``holds if``: optimum / threshold (a threshold > 0), else
    optimum − threshold; −∞ when nothing is verified (unknown, vacuous)."""
    if r.optimum is None or r.vacuous or not r.optimum_known:
        return -math.inf
    return r.optimum / r.threshold if r.threshold > 0 else r.optimum - r.threshold


def best(outcomes: Sequence[Outcome], budget: float) -> Outcome | None:
    """The best design whose false-alarm rate is at most ``budget``: the most properties
    holding non-vacuously, then the widest weakest margin (:func:`margin`), then the fewest
    false alarms, then the smallest tracking error, then the first in the space."""
    within = [(i, o) for i, o in enumerate(outcomes) if o.rate <= budget]
    if not within:
        return None

    def key(io: tuple[int, Outcome]) -> tuple[float, ...]:
        i, o = io
        weakest = min((margin(r) for r in o.results), default=-math.inf)
        err = o.tracking_error if o.tracking_error is not None else 0.0
        return (-o.holding, -weakest, o.rate, err, i)

    return min(within, key=key)[1]


# ------------------------------------------------------------------ the document


def document(
    outcomes: Sequence[Outcome],
    chosen: Outcome | None,
    budget: float,
    source: str,
    space: Space,
    specs: Sequence[str],
) -> dict[str, Any]:
    """The ``lesmc-tune`` document (lesmc/schemas/tune.json)."""
    rows = []
    for i, o in enumerate(outcomes):
        d = o.design
        rows.append(
            {
                "id": i,
                "label": d.label(),
                "tracker": d.tracker,
                "check_design": d.check_design(),
                "parameters": {k: v for k, v in d.parameters},
                "monitor": None
                if d.monitor is None
                else {"kind": d.monitor.kind, "parameter": d.monitor.parameter},
                "results": [
                    {
                        "property": r.property,
                        "status": r.status,
                        "verdict": r.verdict,
                        "vacuous": r.vacuous,
                        "optimum": r.optimum_json(),
                        "threshold": r.threshold,
                    }
                    for r in o.results
                ],
                "false_alarms": {
                    "steps": o.steps,
                    "alarms": o.alarms,
                    "rate": o.rate,
                    "tracks": o.tracks,
                    "tracks_with_alarm": o.tracks_with_alarm,
                },
                "tracking_error": o.tracking_error,
                "front": o.front,
            }
        )
    best_id = None if chosen is None else next(i for i, o in enumerate(outcomes) if o is chosen)
    return {
        "format": FORMAT,
        "version": VERSION,
        "source": source,
        "specs": list(specs),
        "space": space.path,
        "budget": budget,
        "designs": rows,
        "front": [i for i, o in enumerate(outcomes) if o.front],
        "best": best_id,
    }


@dataclass
class Tuned:
    """A search's answer: every design's outcome (front marked) and the best under budget."""

    outcomes: list[Outcome]
    best: Outcome | None
    budget: float
    groups: int = 0


def tune(
    all_groups: Sequence[Group],
    budget: float,
    mapper: Callable[[Callable[[Group], list[Outcome]], Sequence[Group]], Iterable[list[Outcome]]]
    | None = None,
    on_group: Callable[[int, Group], None] | None = None,
) -> Tuned:
    """Evaluate every group (``mapper``: how, e.g. on Dask; default here, one by one, and
    ``on_group`` told of each before it starts), mark the Pareto front and choose the best
    design under ``budget``."""
    if mapper is None:
        mapped = []
        for i, g in enumerate(all_groups):
            if on_group is not None:
                on_group(i, g)
            mapped.append(evaluate(g))
    else:
        mapped = list(mapper(evaluate, all_groups))
    outcomes = pareto([o for outs in mapped for o in outs])
    return Tuned(outcomes, best(outcomes, budget), budget, len(all_groups))


def tracker_file_text(cfg: TrackerConfig, comment: str) -> str:
    """``cfg`` as a TOML tracker file (``lesmc check --tracker`` reads it back)."""
    data = cfg.to_json()
    lines = [f"# {line}" for line in comment.splitlines()]
    tables = {k: v for k, v in data.items() if isinstance(v, dict)}
    for k, v in data.items():
        if k not in tables:
            lines.append(f"{k} = {_toml(v)}")
    for k, v in tables.items():
        lines.append(f"\n[{k}]")
        lines.extend(f"{kk} = {_toml(vv)}" for kk, vv in v.items())
    return "\n".join(lines) + "\n"


def _toml(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else ("inf" if v > 0 else "-inf")
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml(x) for x in v) + "]"
    raise TypeError(f"no TOML form for {v!r}")


def write_tracker(path: str, cfg: TrackerConfig, comment: str) -> None:
    """Write ``cfg`` as a tracker file: JSON for a ``.json`` name, TOML otherwise (as
    :func:`lesmc.scene.tracker_file.load_tracker` reads them), atomically."""
    from lesmc.common.files import atomic_write_text, write_json

    if path.endswith(".json"):
        write_json(path, {"comment": comment, **cfg.to_json()})
    else:
        atomic_write_text(path, tracker_file_text(cfg, comment))


def video_truth_tracks(
    frames: Sequence[TruthFrame], starts: Iterable[TruthStart]
) -> list[dict[int, tuple[float, float]]]:
    """Per start of a video (``vid``: its vehicle's id), its true positions by step after
    the target's frame (``frames[0]``)."""
    out = []
    for s in starts:
        at: dict[int, tuple[float, float]] = {}
        for j, tf in enumerate(frames):
            if s.vid in tf.ids:
                x, y = tf.positions[tf.ids.index(s.vid)]
                at[j] = (float(x), float(y))
        out.append(at)
    return out


#: What ``lesmc verify --space`` writes of a search into results.json, and the report says.
SEARCH_WHAT = (
    "lesmc tune's search (docs/cli.md) over the space file {space}: {n} designs, each "
    "checked on the properties above for this target, its monitor run on the unattacked "
    "tracks started at the {tracks} moving, visible truth vehicles ({steps} steps in all), "
    "its tracking error measured there. Listed: the Pareto front and the best design whose "
    "false-alarm rate is at most {budget:.1%} (the most properties holding non-vacuously, "
    "then the widest weakest margin); their violations are the model's, not replayed."
)


def design_search(
    scene: Scene,
    specs: Sequence[SpecFile],
    frames: Sequence[TruthFrame],
    size: tuple[int, int],
    space_path: str,
    source: str,
    max_states: int | None,
    on_group: Callable[[int, Group], None] | None = None,
) -> dict[str, Any]:
    """``lesmc verify --space``: the search on a video's scene (its truth ``frames`` from the
    target's on), for results.json (``design_search``, lesmc/schemas/results.json): the
    front's and the best design's rows of the ``lesmc-tune`` document; ``best`` their
    index there, or, when no design is within the budget, ``closest`` (the fewest false
    alarms)."""
    starts = truth_starts(frames[0], size)
    space = read_space(space_path, scene.tracker)
    budget = DEFAULT_BUDGET if space.budget is None else space.budget
    truth = video_truth_tracks(frames, starts)
    gs = groups(
        scene, specs, space, starts, truth, len(frames) - 1, None, "attack", max_states, None,
        source,
    )  # fmt: skip
    tuned = tune(gs, budget, on_group=on_group)
    doc = document(tuned.outcomes, tuned.best, budget, "", space, [s.path for s in specs])
    closest = min(range(len(tuned.outcomes)), key=lambda i: tuned.outcomes[i].rate)
    chosen = {closest} if doc["best"] is None else {doc["best"]}
    keep = sorted(set(doc["front"]) | chosen)
    steps = tuned.outcomes[0].steps if tuned.outcomes else 0
    return {
        "what": SEARCH_WHAT.format(
            space=space_path, n=len(tuned.outcomes), tracks=len(starts), steps=steps,
            budget=budget,
        ),
        "budget": budget,
        "designs": [doc["designs"][i] for i in keep],
        "best": None if doc["best"] is None else keep.index(doc["best"]),
        "closest": None if doc["best"] is not None else keep.index(closest),
    }  # fmt: skip
