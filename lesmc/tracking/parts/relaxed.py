"""The joint design relaxed to its primary track: whether a state has any completion that a
monitor reading only the primary's covariance allows (docs/semantics.md, "A root no
monitored path leaves").

Every path of the joint model moves its primary, at each step, by a skipped update (P̂) or
by an update with one measurement its gate admits: a detection of the frame or, in the
attack window under inject, an injection candidate. The relaxation lets the primary do
any of these whatever the other tracks and the attacker do, with the design's own
prediction, gains and gate (its Schedule and hypothesiser, kalman.py's batch-size
independent means), so its paths contain every path of the model's primary, bit for bit
(the measurements and the predict/gate sequence are joint_step.py's own functions).
If none of them passes the monitor (``cut``) on every step to the end, no path of the
model does. A halted primary ends a path (alive if the step into it is not cut).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING

import numpy as np

from lesmc.tracking.kalman import update_means
from lesmc.tracking.parts.joint_step import measurements, predict_and_gate

if TYPE_CHECKING:
    from lesmc.tracking.joint import JointDesign

#: (step entered, P before, P after) -> whether the monitor cuts that transition
Cut = Callable[[int, np.ndarray, np.ndarray], bool]
#: relaxed nodes one question visits at most (about 0.25-0.45 ms each; seed 2 of the
#: default video needs 1,108); past them the answer is "alive", which is sound
MAX_NODES = 5_000

#: one relaxed node on the search's stack: its memo key, step, and the moves left to try
_Node = tuple[tuple[bytes, int, int], int, Iterator[tuple[np.ndarray, int, bool]]]


def primary_alive(
    design: JointDesign,
    x: np.ndarray,
    cov: int,
    k: int,
    window: tuple[int, int],
    end: int,
    cut: Cut,
    max_nodes: int = MAX_NODES,
    deadline: float | None = None,
) -> bool:
    """Whether a primary of mean ``x`` and covariance ``cov`` (the design's track table) at
    model step ``k`` has a relaxed path to step ``end`` that ``cut`` never cuts (False: no
    path of the model from such a state survives the monitor). ``window``: the model's
    attack window (candidates are measurements there under inject). A depth-first search
    with an explicit stack (a horizon of any length) and a memo; past ``max_nodes`` nodes
    or past ``deadline`` (time.monotonic()), every node not yet decided counts as alive."""
    memo: dict[tuple[bytes, int, int], bool] = {}
    stack: list[_Node] = []
    left = [max_nodes]

    def known(x: np.ndarray, c: int, k: int) -> bool | None:
        """The node's answer when known without its moves; else None, the node pushed."""
        if k >= end or left[0] <= 0:
            return True
        if deadline is not None and time.monotonic() >= deadline:
            left[0] = 0
            return True
        key = (x.tobytes(), c, k)
        if key in memo:
            return memo[key]
        left[0] -= 1
        kids = _moves(design, x, c, k + 1, window[0] <= k + 1 <= window[1])
        stack.append((key, k, iter(kids)))
        return None

    def next_answer(k: int, kids: Iterator[tuple[np.ndarray, int, bool]], c: int) -> bool | None:
        """Try the node's moves left: True at the first alive one, False with none left,
        None when a child was pushed (the node waits for it)."""
        for y, d, halt in kids:
            if cut(k + 1, design.track_covariances[c], design.track_covariances[d]):
                continue
            got = True if halt else known(y, d, k + 1)
            if got is not False:
                return got
        return False

    answer = known(x, cov, k)
    while stack:
        key, at, kids = stack[-1]
        if answer is not True:  # None: the node is new; False: its last child was dead
            answer = next_answer(at, kids, key[1])
        if answer is None:
            continue
        memo[key] = answer
        stack.pop()
    assert answer is not None
    return answer


def _moves(
    design: JointDesign, x: np.ndarray, c: int, k: int, attacked: bool
) -> list[tuple[np.ndarray, int, bool]]:
    """The relaxed primary's moves into model step ``k``: skip, or update with each
    measurement its gate admits (those of the frame as the joint design measures it,
    joint_step.py ``measurements``); each as (mean, covariance, halted)."""
    scene = design.scene
    frame = scene.target.step + k
    Z, _ = measurements(scene, frame, attacked and design.inject, design.hide)
    cu = np.array([c], dtype=np.int64)
    hyp = design.parts.hypothesiser
    m, X, g, gated = predict_and_gate(scene, design.schedule, hyp, x[None].copy(), cu, Z, frame)
    pz, ok = gated[1], gated[5]
    out = [(X[0], int(g.pred[0]), bool(g.halt_pred[0]))]
    for z in pz[ok].tolist():
        y = update_means(m, X, g.K[:1], Z[z : z + 1])[0]
        out.append((y, int(g.post[0]), bool(g.halt_post[0])))
    return out
