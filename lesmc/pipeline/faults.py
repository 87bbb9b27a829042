"""Component failures as part of the threat model (paper section 9.2, "Future Work").

A ``faults { ... }`` block (docs/language.md, "Faults") declares what may fail
inside the system: an entry of the Kalman filter's F, H, Q or R scaled or set
("missing or perturbed values in the matrices F, H, Q and R"), or a sensor
outage of k steps (no measurement reaches the tracker; a detector that answers
nothing for a frame is ``outage 1``), or a detector neuron stuck at a value ("a
neuron that does not function"). At most ``budget`` faults strike at once.

A stuck neuron changes what the detector sees, so its frames come from running the
faulty network over the video (``lesmc verify``, lesmc/experiment/neuron_faults.py):
the caller passes them as :data:`NeuronFrames`, and a variant takes, in each frame,
the detections and payoffs of the neuron faults active there (the detector reads
only the frames, never its own earlier answers, so this substitution is exact).

The adversary chooses, besides the attack, which faults strike and when each
becomes active (its activation step, within the attack window unless the fault
says ``from A..B``). Faults cost nothing, so the optimum of a property under a
combination of faults is the least optimum over every choice of activation
steps, each checked exactly on its own model: that is the constrained minimum
over the union of their paths (Eq. 6-7), so the verdict is exact. Each
combination is reported as a property of its own, ``NAME+FAULT`` (``NAME+A+B``
for a pair), with the worst activation in its notes: "resilient to every single
fault" is every ``NAME+F`` holding, "to every pair" every ``NAME+A+B``.

Deviations (Eq. 4) are measured against the fault-free system's unattacked
track: a fault that moves the track on its own has broken it (the reference a
variant model carries, lesmc.model.arrays.reference_states).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, replace

from lesmc.common.errors import Location, SpecError, source_line
from lesmc.engines.result import CheckResult, Stats, StopReason, Verdict
from lesmc.language.properties import Fault, FaultSet
from lesmc.language.semantics import BoundProperty
from lesmc.scene import Frame, Scene
from lesmc.scene.tracker_model import MAX_ENTRY, EntryFault

#: Most checks one property's fault variants may need (combinations × activation steps).
MAX_FAULT_CHECKS = 5000

#: The measurement space's coordinates: the rows of H, the rows and columns of R.
MEASUREMENT = ("x", "y")

#: Per set of neuron faults (by name), the frames of the video perceived with those
#: units stuck, by step.
NeuronFrames = Mapping[frozenset[str], Mapping[int, Frame]]


@dataclass(frozen=True)
class BoundFault:
    """A fault resolved against a scene's tracker: a matrix entry by indices, or an outage."""

    fault: Fault
    entry: tuple[int, int] | None = None

    @property
    def name(self) -> str:
        return self.fault.name


@dataclass(frozen=True)
class Strike:
    """One fault of a combination, active from model step ``step``."""

    fault: BoundFault
    step: int

    def text(self) -> str:
        f = self.fault.fault
        if f.kind == "outage":
            last = self.step + f.length - 1
            span = f"step {self.step}" if f.length == 1 else f"steps {self.step}..{last}"
            return f"{f.name} (no measurement at {span})"
        return f"{f.name} ({f.text()} from step {self.step})"


def fault_error(fs: FaultSet, f: Fault, message: str) -> SpecError:
    """``message`` located at the declaration of ``f``."""
    return SpecError(
        message, Location(fs.path, f.pos.line, f.pos.column, source_line(fs.text, f.pos.line))
    )


def bind_faults(fs: FaultSet, scene: Scene, neuron: NeuronFrames | None = None) -> list[BoundFault]:
    """Each fault of ``fs`` with its entry resolved against the scene's tracker; a located
    error for an unknown matrix entry, a value beyond ±MAX_ENTRY (a declared matrix's
    limit, so a failed entry stays finite), or a neuron fault without its frames."""
    state = scene.tracker.state_names
    out = []
    for f in fs.faults:
        if f.kind == "neuron" and (neuron is None or frozenset([f.name]) not in neuron):
            raise fault_error(
                fs,
                f,
                f"fault '{f.name}' makes a detector neuron fail: only `lesmc verify` perceiving "
                "a video (not --scene) runs the faulty network; a scene holds the detections "
                "of the fault-free one",
            )
        if f.kind in ("outage", "neuron"):
            out.append(BoundFault(f))
            continue
        if not abs(f.value) <= MAX_ENTRY:
            raise fault_error(
                fs, f, f"a fault's value must lie within ±{MAX_ENTRY:g}, got {f.value:g}"
            )
        rows = MEASUREMENT if f.matrix in ("H", "R") else state
        cols = MEASUREMENT if f.matrix == "R" else state
        entry = (_index(fs, f, f.row, rows, "row"), _index(fs, f, f.col, cols, "column"))
        out.append(BoundFault(f, entry))
    return out


