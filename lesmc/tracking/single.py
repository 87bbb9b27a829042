"""Design "single": one Kalman filter with gated nearest-neighbour association (section 6.7).

A tracker state is (x, P) plus a halted flag. :meth:`SingleDesign.options`
returns every outcome an attacker can force at the next frame, in rank order;
option 0 is what the unattacked tracker does.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lesmc.tracking.association import attack_options, gate_mask, gate_radius
from lesmc.tracking.design import Outcome, merge_equal
from lesmc.tracking.kalman import Matrices, innovation, matrices, predict, update_many, warp
from lesmc.tracking.scene import Scene


@dataclass(frozen=True, eq=False)
class SingleState:
    """ρ = (s, P) of one Kalman filter."""

    x: np.ndarray
    P: np.ndarray
    halted: bool = False

    def estimate(self) -> tuple[np.ndarray, np.ndarray]:
        return self.x, self.P

    def key(self) -> bytes:
        """Exact identity, so coinciding states can be shared."""
        return self.x.tobytes() + self.P.tobytes()


class SingleDesign:
    """The plain tracker; ``scene`` gives detections, camera motion and the configuration."""

    name = "single"

    def __init__(self, scene: Scene) -> None:
        self.scene = scene
        self.cfg = scene.tracker
        self.m: Matrices = matrices(self.cfg, scene.dt)

    def initial(self) -> SingleState:
        """At the target's frame: (start, velocity) with P0; that frame's detections unused."""
        t = self.scene.target
        return SingleState(np.array([*t.start, *t.velocity], dtype=float), self.m.P0.copy())

    def options(self, st: SingleState, step: int) -> list[Outcome]:
        """All attacker-forced outcomes of moving from frame ``step − 1`` to ``step``."""
        scene = self.scene
        x = st.x.copy()
        x[:2] = warp(scene.frame(step - 1).to_next, x[:2])
        x_pred, P_pred = predict(self.m, x, st.P)
        inn = innovation(self.m, P_pred)
        frame = scene.frame(step)
        Z = frame.positions()
        y = Z - x_pred[:2]
        dist = np.sqrt(np.einsum("ij,ij->i", y, y))
        near = np.nonzero(dist <= gate_radius(inn, P_pred, self.cfg.gate, self.cfg.gate_type))[0]
        gated = gate_mask(y[near], inn, P_pred, self.cfg.gate, self.cfg.gate_type)
        opts = attack_options(dist[near], gated, frame.payoffs()[near])
        chosen = [near[o.detection] for o in opts if o.detection is not None]
        X = update_many(x_pred, inn, Z[chosen]) if chosen else np.zeros((0, 4))
        halt_post = float(np.trace(inn.P_post)) > self.cfg.max_trace
        halt_pred = float(np.trace(P_pred)) > self.cfg.max_trace
        out: list[Outcome] = []
        row = 0
        for o in opts:
            if o.detection is None:
                nxt = SingleState(x_pred, P_pred, halt_pred)
                out.append(Outcome(nxt, None, o.payoff))
            else:
                det = frame.detections[int(near[o.detection])]
                out.append(Outcome(SingleState(X[row], inn.P_post, halt_post), det.id, o.payoff))
                row += 1
        return merge_equal(out)
