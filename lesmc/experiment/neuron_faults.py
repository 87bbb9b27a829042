"""Neuron faults in ``lesmc verify``: the video perceived with detector units stuck.

A fault ``neuron detector[L, U] = c`` (docs/language.md, "Faults") changes what
the detector sees from its activation frame on. For every set of neuron faults a
combination may hold (1..budget of them), the networks with those units stuck
(lesmc/perception/neurons.py) run over the whole video as the fault-free ones did:
detections, then DeepFool payoffs on the faulty N_dr. The checker takes each
frame's detections from the set active there (lesmc/pipeline/faults.py). In a
certified payoff mode, each run also certifies, on its faulty N_dr, the detections
a fault variant's model can hide (as the fault-free run does for the nominal
models). Each perception is kept under OUT/cache, keyed by the fault-free
perception's inputs and the stuck units (a certified mode perceives again: it
needs the windows, which the cache does not keep).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from lesmc.common.errors import InputError, Location
from lesmc.common.progress import Reporter
from lesmc.experiment import video_perception
from lesmc.experiment.cache import StageCache, digest
from lesmc.experiment.video_perception import UnitMax
from lesmc.language.properties import Fault, FaultSet
from lesmc.pipeline.faults import fault_error
from lesmc.pipeline.job import Certifier
from lesmc.scene import Footage, Frame

if TYPE_CHECKING:
    from lesmc.perception.cnn import Nets
    from lesmc.perception.neurons import StuckUnit
    from lesmc.video.reader import FrameSet


def neuron_faults(fs: FaultSet | None) -> list[Fault]:
    """The neuron faults of ``fs`` (none without a faults block)."""
    return [] if fs is None else [f for f in fs.faults if f.kind == "neuron"]


def check_units(fs: FaultSet, nets: Nets) -> None:
    """Every neuron fault names an existing unit of a network lesmc can open up: a located
    error (exit 2) otherwise, before any perception runs."""
    from lesmc.perception.neurons import layer_sizes, network

    for f in neuron_faults(fs):
        assert isinstance(f.row, int) and isinstance(f.col, int)
        sizes = layer_sizes(network(nets, f.net))  # type: ignore[arg-type]
        if not sizes:
            raise fault_error(
                fs,
                f,
                f"the {f.net} was loaded from a graph file (--{f.net}): a neuron fault names a "
                "hidden layer of lesmc's own networks (--nets)",
            )
        if f.row >= len(sizes):
            raise fault_error(
                fs,
                f,
                f"the {f.net} has {len(sizes)} hidden layers (0..{len(sizes) - 1}): layer "
                f"{f.row} is out of range",
            )
        if f.col >= sizes[f.row]:
            raise fault_error(
                fs,
                f,
                f"layer {f.row} of the {f.net} has {sizes[f.row]} units (0..{sizes[f.row] - 1}): "
                f"unit {f.col} is out of range",
            )


def stuck_unit(f: Fault, unit_max: UnitMax) -> StuckUnit:
    """The unit ``f`` makes fail and the value it outputs: its own, or for ``= max`` the
    largest value the unit reached on the video's windows (0 if it never was scored)."""
    from lesmc.perception.neurons import StuckUnit

    assert isinstance(f.row, int) and isinstance(f.col, int)
    value = float(unit_max[f.net][f.row][f.col]) if f.at_max else f.value
    return StuckUnit(f.net, f.row, f.col, max(value, 0.0))  # type: ignore[arg-type]


def _check_maxima(unit_max: UnitMax, nets: Nets, entry: Path) -> None:
    """The fault-free perception's unit maxima (read from ``entry`` on a rerun) have one
    value per unit of each hidden layer; an entry changed by hand is a located error."""
    from lesmc.perception.neurons import layer_sizes, network

    for name in ("detector", "locator"):
        sizes = layer_sizes(network(nets, name))
        got = [len(m) for m in unit_max.get(name, [])]
        if sizes and got != sizes:
            raise InputError(
                f"unit_max.{name}: {got} values per layer where the networks have {sizes} "
                "units; delete this entry to perceive the video again",
                Location(str(entry)),
            )