def _index(fs: FaultSet, f: Fault, ref: int | str, names: tuple[str, ...], what: str) -> int:
    """A row or column of ``f.matrix``: a number below its size or one of ``names``."""
    size = len(names)
    if isinstance(ref, int):
        if ref >= size:
            raise fault_error(
                fs,
                f,
                f"{f.matrix} has {size} {what}s (0..{size - 1}): {what} {ref} is out of range",
            )
        return ref
    if ref not in names:
        raise fault_error(
            fs, f, f"{f.matrix} has no {what} '{ref}'; its {what}s are {', '.join(names)}"
        )
    return names.index(ref)


def validate(
    fs: FaultSet, scene: Scene, bound: list[BoundProperty], neuron: NeuronFrames | None = None
) -> None:
    """Every fault binds to the scene's tracker and every activation range fits every
    property: checked before any check runs, so a bad declaration costs no search."""
    bind_faults(fs, scene, neuron)
    for bp in bound:
        refuse_too_many(fs, bp)


def activation_steps(fs: FaultSet, f: Fault, bp: BoundProperty) -> range:
    """The steps at which ``f`` may become active for property ``bp``: its ``from A..B``
    (B may be ``end``), else the attack window; within the property's steps l..end."""
    if f.steps is None:
        return range(bp.l, bp.u + 1)
    lo, hi = f.steps[0], bp.end if f.steps[1] is None else f.steps[1]
    if not bp.l <= lo <= hi <= bp.end:
        raise fault_error(
            fs,
            f,
            f"activation steps {lo}..{hi} must lie within steps {bp.l}..{bp.end} of property "
            f"'{bp.name}' (before its attack window the system runs fault-free)",
        )
    return range(lo, hi + 1)


def count_checks(fs: FaultSet, bp: BoundProperty) -> int:
    """How many checks property ``bp`` needs under ``fs``: over every combination of
    1..budget faults, the product of their numbers of activation steps. Counted without
    listing the combinations (the elementary symmetric sums of those numbers, built one
    fault at a time); also checks every activation range (:func:`activation_steps`)."""
    sums = [1] + [0] * fs.budget  # sums[k]: the checks of every combination of k faults
    for f in fs.faults:
        n = len(activation_steps(fs, f, bp))
        for k in range(fs.budget, 0, -1):
            sums[k] += sums[k - 1] * n
    return sum(sums[1:])


def refuse_too_many(fs: FaultSet, bp: BoundProperty) -> None:
    """A located error, before any check runs, when ``bp`` needs more than
    :data:`MAX_FAULT_CHECKS` checks under ``fs``."""
    n = count_checks(fs, bp)
    if n > MAX_FAULT_CHECKS:
        raise SpecError(
            f"these {len(fs.faults)} faults with budget {fs.budget} need {n} checks of "
            f"property '{bp.name}', more than {MAX_FAULT_CHECKS}: lower the budget, "
            "remove faults or narrow their activation steps (from A..B)",
            Location(fs.path, fs.pos.line, fs.pos.column, source_line(fs.text, fs.pos.line)),
        )


def combinations(
    fs: FaultSet, faults: list[BoundFault], bp: BoundProperty
) -> Iterator[tuple[str, list[list[Strike]]]]:
    """Every combination of 1..budget faults, named ``NAME+A+B``, with every choice of their
    activation steps (refused first when they are too many: :func:`refuse_too_many`)."""
    refuse_too_many(fs, bp)
    steps = {f.name: activation_steps(fs, f.fault, bp) for f in faults}
    for size in range(1, min(fs.budget, len(faults)) + 1):
        for combo in itertools.combinations(faults, size):
            choices = [
                [Strike(f, s) for f, s in zip(combo, when, strict=True)]
                for when in itertools.product(*(steps[f.name] for f in combo))
            ]
            yield "+".join([bp.name, *(f.name for f in combo)]), choices


