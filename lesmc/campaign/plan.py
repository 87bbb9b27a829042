"""What a campaign checks: windows, designs, units of work, and the key of each unit.

A *unit* is one (video, target, window, design, property): one row of
``results.jsonl``. A *group* is every unit of one (video, target, tracker):
one unfolded model serves them all (the union of their windows is unfolded
once, lesmc/engines/lazy.py restricts each property to its own window), and
the joint KFs and joint KFs + monitor designs share the joint tracker's model.
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass
from typing import Any

from lesmc.common.errors import UsageError, clipped
from lesmc.common.fields import MAX_STEP
from lesmc.designs import registry
from lesmc.language import actions
from lesmc.language.properties import Property, SpecFile
from lesmc.pipeline.certify import PROBE_STOPPED
from lesmc.tracking.targets import TargetSpec

#: The paper's windows (section 8.2): l from 4 to 12, u − l from 1 to 4.
DEFAULT_WINDOWS = "4..12:1..4"
#: Windows a campaign may have: a campaign's units grow with them (the paper has 36).
MAX_WINDOWS = 10_000
#: Bumped when a unit's answer could change for the same inputs: old keys are then redone.
KEY_VERSION = 1


def parse_windows(text: str) -> list[tuple[int, int]]:
    """``L1..L2:D1..D2`` -> every (l, l + d) with l in L1..L2 and d in D1..D2, l-major:
    ASCII digits, windows ending by step :data:`MAX_STEP`, at most :data:`MAX_WINDOWS`."""
    r = r"\s*([0-9]{1,9})\s*\.\.\s*([0-9]{1,9})\s*"
    m = re.fullmatch(r + ":" + r, text, re.ASCII)
    shown = clipped(text)
    if not m:
        raise UsageError(
            f"--windows must look like L1..L2:D1..D2 (e.g. {DEFAULT_WINDOWS}), got '{shown}'"
        )
    l1, l2, d1, d2 = (int(g) for g in m.groups())
    if l1 < 1 or l1 > l2 or d1 > d2:
        raise UsageError(f"--windows {shown}: need 1 <= L1 <= L2 and D1 <= D2")
    if l2 + d2 > MAX_STEP:
        raise UsageError(f"--windows {shown}: windows must end by step {MAX_STEP}")
    if (l2 - l1 + 1) * (d2 - d1 + 1) > MAX_WINDOWS:
        raise UsageError(f"--windows {shown}: at most {MAX_WINDOWS} windows")
    return [(lo, lo + d) for lo in range(l1, l2 + 1) for d in range(d1, d2 + 1)]


def design_specs(specs: list[SpecFile], window: tuple[int, int], design: str) -> list[SpecFile]:
    """The properties a design is checked against in a window (with the monitor when the
    design has it: lesmc/designs/registry.py)."""
    out = [s.with_window(window) for s in specs]
    return [s.with_monitor() for s in out] if registry.get(design).monitor else out


def property_text(p: Property) -> str:
    """Everything that decides a property's answer, as one canonical line."""
    mon = "none"
    if p.monitor is not None:  # Eq. 13's monitor keeps the text (and keys) it always had
        m = p.monitor
        mon = f"{m.components}/{m.parameter!r}"
        if m.kind != "tau_rise" or m.window != 1:
            mon += f"/{m.kind}/window {m.window}"
        if m.except_original:
            mon += "/except original"
    return (
        f"{p.name}|window {p.window}|min {p.objective.text()}|s.t. {p.constraint.text()}|"
        f"{p.holds_text()}|end {p.end}|norm {p.norm!r}|on {p.components}|monitor {mon}"
        f"{_attacker_text(p)}"
    )


def _attacker_text(p: Property) -> str:
    """The attacker's clauses that are not the defaults (``within R``, ``allow ...``,
    ``inject grid D within R payoff P``), exactly; empty for the paper's attacker, so the
    keys of properties without them stay those of earlier versions."""
    out = "" if p.radius is None else f"|within {p.radius!r}"
    if p.actions != actions.DEFAULT:
        out += f"|allow {', '.join(sorted(p.actions))}"
    if p.grid is not None:
        g = p.grid
        out += f"|inject grid {g.spacing!r} within {g.radius!r} payoff {g.payoff!r}"
    return out


