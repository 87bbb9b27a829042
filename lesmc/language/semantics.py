"""Bind a property to a model: resolve ``end``, check ranges and component names.

The result, :class:`BoundProperty`, has only concrete step numbers and component
indices, which is what the engines need. Errors point into the spec file.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from lesmc.common.errors import Location, SpecError, source_line
from lesmc.language import actions, measures, monitors
from lesmc.language.properties import Measure, Pos, Property, SpecFile, StepRef

#: Names that ``monitor uncertainty`` takes as the location block (Eq. 12) by default.
LOCATION_COMPONENTS = ("x", "y")


@dataclass(frozen=True)
class BoundMeasure:
    """A measure with concrete steps: ``source``, one of a registered measure's sources
    (lesmc/language/measures/: payoff, count, frames, dist, near, tau, switches, lost),
    ``aggregate`` sum/max.

    ``dist.at(k)`` becomes a sum over k..k; ``payoff.mean`` a sum with
    ``weight`` 1/(u−l+1).
    """

    source: str
    aggregate: str
    lo: int
    hi: int
    weight: float
    text: str

    @property
    def declared(self) -> measures.DeclaredMeasure:
        """The measure it binds (lesmc/language/measures/), found by its source."""
        return measures.by_source(self.source)


@dataclass(frozen=True)
class BoundProperty:
    """A property ready for an engine, bound to a model whose original path ends at e."""

    prop: Property
    l: int
    u: int
    end: int
    objective: BoundMeasure
    constraint: BoundMeasure
    op: str
    bound: float
    norm: float
    components: tuple[int, ...]
    #: τ's components (Eq. 12) for the monitor (() for a monitor that reads no τ); None: the
    #: property has no monitor
    monitor_components: tuple[int, ...] | None
    monitor_parameter: float  #: the monitor kind's number (tau_rise: its tolerance)
    monitor_except_original: bool = False  # alarms at the original track's alarm steps excused
    spec: str = ""  #: the path of the spec file that states it
    #: components of τ (Eq. 12) for a ``tau.rise`` measure: the monitor's, else x, y
    tau_components: tuple[int, ...] | None = None
    #: for a ``dist.nearest`` measure: the model components of its ground-truth tracks,
    #: in the tracks' order (the property's ``on`` components)
    near_components: tuple[int, ...] | None = None
    #: the monitor's kind (lesmc/language/monitors.py) and its NIS window of steps
    monitor_kind: str = "tau_rise"
    monitor_window: int = 1
    #: ``attack window L..U within R``: the attack radius in px (multi-target designs)
    radius: float | None = None

    @property
    def monitor_tolerance(self) -> float:
        """The monitor's parameter under its ``tau_rise`` name (Eq. 13's tolerance)."""
        return self.monitor_parameter

    @property
    def uses_tau(self) -> bool:
        """A measure reads the uncertainty τ (``tau.rise``)."""
        return any(m.declared.needs_covariance for m in (self.objective, self.constraint))

    @property
    def name(self) -> str:
        return self.prop.name


def bind(
    spec: SpecFile,
    prop: Property,
    e: int,
    components: tuple[str, ...],
    has_covariance: bool,
    tracks: tuple[str, ...] | None = None,
    has_nis: bool = True,
    multi: bool = False,
    tracker: str | None = None,
    model_actions: tuple[str, ...] = actions.DEFAULT,
    model_grid: Mapping[str, Any] | None = None,
) -> BoundProperty:
    """Resolve ``prop`` against a model with steps 0..e and the given components;
    ``tracks``: the components of the model's ground-truth tracks (None: it has none);
    ``has_nis``: the model carries the NIS of its transitions' updates (a monitor that
    reads them is refused otherwise); ``multi``: a multi-target design's model (the only
    one with identity measures); ``tracker``: the tracker the model unfolds (``single``,
    ``joint``), for the actions it takes (lesmc/language/actions.py); None: a model
    already built, whose attacker took ``model_actions`` (its ``meta.actions``), which the
    property's must equal, and ``inject grid`` ``model_grid`` (its ``meta.inject_grid``)."""
    if not multi:
        _single_target(spec, prop)
        _single_target_actions(spec, prop, tracker, model_actions)
    _inject_grid(spec, prop, tracker, multi, model_grid)
    l, u, end = _window(spec, prop, e)
    monitor_idx, tol = _monitor(spec, prop, components, has_covariance, has_nis)
    tau_idx = _tau(spec, prop, components, has_covariance, monitor_idx)
    on = prop.clause_pos.get("on", prop.pos)
    comps = _indices(spec, prop.components, on, components)
    near_idx = _nearest(spec, prop, components, comps, tracks)
    if not math.isfinite(prop.threshold) or not math.isfinite(prop.constraint.threshold):
        raise _fail(spec, "thresholds must be finite", prop.pos)  # the parser refuses these
    return BoundProperty(
        prop=prop,
        l=l,
        u=u,
        end=end,
        objective=_measure(spec, prop.objective, l, u, end),
        constraint=_measure(spec, prop.constraint.measure, l, u, end),
        op=prop.constraint.op,
        bound=prop.constraint.threshold,
        norm=prop.norm,
        components=comps,
        monitor_components=monitor_idx,
        monitor_parameter=tol,
        monitor_except_original=prop.monitor is not None and prop.monitor.except_original,
        spec=spec.path,
        tau_components=tau_idx,
        near_components=near_idx,
        monitor_kind="tau_rise" if prop.monitor is None else prop.monitor.kind,
        monitor_window=1 if prop.monitor is None else prop.monitor.window,
        radius=prop.radius,
    )