def variant_scene(scene: Scene, strikes: list[Strike], neuron: NeuronFrames | None = None) -> Scene:
    """The scene as the faulty system sees it: failed matrix entries from their frames on,
    each frame's detections as the networks with the units stuck by then perceive it
    (``neuron``), and no detections in the frames of an outage."""
    first = scene.target.step
    entries = tuple(
        EntryFault(
            s.fault.fault.matrix,
            *s.fault.entry,
            s.fault.fault.op,
            s.fault.fault.value,
            first + s.step,
        )
        for s in strikes
        if s.fault.entry is not None
    )
    dark: set[int] = set()
    for s in strikes:
        if s.fault.fault.kind == "outage":
            dark.update(range(first + s.step, first + s.step + s.fault.fault.length))
    stuck = perceived_by(scene, strikes)
    if stuck:
        assert neuron is not None, "bind_faults refuses neuron faults without their frames"
    frames = tuple(
        replace(fr, detections=())
        if fr.step in dark
        else replace(fr, detections=neuron[stuck[fr.step]][fr.step].detections)
        if neuron is not None and fr.step in stuck
        else fr
        for fr in scene.frames
    )
    return replace(
        scene,
        frames=frames,
        tracker=replace(scene.tracker, faults=scene.tracker.faults + entries),
    )


def perceived_by(scene: Scene, strikes: list[Strike]) -> dict[int, frozenset[str]]:
    """Per frame step, the neuron faults of ``strikes`` active there (model step 0 is the
    target's frame): whose run perceives that frame. Frames with none are left out."""
    first = scene.target.step
    neurons = [s for s in strikes if s.fault.fault.kind == "neuron"]
    out = {}
    for fr in scene.frames:
        active = frozenset(s.fault.name for s in neurons if first + s.step <= fr.step)
        if active:
            out[fr.step] = active
    return out


def worst(name: str, checks: list[tuple[list[Strike], CheckResult]]) -> CheckResult:
    """The property under one combination of faults: the least optimum over every choice of
    activation steps (the adversary's), with that choice's counterexample and witness.

    Bounds: the minimum of a set of numbers lies between the minimum of their lower
    bounds and the minimum of their upper bounds. Verdict: violated if some choice
    violates, holds if every choice holds (a vacuous one makes it vacuous), else unknown.
    """
    results = [r for _, r in checks]
    lower = min(r.lower for r in results)
    upper = min(r.upper for r in results)
    at = min(range(len(results)), key=lambda i: (results[i].upper, results[i].lower))
    strikes, chosen = checks[at]
    verdicts = [r.verdict for r in results]
    verdict: Verdict
    if "violated" in verdicts:
        verdict = "violated"
        at = min(
            (i for i, r in enumerate(results) if r.verdict == "violated"),
            key=lambda i: results[i].upper,
        )
        strikes, chosen = checks[at]
    elif all(v == "holds" for v in verdicts):
        verdict = "holds"
    else:
        verdict = "unknown"
    known = lower == upper and all(r.optimum_known for r in results)
    optimum = chosen.optimum if known or verdict == "violated" else None
    notes = [f"worst activation: {', '.join(s.text() for s in strikes)}", *chosen.notes]
    if len(results) > 1:
        notes.append(f"{len(results)} activations checked, the least optimum kept")
    return replace(
        chosen,
        property=name,
        verdict=verdict,
        optimum=optimum,
        optimum_known=known,  # a violation's cost alone is an upper bound of the least
        lower=lower,
        upper=upper,
        vacuous=verdict == "holds" and any(r.vacuous for r in results),
        notes=notes,
        stats=_summed([r.stats for r in results]),
    )


def _summed(stats: list[Stats]) -> Stats:
    """Every activation's search in one record: counts and seconds added."""
    first = stats[0]
    stopped: StopReason = next((s.stopped for s in stats if s.stopped != "finished"), "finished")
    return Stats(
        engine=first.engine,
        states_expanded=sum(s.states_expanded for s in stats),
        transitions=sum(s.transitions for s in stats),
        seconds=sum(s.seconds for s in stats),
        stopped=stopped,
        extra={"fault_activations": len(stats)},
    )


#: Check one property on one variant scene (the pipeline's model and payoff handling),
#: given which neuron faults perceive each of its frames (:func:`perceived_by`).
CheckVariant = Callable[[Scene, BoundProperty, Mapping[int, frozenset[str]]], CheckResult]


def check_faults(
    fs: FaultSet,
    scene: Scene,
    bp: BoundProperty,
    check: CheckVariant,
    neuron: NeuronFrames | None = None,
) -> list[tuple[BoundProperty, CheckResult]]:
    """``bp`` under every combination of the faults of ``fs``: one result per combination,
    named ``NAME+FAULT...`` (:func:`worst` of its activations). ``neuron``: the frames
    perceived under every set of neuron faults a combination can hold."""
    bound = bind_faults(fs, scene, neuron)
    out = []
    for name, choices in combinations(fs, bound, bp):
        checks = [
            (
                strikes,
                check(variant_scene(scene, strikes, neuron), bp, perceived_by(scene, strikes)),
            )
            for strikes in choices
        ]
        renamed = replace(bp, prop=replace(bp.prop, name=name))
        out.append((renamed, worst(name, checks)))
    return out
