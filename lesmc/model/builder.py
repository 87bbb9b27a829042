"""Unfold a tracked scene into a <PO>²-LTS (paper section 3.3, Algorithm 1).

Model step k is frame ``target.step + k``. The original run goes from the
target's frame to step e; from step l to u every attacker-forced outcome of
the tracker is a transition (ranked nearest detection first, see
tracking/association.py); outside the window each branch follows the
unattacked (rank-minimal) outcome to e. States that coincide exactly are
shared.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from lesmc.errors import UsageError
from lesmc.model.lts import HALTED, LTS, State, Transition
from lesmc.tracking.design import Design, TrackerState, make_design
from lesmc.tracking.scene import Scene

COMPONENTS = ("x", "y", "vx", "vy")


def max_end(scene: Scene) -> int:
    """The last model step the scene's frames allow."""
    return scene.last_step - scene.target.step


def original_run(design: Design, end: int | None = None) -> list[TrackerState]:
    """The unattacked track from the target's frame, up to ``end`` or until it halts."""
    scene = design.scene
    last = max_end(scene) if end is None else end
    run = [design.initial()]
    for k in range(1, last + 1):
        if run[-1].halted:
            break
        run.append(design.unattacked([run[-1]], scene.target.step + k)[0].state)
    return run


@dataclass
class _Graph:
    """States and transitions being collected, with exact-duplicate sharing per step."""

    states: list[State] = field(default_factory=list)
    trans: list[Transition] = field(default_factory=list)
    index: dict[tuple[int, bytes], str] = field(default_factory=dict)
    tstate: dict[str, TrackerState] = field(default_factory=dict)

    def add(self, step: int, ts: TrackerState) -> tuple[str, bool]:
        """The id of ``ts`` at ``step``, and whether it is new."""
        key = (step, ts.key())
        if key in self.index:
            return self.index[key], False
        sid = f"k{step}.{len(self.states)}"
        s, P = ts.estimate()
        labels = frozenset({HALTED}) if ts.halted else frozenset()
        self.states.append(State(sid, step, s, P, labels))  # tracker arrays are never mutated
        self.index[key] = sid
        self.tstate[sid] = ts
        return sid, True


def build_model(
    scene: Scene,
    window: tuple[int, int],
    end: int | None = None,
    on_level: Callable[[int, int], None] | None = None,
) -> LTS:
    """The LTS of ``scene`` for attacks in ``window`` = (l, u), up to step ``end``.

    ``on_level(step, states)`` is called after each step (for progress bars).
    """
    design = make_design(scene)
    l, u = window
    limit = max_end(scene)
    if end is not None and end > limit:
        raise UsageError(
            f"end {end} is beyond the scene: its frames allow steps 0..{limit} "
            f"from the target's frame {scene.target.step}"
        )
    run = original_run(design, end)
    e = len(run) - 1
    if end is not None and e < end:
        raise UsageError(
            f"the unattacked track halts at step {e} (trace(P) > max_trace); use --end {e} or less"
        )
    if not 1 <= l <= u <= e:
        raise UsageError(f"window {l}..{u} must satisfy 1 <= l <= u <= end = {e}")
    g = _Graph()
    root, _ = g.add(0, run[0])
    frontier = [root]
    for k in range(1, e + 1):
        nxt: list[str] = []
        live = [sid for sid in frontier if not g.tstate[sid].halted]
        frame = scene.target.step + k
        if l <= k <= u:
            expanded = [design.options(g.tstate[sid], frame) for sid in live]
        else:  # outside the window only the unattacked outcome, for all states at once
            expanded = [[o] for o in design.unattacked([g.tstate[sid] for sid in live], frame)]
        for sid, opts in zip(live, expanded, strict=True):
            for rank, o in enumerate(opts):
                child, new = g.add(k, o.state)
                g.trans.append(Transition(sid, child, o.payoff, rank, o.obs))
                if new:
                    nxt.append(child)
        frontier = nxt
        if on_level is not None:
            on_level(k, len(g.states))
    # the original path is the rank-0 (unattacked) chain of the graph itself: recomputing it
    # apart would differ in the last bits wherever a design batches its arithmetic
    first_choice = {t.src: t.dst for t in g.trans if t.rank == 0}
    original = [root]
    while len(original) <= e and original[-1] in first_choice:
        original.append(first_choice[original[-1]])
    model = LTS.from_parts(g.states, g.trans, root, original, COMPONENTS, check=False)
    model.meta = {
        "source": "lesmc build",
        "design": design.name,
        "window": [l, u],
        "first_frame": scene.target.step,
        "end": e,
    }
    return model