def fault_sets(fs: FaultSet) -> list[tuple[Fault, ...]]:
    """Every set of 1..budget neuron faults: the networks a combination's frames need."""
    faults = neuron_faults(fs)
    return [
        combo
        for size in range(1, min(fs.budget, len(faults)) + 1)
        for combo in itertools.combinations(faults, size)
    ]


@dataclass
class NeuronRuns:
    """The video under every set of neuron faults: its frames, and in a certified payoff
    mode each run's certifier."""

    frames: dict[frozenset[str], dict[int, Frame]] = field(default_factory=dict)
    certify: dict[frozenset[str], Certifier] = field(default_factory=dict)


def neuron_frames(
    fs: FaultSet,
    frames: FrameSet,
    nets: Callable[[], Nets],
    seen: tuple[str, UnitMax, float],
    cache: StageCache,
    rep: Reporter,
    spent: Callable[[str], None],
    certified: bool = False,
) -> NeuronRuns:
    """Per set of neuron faults, the video's frames (by step) as the networks with those
    units stuck perceive it, and with ``certified`` a certifier of those frames'
    detections on the faulty N_dr. ``seen``: the fault-free perception's cache key, unit
    maxima and seconds between frames; ``nets()`` loads the fault-free networks;
    ``spent(stage)`` stops the run once the budget is spent."""
    key, unit_max, dt = seen
    _check_maxima(unit_max, nets(), cache.path("perception", key))
    out = NeuronRuns()
    todo = []
    for combo in fault_sets(fs):
        units = [stuck_unit(f, unit_max) for f in combo]
        combo_key = digest({"perception": key, "stuck": [asdict(u) for u in units]})
        hit = None if certified else video_perception.read(cache, "neuron-fault", combo_key)
        if hit is not None:
            rep.log(f"reusing the perception with {_names(combo)} from {cache.dir}")
            out.frames[frozenset(f.name for f in combo)] = _by_step(hit[0])
        else:
            todo.append((combo, units, combo_key))
    # every faulty network over one front end; in a certified mode a few at a time, as
    # each run then keeps its N_dr windows
    group = 2 if certified else len(todo)
    for at in range(0, len(todo), max(group, 1)):
        _perceive_group(todo[at : at + group], frames, nets, dt, cache, rep, spent, out, certified)
    return out


def _names(combo: tuple[Fault, ...]) -> str:
    return ", ".join(f"{f.name} ({f.text()})" for f in combo)


def _by_step(footage: Footage) -> dict[int, Frame]:
    return {fr.step: fr for fr in footage.frames}


def _perceive_group(
    todo: list[tuple[tuple[Fault, ...], list[StuckUnit], str]],
    frames: FrameSet,
    nets: Callable[[], Nets],
    dt: float,
    cache: StageCache,
    rep: Reporter,
    spent: Callable[[str], None],
    out: NeuronRuns,
    certified: bool,
) -> None:
    """The video perceived by each faulty network of ``todo``, stored and added to ``out``."""
    from lesmc.perception.neurons import with_stuck_units

    faulty = [with_stuck_units(nets(), units) for _, units, _ in todo]
    label = _names(todo[0][0]) if len(todo) == 1 else f"{len(todo)} sets of stuck neurons"
    with rep.bar(f"perceiving with {label}", len(frames)) as bar:

        def advance() -> None:
            bar.advance()
            spent("perceiving the video with neurons stuck")

        metas = [{"neuron faults": _names(combo)} for combo, _, _ in todo]
        seen = video_perception.perceive_videos(frames, faulty, dt, metas, certified, advance)
    for (combo, _, combo_key), net, (footage, run) in zip(todo, faulty, seen, strict=True):
        video_perception.store(cache, "neuron-fault", combo_key, footage, run.unit_max)
        name = frozenset(f.name for f in combo)
        out.frames[name] = _by_step(footage)
        if certified:
            label = f"certifying with {_names(combo)}"
            out.certify[name] = video_perception.certifier(net, run, label, rep, spent)
