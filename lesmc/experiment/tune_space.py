"""The space file of ``lesmc tune`` (docs/cli.md, "lesmc tune"): which tracker parameters a
design search may vary, and the reader of the file that declares their values.

Every parameter a space file may name is declared once, in :data:`PARAMETERS` (its domain,
which trackers have it, how it changes a tracker's configuration); the space file's
validation (:func:`read_space`) and the docs' table (:func:`docs_table`) are made from it,
and the monitors' domains from the monitor registry (lesmc/language/monitors.py).

The reader stops at the first problem: one :class:`InputError` at its key
(``FILE:LINE:COL``, with the source line and a caret), made by ``read_space``'s ``fail``.
It is not lesmc/common/files.py's ``error_at_keys``: that one lists every problem of a file,
one line each without the caret (a preformatted error), for the readers that collect all
their problems first; routing one error through it would drop the caret line.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from lesmc.common.errors import InputError, Location, clipped
from lesmc.common.fields import MAX_STEP
from lesmc.common.files import read_text, read_toml
from lesmc.common.locations import key_locations
from lesmc.designs import registry
from lesmc.language import monitors
from lesmc.language.monitors import Domain
from lesmc.language.properties import Monitor
from lesmc.scene.scene import TrackerConfig
from lesmc.scene.tracker_file import TRACKER_LIMITS
from lesmc.scene.tracker_model import DeclaredModel

#: ``--budget``: the false-alarm rate (alarms per step of the unattacked tracks) the best
#: design may cost, the issue's "1 % of steps".
DEFAULT_BUDGET = 0.01
#: The space file's key of the trackers, and of the monitor table (and its "no monitor").
DESIGN_KEY, MONITOR_KEY, NO_MONITOR = "design", "monitor", "none"
#: The space file's key of the false-alarm budget (``--budget`` overrides it).
BUDGET_KEY = "budget"


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
