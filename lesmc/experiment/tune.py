"""``lesmc tune``: search a declared space of tracker and monitor settings for designs that
verifiably hold, at a measured false-alarm cost (docs/cli.md, "lesmc tune").

A design is a tracker (``single``, ``joint``) with parameter values (the gate, the noise
σ_q, σ_r or scalings of a declared model's Q, R) and a runtime monitor (a kind of
lesmc/language/monitors.py and its parameter) or none. Every parameter a space file may
name is declared once, in :data:`PARAMETERS` (its domain, which trackers have it, how it
changes a tracker's configuration); the space file's validation and the docs' table
(:func:`docs_table`) are made from it, and the monitors' domains from the monitor registry.

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
from lesmc.common.errors import InputError, Location, UsageError, clipped
from lesmc.common.fields import MAX_STEP
from lesmc.common.files import key_locations, read_text, read_toml
from lesmc.designs import registry
from lesmc.experiment.false_alarms import Series, TruthStart, truth_starts, unattacked_tracks
from lesmc.language import monitors
from lesmc.language.monitors import Domain
from lesmc.language.properties import Monitor, SpecFile
from lesmc.model.kernel import track_alarms
from lesmc.perception.quality import TruthFrame
from lesmc.pipeline.check import run
from lesmc.pipeline.job import Job
from lesmc.scene import Scene
from lesmc.scene.io import TRACKER_LIMITS
from lesmc.scene.scene import TrackerConfig
from lesmc.scene.tracker_model import DeclaredModel

FORMAT = "lesmc-tune"
VERSION = 1
#: ``--budget``: the false-alarm rate (alarms per step of the unattacked tracks) the best
#: design may cost, the issue's "1 % of steps".
DEFAULT_BUDGET = 0.01
#: The space file's key of the trackers, and of the monitor table (and its "no monitor").
DESIGN_KEY, MONITOR_KEY, NO_MONITOR = "design", "monitor", "none"
#: The space file's key of the false-alarm budget (``--budget`` overrides it).
BUDGET_KEY = "budget"


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


# ------------------------------------------------------------------ the parameters


@dataclass(frozen=True)
class Parameter:
    """One tracker parameter a space may vary: its domain, why a tracker lacks it (None:
    it has it) and how a value changes a tracker's configuration."""

    name: str
    summary: str
    domain: Domain
    has: str  #: which trackers have it, in words (the docs' table)
    lacks: Callable[[TrackerConfig, str], str | None]
    apply: Callable[[TrackerConfig, float], TrackerConfig]


def _preset_only(cfg: TrackerConfig, _tracker: str) -> str | None:
    if isinstance(cfg.model, str):
        return None
    return "the tracker's model is declared by its matrices (vary q_scale, r_scale)"


def _declared_only(cfg: TrackerConfig, _tracker: str) -> str | None:
    if not isinstance(cfg.model, str):
        return None
    return f"the tracker's model is the preset {cfg.model!r} (vary sigma_q, sigma_r)"


def _multi_only(_cfg: TrackerConfig, tracker: str) -> str | None:
    if registry.get(tracker).multi:
        return None
    multi = ", ".join(n for n in registry.tracker_names() if registry.get(n).multi)
    return f"design {tracker} is single-target; only a multi-target tracker ({multi}) has it"


def _every(_cfg: TrackerConfig, _tracker: str) -> str | None:
    return None


def _scaled(cfg: TrackerConfig, matrix: str, s: float) -> TrackerConfig:
    """``cfg`` with its declared model's ``matrix`` (Q or R) multiplied by ``s``."""
    assert isinstance(cfg.model, DeclaredModel)
    m = cfg.model
    rows = tuple(tuple(float(v) * s for v in row) for row in getattr(m, matrix))
    model = replace(m, Q=rows) if matrix == "Q" else replace(m, R=rows)
    return replace(cfg, model=model)


def _positive(name: str) -> Domain:
    return Domain(0.0, TRACKER_LIMITS[name], lo_open=True)


#: Every tracker parameter a space file may name, in the order designs are labelled.
PARAMETERS: dict[str, Parameter] = {
    p.name: p
    for p in (
        Parameter(
            "gate", "the gate g of Eq. 19 (Mahalanobis) or k (Euclidean)", _positive("gate"),
            "every tracker", _every, lambda c, v: replace(c, gate=v),
        ),
        Parameter(
            "sigma_q", "the process noise σ_q of Eq. 17", _positive("sigma_q"),
            "a preset model (cv2d, ca2d)", _preset_only, lambda c, v: replace(c, sigma_q=v),
        ),
        Parameter(
            "sigma_r", "the measurement noise σ_r of Eq. 18", _positive("sigma_r"),
            "a preset model (cv2d, ca2d)", _preset_only, lambda c, v: replace(c, sigma_r=v),
        ),
        Parameter(
            "q_scale", "a factor on every entry of the declared Q", Domain(0.0, 1e6, True),
            "a model declared by its matrices", _declared_only, lambda c, v: _scaled(c, "Q", v),
        ),
        Parameter(
            "r_scale", "a factor on every entry of the declared R", Domain(0.0, 1e6, True),
            "a model declared by its matrices", _declared_only, lambda c, v: _scaled(c, "R", v),
        ),
        Parameter(
            "min_hits", "updates in a row before a track is output", Domain(1, MAX_STEP,
            integer=True), "a multi-target tracker", _multi_only,
            lambda c, v: replace(c, min_hits=int(v)),
        ),
        Parameter(
            "max_age", "missed frames in a row before a track ends", Domain(0, MAX_STEP,
            integer=True), "a multi-target tracker", _multi_only,
            lambda c, v: replace(c, max_age=int(v)),
        ),
    )
}  # fmt: skip


