"""The joint design relaxed to its primary track: whether a state has any completion that a
monitor reading only the primary's covariance allows (docs/semantics.md, "A root no
monitored path leaves").

Every path of the joint model moves its primary, at each step, by a skipped update (P̂) or
by an update with one measurement its gate admits: a detection of the frame or, in the
attack window under inject, an injection candidate. The relaxation lets the primary do
any of these whatever the other tracks and the attacker do, with the design's own
prediction, gains and gate (its Schedule and hypothesiser, kalman.py's batch-size
independent means), so its paths contain every path of the model's primary, bit for bit.
If none of them passes the monitor (``cut``) on every step to the end, no path of the
model does. A halted primary ends a path (alive if the step into it is not cut).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from lesmc.tracking.kalman import measure, positions, predict_means, update_means, warp

if TYPE_CHECKING:
    from lesmc.tracking.joint import JointDesign

#: (step entered, P before, P after) -> whether the monitor cuts that transition
Cut = Callable[[int, np.ndarray, np.ndarray], bool]
#: relaxed nodes one question visits at most (about 1-4 ms each; seed 2 of the default
#: video needs 1,108); past them the answer is "alive", which is sound
MAX_NODES = 5_000


def primary_alive(
    design: JointDesign,
    x: np.ndarray,
    cov: int,
    k: int,
    window: tuple[int, int],
    end: int,
    cut: Cut,
) -> bool:
    """Whether a primary of mean ``x`` and covariance ``cov`` (the design's track table) at
    model step ``k`` has a relaxed path to step ``end`` that ``cut`` never cuts (False: no
    path of the model from such a state survives the monitor). ``window``: the model's
    attack window (candidates are measurements there under inject)."""
    memo: dict[tuple[bytes, int, int], bool] = {}
    left = [MAX_NODES]

    def alive(x: np.ndarray, c: int, k: int) -> bool:
        if k >= end or left[0] <= 0:
            return True
        key = (x.tobytes(), c, k)
        if key not in memo:
            left[0] -= 1
            kids = _moves(design, x, c, k + 1, window[0] <= k + 1 <= window[1])
            memo[key] = any(
                halt or alive(y, d, k + 1)
                for y, d, halt in kids
                if not cut(k + 1, design.track_covariances[c], design.track_covariances[d])
            )
        return memo[key]

    return alive(x, cov, k)


def _moves(
    design: JointDesign, x: np.ndarray, c: int, k: int, attacked: bool
) -> list[tuple[np.ndarray, int, bool]]:
    """The relaxed primary's moves into model step ``k``: skip, or update with each
    measurement its gate admits; each as (mean, covariance, halted)."""
    scene = design.scene
    frame = scene.target.step + k
    m, gains = design.schedule.at(frame)
    X = x[None].copy()
    Hm = scene.frame(frame - 1).to_next
    if Hm is not None:
        X[:, list(m.pos)] = warp(Hm, positions(m, X))
    X = predict_means(m, X)
    g = gains.rows(np.array([c], dtype=np.int64))
    f = scene.frame(frame)
    Z = f.positions()
    if attacked and design.inject and f.candidates:
        Z = np.vstack([Z, f.injectable.positions()])
    _, pz, _, _, _, ok = design.parts.hypothesiser.pairs(
        Z, measure(m, X), g.radius, g.S_inv, g.spread
    )
    out = [(X[0], int(g.pred[0]), bool(g.halt_pred[0]))]
    for z in pz[ok].tolist():
        y = update_means(m, X, g.K[:1], Z[z : z + 1])[0]
        out.append((y, int(g.post[0]), bool(g.halt_post[0])))
    return out