def _single_target(spec: SpecFile, prop: Property) -> None:
    """A single-target design follows one track: it has no identities to switch or lose,
    and its attacker's options are ranked detections, not detections near a reference."""
    if prop.radius is not None:
        raise _fail(
            spec,
            "'attack window ... within R' limits a multi-target design's attack to the "
            "detections near the target: check the scene with --design sort (docs/trackers.md)",
            prop.clause_pos.get("window", prop.pos),
        )
    for m in (prop.objective, prop.constraint.measure):
        if m.declared.multi_only:
            raise _fail(
                spec,
                f"'{m.kind}' measures a multi-target design's identities: check the scene "
                "with --design sort (docs/trackers.md)",
                m.pos,
            )


def _single_target_actions(
    spec: SpecFile, prop: Property, tracker: str | None, model_actions: tuple[str, ...]
) -> None:
    """A single-target design's attacker takes only the actions registered for its tracker
    (lesmc/language/actions.py: inject on ``single``, not on ``joint``); a model already
    built has its attacker in its transitions: the property's actions must be the ones it
    was built for."""
    if tracker is None:
        if set(prop.actions) != set(model_actions):
            raise _fail(
                spec,
                f"the property's attacker takes {', '.join(prop.actions)} but the model was "
                f"built for one taking {', '.join(model_actions)} (its meta.actions): build "
                "the model from the scene with this property's actions, or check the scene",
                prop.clause_pos.get("allow", prop.pos),
            )
        return
    for name in prop.actions:
        action = actions.get(name)
        if action.taken_by(tracker):
            continue
        takers = "every design" if action.trackers is None else ", ".join(sorted(action.trackers))
        raise _fail(
            spec,
            f"attack action '{name}' is not supported for the {tracker} design: it is taken "
            f"by {takers} (check the scene with --design single or --design sort; issue 61)",
            prop.clause_pos.get("allow", prop.pos),
        )


#: The trackers that take ``inject grid`` (lesmc/tracking/single.py: its candidates lie
#: around the nearest-neighbour tracker's prediction).
GRID_TRACKERS = ("single",)


def _inject_grid(
    spec: SpecFile,
    prop: Property,
    tracker: str | None,
    multi: bool,
    model_grid: Mapping[str, Any] | None,
) -> None:
    """``inject grid D within R payoff P`` needs ``allow ..., inject`` and a tracker that
    takes it (the grid lies around the tracker's prediction; not a multi-target design);
    a model already built must have been built with the same grid (``model_grid``)."""
    at = prop.clause_pos.get("grid", prop.clause_pos.get("allow", prop.pos))
    if tracker is None and not multi:
        own = None if prop.grid is None else (prop.grid.offsets(), prop.grid.payoff)
        built = None
        if model_grid is not None:
            offs = [(float(x), float(y)) for x, y in model_grid["offsets"]]
            built = (offs, float(model_grid["payoff"]))
        if own != built:
            what = "no inject grid" if built is None else "another inject grid"
            raise _fail(
                spec,
                f"the model was built with {what} than the property's (its meta.inject_grid):"
                " build the model from the scene with this property, or check the scene",
                at,
            )
    if prop.grid is None:
        return
    if "inject" not in prop.actions:
        raise _fail(
            spec,
            "'inject grid' offers injection candidates: the attack window must allow "
            "inject ('attack window L..U allow hide, inject')",
            at,
        )
    if multi or (tracker is not None and tracker not in GRID_TRACKERS):
        what = "a multi-target design" if multi else f"the {tracker} design"
        raise _fail(
            spec,
            f"'inject grid' is not supported on {what}: it places candidates around the "
            f"tracker's prediction, on {', '.join(GRID_TRACKERS)} checked from a scene",
            at,
        )


def _fail(spec: SpecFile, message: str, pos: Pos) -> SpecError:
    """An error at ``pos`` of the spec file, with its line shown."""
    return SpecError(
        message, Location(spec.path, pos.line, pos.column, source_line(spec.text, pos.line))
    )


