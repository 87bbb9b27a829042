"""The runtime monitor of section 7.1: uncertainty τ (Eq. 12) and its alarm (Eq. 13).

τ is the trace of the location block of the covariance P (the components the
detections measure). During normal
tracking it shrinks towards convergence; it rises when an update is skipped
(no observation accepted), which is what an attack that hides detections
causes. The alarm fires when τ rises: Eq. 13's Γ = 0. Both equations live in the
semantics kernel (lesmc/model/kernel.py); this module runs the unattacked track.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lesmc.model.kernel import alarm, tau
from lesmc.tracking.design import Design


@dataclass(frozen=True)
class TrackPoint:
    """One step of an unattacked track, with the monitor's view of it."""

    step: int
    frame: int
    obs: str | None
    x: np.ndarray
    P: np.ndarray
    tau: float
    alarm: bool
    halted: bool
    #: the NIS of the update entering this step (None: no update, step 0, or a design that
    #: does not report it)
    nis: float | None = None


def track(design: Design, end: int | None = None) -> list[TrackPoint]:
    """The unattacked track from the target's frame, with τ and the alarm per step."""
    scene = design.scene
    last = scene.last_step - scene.target.step if end is None else end
    b = design.initial()
    loc = scene.tracker.measured
    P = design.covariances[int(b.cov[0])]
    t0 = float(tau(P, loc))
    points = [TrackPoint(0, scene.target.step, None, b.X[0], P, t0, False, bool(b.halted[0]))]
    for k in range(1, last + 1):
        if b.halted[0]:
            break
        frame = scene.target.step + k
        succ = design.successors(b, frame, False)
        b = succ.states
        det = int(succ.det[0])
        obs = None if det < 0 else scene.frame(frame).detections[det].id
        P = design.covariances[int(b.cov[0])]
        t = float(tau(P, loc))
        nis = None if succ.nis is None or np.isnan(succ.nis[0]) else float(succ.nis[0])
        fired = bool(alarm(points[-1].tau, t))
        points.append(TrackPoint(k, frame, obs, b.X[0], P, t, fired, bool(b.halted[0]), nis))
    return points