def docs_table() -> str:
    """The table of a space file's keys (docs/cli.md, "lesmc tune"), from the registries."""
    rows = [
        "| key | what | values | applies to |",
        "|---|---|---|---|",
        f"| `{DESIGN_KEY}` | the trackers | a name or a list of "
        f"{', '.join(f'`{n}`' for n in single_trackers())} | — |",
    ]
    for p in PARAMETERS.values():
        rows.append(f"| `{p.name}` | {p.summary} | {p.domain.text()} | {p.has} |")
    rows.append(
        f"| `{BUDGET_KEY}` | the false-alarm budget of the best design (`--budget` overrides "
        f"it) | in [0, 1], default {DEFAULT_BUDGET:g} | — |"
    )
    rows.append(
        f"| `[{MONITOR_KEY}]` `{NO_MONITOR}` | also each tracker without a monitor | "
        "true or false | every tracker |"
    )
    for name in monitors.names():
        kind = monitors.get(name)
        values = kind.domain.text()
        if kind.memory(kind.domain.lo + 1, 1) > 0:  # the checker reads one transition
            values = f"{kind.domain.lo:g} (the checker reads one transition at a time)"
        rows.append(
            f"| `[{MONITOR_KEY}]` `{name}` | {kind.summary}: its {kind.parameter} | "
            f"{values} | every tracker |"
        )
    return "\n".join(rows)


#: Most designs a space may make (each is checked on every property), and so also most
#: values of one parameter or monitor.
MAX_DESIGNS = 10_000


def single_trackers() -> tuple[str, ...]:
    """The trackers a space may name: the registry's single-target ones."""
    return tuple(n for n in registry.tracker_names() if not registry.get(n).multi)


# ------------------------------------------------------------------ the space file


@dataclass(frozen=True)
class Space:
    """A space file read: the trackers, each tracker parameter's values (registry order),
    and the monitors (None: no monitor)."""

    path: str
    trackers: tuple[str, ...]
    values: tuple[tuple[str, tuple[float, ...]], ...]
    monitors: tuple[Monitor | None, ...]
    #: the false-alarm budget the file declares (None: :data:`DEFAULT_BUDGET`)
    budget: float | None = None

    @property
    def size(self) -> int:
        """The number of designs."""
        n = len(self.trackers) * len(self.monitors)
        for _, vs in self.values:
            n *= len(vs)
        return n


def read_space(path: str, base: TrackerConfig) -> Space:
    """The space file at ``path`` for a scene whose tracker is ``base``; every problem is an
    :class:`InputError` at its key (``FILE:LINE:COL``, exit 2)."""
    raw = read_toml(path)
    where = key_locations(path, read_text(path), False)

    def fail(key: str, message: str) -> InputError:
        return InputError(f"{clipped(key, 60)}: {message}", where.get(key, Location(path)))

    trackers = _trackers(raw.get(DESIGN_KEY, base.design), fail)
    values = []
    for key, v in raw.items():
        if key in (DESIGN_KEY, MONITOR_KEY, BUDGET_KEY):
            continue
        if key not in PARAMETERS:
            known = ", ".join([DESIGN_KEY, *PARAMETERS, MONITOR_KEY, BUDGET_KEY])
            raise fail(key, f"unknown parameter; a space declares {known} (docs/cli.md)")
        p = PARAMETERS[key]
        for t in trackers:
            why = p.lacks(base, t)
            if why is not None:
                raise fail(key, f"the design has no {key}: {why}")
        values.append((key, _values(v, p.domain, _at(fail, key))))
    order = list(PARAMETERS)
    values.sort(key=lambda kv: order.index(kv[0]))
    mons = _monitors(raw.get(MONITOR_KEY), fail)
    budget = raw.get(BUDGET_KEY)
    if budget is not None and not (_number(budget) and 0.0 <= budget <= 1.0):
        raise fail(BUDGET_KEY, "must be a false-alarm rate in [0, 1] (alarms per step)")
    space = Space(path, trackers, tuple(values), mons, budget)
    if space.size > MAX_DESIGNS:
        counts = [(len(vs), k) for k, vs in values] + [(len(mons), MONITOR_KEY)]
        raise fail(
            max(counts)[1],
            f"the space makes {space.size} designs (the trackers times every parameter's "
            f"values times the monitors), at most {MAX_DESIGNS}",
        )
    return space