def _window(spec: SpecFile, prop: Property, e: int) -> tuple[int, int, int]:
    """The attack window l..u and the end: 1 <= l <= u <= end <= e (section 4)."""
    cpos = prop.clause_pos
    end = e if prop.end is None else prop.end
    if end > e:
        raise _fail(
            spec,
            f"end {end} is beyond the model's original path, which ends at step {e}",
            cpos["end"],
        )
    l, u_ref = prop.window
    u = end if u_ref is None else u_ref
    if l < 1:
        raise _fail(
            spec,
            "the attack window must start at step 1 or later (step 0 has no incoming "
            "transition to attack)",
            cpos["window"],
        )
    if not l <= u <= end:
        raise _fail(
            spec, f"attack window {l}..{u} must satisfy 1 <= l <= u <= end = {end}", cpos["window"]
        )
    return l, u, end


def _measure(spec: SpecFile, m: Measure, l: int, u: int, end: int) -> BoundMeasure:
    """A measure with its steps resolved: payoffs over the window, deviations over lo..hi
    (the measure's own binding: lesmc/language/measures/)."""
    declared = m.declared
    lo, hi = l, u
    if declared.ranged:
        lo, hi = _resolve(m.lo, end), _resolve(m.hi, end)
        if lo > hi:
            raise _fail(spec, f"empty step range {lo}..{hi}", m.pos)
        if hi > end:
            raise _fail(spec, f"step {hi} is beyond end = {end}", m.pos)
    try:
        b = declared.bind(m.aggregate, l, u, lo, hi)
    except measures.MeasureError as exc:
        raise _fail(spec, str(exc), m.pos) from None
    return BoundMeasure(b.source, b.aggregate, b.lo, b.hi, b.weight, m.text())


def _indices(
    spec: SpecFile, names: tuple[str, ...] | None, pos: Pos, components: tuple[str, ...]
) -> tuple[int, ...]:
    """The model's indices of the named components (all of them when none are named)."""
    if names is None:
        return tuple(range(len(components)))
    for n in names:
        if n not in components:
            raise _fail(
                spec, f"unknown component '{n}'; the model has {', '.join(components)}", pos
            )
    return tuple(components.index(n) for n in names)


def _monitor(
    spec: SpecFile,
    prop: Property,
    components: tuple[str, ...],
    has_covariance: bool,
    has_nis: bool,
) -> tuple[tuple[int, ...] | None, float]:
    """The monitor's components of τ (default: the location x, y; () for a monitor that
    reads no τ) and its parameter (lesmc/language/monitors.py)."""
    mon = prop.monitor
    if mon is None:
        return None, 0.0
    kind = monitors.get(mon.kind)
    reason = monitors.unchecked_reason(mon)
    if reason is not None:
        raise _fail(spec, reason, mon.pos)
    if kind.reads == "nis":
        if not has_nis:
            raise _fail(
                spec,
                f"the {mon.kind} monitor needs the NIS of every transition's update "
                "(transitions[].nis, docs/lts-format.md); the model has none",
                mon.pos,
            )
        return (), mon.parameter
    if not has_covariance:
        raise _fail(
            spec,
            f"'monitor {mon.kind}' needs the covariance P in every model state",
            mon.pos,
        )
    names = mon.components
    if names is None and all(c in components for c in LOCATION_COMPONENTS):
        names = LOCATION_COMPONENTS
    return _indices(spec, names, mon.pos, components), mon.parameter


def _tau(
    spec: SpecFile,
    prop: Property,
    components: tuple[str, ...],
    has_covariance: bool,
    monitor_idx: tuple[int, ...] | None,
) -> tuple[int, ...] | None:
    """The components of τ for a ``tau.rise`` measure: the monitor's when the property has
    one, else the location x, y (Eq. 12's Σ_ll), else every component."""
    tau_measures = [
        m for m in (prop.objective, prop.constraint.measure) if m.declared.needs_covariance
    ]
    if not tau_measures:
        return None
    if not has_covariance:
        raise _fail(
            spec, "'tau.rise' needs the covariance P in every model state", tau_measures[0].pos
        )
    if monitor_idx:
        return monitor_idx
    names = LOCATION_COMPONENTS if all(c in components for c in LOCATION_COMPONENTS) else None
    return _indices(spec, names, tau_measures[0].pos, components)


def _nearest(
    spec: SpecFile,
    prop: Property,
    components: tuple[str, ...],
    comps: tuple[int, ...],
    tracks: tuple[str, ...] | None,
) -> tuple[int, ...] | None:
    """For ``dist.nearest``: the model has ground-truth tracks, over exactly the components
    the property measures (its ``on``); their indices in the tracks' order."""
    near = [m for m in (prop.objective, prop.constraint.measure) if m.aggregate == "nearest"]
    if not near:
        return None
    if tracks is None:
        raise _fail(
            spec,
            "dist.nearest needs ground-truth tracks (a scene's 'truth', a model's 'tracks'); "
            "without them it is dist.at",
            near[0].pos,
        )
    names = {components[i] for i in comps}
    if names != set(tracks):
        raise _fail(
            spec,
            f"dist.nearest compares with the ground-truth tracks, which give "
            f"{', '.join(tracks)}: write 'on {', '.join(tracks)}'",
            near[0].pos,
        )
    return tuple(components.index(c) for c in tracks)


def _resolve(ref: StepRef, end: int) -> int:
    return end if ref is None else ref