def unit_key(
    scene_key: str, target: TargetSpec, design: str, prop: Property, payoffs: str = "attack"
) -> str:
    """The hash of a unit's inputs: the scene, the target, the design, the property and the
    payoff mode (``attack`` adds nothing, so attack keys stay those of earlier versions)."""
    parts = [KEY_VERSION, scene_key, target.text(), design, property_text(prop)]
    if payoffs != "attack":
        parts.append(f"payoffs {payoffs}")
    text = json.dumps(parts, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:20]


@dataclass(frozen=True)
class Unit:
    """One row to compute: a window, a design, a property (by name), and its key."""

    key: str
    window: tuple[int, int]
    design: str
    prop: str


@dataclass(frozen=True)
class Group:
    """Every unit of one (video, target, tracker): one model serves them all."""

    video: str
    scene_key: str
    target: TargetSpec
    tracker: str  #: the registry's tracker every unit's design unfolds with
    units: tuple[Unit, ...]
    specs: tuple[tuple[str, str], ...]  # (path, text) of each spec file: workers read no files
    timeout: float | None
    max_states: int | None
    payoffs: str = "attack"  #: attack | certified | interval (docs/semantics.md)
    #: certified modes: per probed window (lesmc.campaign.run.widest), how many of the
    #: detections its model can hide carry no certified bound (normally none)
    unbounded: tuple[tuple[tuple[int, int], int], ...] = ()
    #: the scene file the units read (OUT/scenes/VIDEO.json): where its errors are located
    scene_file: str = ""

    def unbounded_in(self, window: tuple[int, int]) -> int:
        """``unbounded`` for a unit's ``window``: the least over the probed windows holding
        it whose probe finished (each prices a superset of the unit's detections); else
        :data:`PROBE_STOPPED` (a stopped probe, or none: nothing is known)."""
        counts = [n for (lo, hi), n in self.unbounded if lo <= window[0] and window[1] <= hi]
        known = [n for n in counts if n >= 0]
        return min(known) if known else PROBE_STOPPED

    @property
    def name(self) -> str:
        return f"{self.video} {self.target.text()} {self.tracker}"


def plan_units(
    scene_key: str,
    target: TargetSpec,
    specs: list[SpecFile],
    windows: list[tuple[int, int]],
    designs: tuple[str, ...],
    payoffs: str = "attack",
) -> dict[str, list[Unit]]:
    """Every unit of one target, by tracker."""
    out: dict[str, list[Unit]] = {}
    for d in designs:
        for w in windows:
            for spec in design_specs(specs, w, d):
                for p in spec.properties:
                    key = unit_key(scene_key, target, d, p, payoffs)
                    out.setdefault(registry.get(d).tracker, []).append(Unit(key, w, d, p.name))
    return out


def scene_key(doc: dict[str, Any], bounds: bool = False) -> str:
    """The hash of a scene's content (frames, dt, tracker; not its meta or target).

    Without ``bounds`` the detections' certified ``payoff_lower`` are left out: a
    campaign adds them to its scene as its units need them, and the units' keys
    stay the same (the bounds follow from the frames). With ``bounds``: the key of
    the document the workers parse (and cache), ``meta.certified`` included, which a
    certified scene without any bound needs (:meth:`lesmc.scene.Scene.priced`).
    """
    body: dict[str, Any] = {k: doc[k] for k in ("dt", "frames", "tracker") if k in doc}
    if bounds and isinstance(doc.get("meta"), dict) and "certified" in doc["meta"]:
        body["certified"] = doc["meta"]["certified"]
    if not bounds and isinstance(body.get("frames"), list):
        body["frames"] = [_without_lower(f) for f in body["frames"]]
    text = json.dumps(body, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def _without_lower(frame: Any) -> Any:
    """A scene document's frame without its detections' ``payoff_lower``."""
    if not (isinstance(frame, dict) and isinstance(frame.get("detections"), list)):
        return frame
    dets = [
        {k: v for k, v in d.items() if k != "payoff_lower"} if isinstance(d, dict) else d
        for d in frame["detections"]
    ]
    return frame | {"detections": dets}