def _at(fail: Callable[[str, str], InputError], key: str) -> Callable[[str], InputError]:
    """``fail`` at ``key``."""
    return lambda message: fail(key, message)


def _trackers(v: Any, fail: Callable[[str, str], InputError]) -> tuple[str, ...]:
    names = [v] if isinstance(v, str) else v
    ok = single_trackers()
    if not isinstance(names, list) or not names:
        raise fail(DESIGN_KEY, f"must be a tracker or a non-empty list of them: {', '.join(ok)}")
    for n in names:
        if n not in ok:
            raise fail(DESIGN_KEY, f"{n!r} is not a tracker tune can check; choose {', '.join(ok)}")
    return tuple(dict.fromkeys(names))


def _number(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool)


def _values(v: Any, domain: Domain, fail: Callable[[str], InputError]) -> tuple[float, ...]:
    """A parameter's values: a number, a list of numbers, or a range ``{from, to, count}``
    (``count`` values evenly spaced, both ends included; for whole numbers without
    ``count``, every one from ``from`` to ``to``)."""
    if _number(v):
        out = [float(v)]
    elif isinstance(v, list):
        if not all(_number(x) for x in v):
            raise fail("a list of values must hold numbers only")
        out = [float(x) for x in v]
    elif isinstance(v, dict):
        out = _range(v, domain, fail)
    else:
        raise fail("must be a number, a list of numbers or a range {from, to, count}")
    if not out:
        raise fail("empty range: no value to try")
    for x in out:
        if not domain.contains(x):
            raise fail(f"{x:g} is outside the domain: must be {domain.text()}")
    return tuple(dict.fromkeys(out))


def _range(v: dict[str, Any], domain: Domain, fail: Callable[[str], InputError]) -> list[float]:
    extra = sorted(set(v) - {"from", "to", "count"})
    if extra:
        raise fail(f"a range has the keys from, to, count; unknown {', '.join(extra)}")
    lo_raw: Any = v.get("from")
    hi_raw: Any = v.get("to")
    count = v.get("count")
    if not (_number(lo_raw) and _number(hi_raw)):
        raise fail("a range needs numbers from and to")
    lo, hi = float(lo_raw), float(hi_raw)
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise fail("a range needs finite numbers from and to")
    if lo > hi:
        raise fail(f"empty range: from {lo:g} is above to {hi:g}")
    if count is None:
        if not domain.integer:
            raise fail("a range of real values needs count (how many values, ends included)")
        if lo != int(lo) or hi != int(hi):
            raise fail("a range of whole numbers needs whole from and to")
        if hi - lo + 1 > MAX_DESIGNS:
            raise fail(f"the range has {hi - lo + 1:.0f} values, at most {MAX_DESIGNS}")
        return [float(x) for x in range(int(lo), int(hi) + 1)]
    if not (isinstance(count, int) and not isinstance(count, bool)) or count < 0:
        raise fail(f"count must be a whole number of values, got {count!r}")
    if count == 0:
        raise fail("empty range: count is 0")
    if count > MAX_DESIGNS:
        raise fail(f"count {count} is more values than a space may try (at most {MAX_DESIGNS})")
    if count == 1 and lo != hi:
        raise fail("count 1 needs from = to (the range's ends are both included)")
    return [float(x) for x in np.linspace(lo, hi, count)]


def _monitors(v: Any, fail: Callable[[str, str], InputError]) -> tuple[Monitor | None, ...]:
    """The ``[monitor]`` table: per kind, its parameter's values; ``none = true`` also
    the trackers without a monitor. No table: no monitor."""
    if v is None:
        return (None,)
    if not isinstance(v, dict):
        raise fail(MONITOR_KEY, "must be a table: [monitor] with KIND = values, none = true")
    out: list[Monitor | None] = []
    none = v.get(NO_MONITOR, False)
    if not isinstance(none, bool):
        raise fail(NO_MONITOR, "must be true or false (also each tracker without a monitor)")
    if none:
        out.append(None)
    for kind, vals in v.items():
        if kind == NO_MONITOR:
            continue
        if kind not in monitors.names():
            raise fail(kind, f"unknown monitor; the monitors are {', '.join(monitors.names())}")
        declared = monitors.get(kind)
        for x in _values(vals, declared.domain, _at(fail, kind)):
            mon = Monitor(parameter=x, kind=kind)
            reason = monitors.unchecked_reason(mon)
            if reason is not None:
                raise fail(kind, reason)
            out.append(mon)
    if not out:
        raise fail(MONITOR_KEY, "empty range: no monitor and none = false")
    return tuple(out)


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
    :func:`lesmc.scene.io.load_tracker` reads them), atomically."""
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
