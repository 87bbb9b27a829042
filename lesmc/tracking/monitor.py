"""The runtime monitor of section 7.1: uncertainty τ (Eq. 12) and its alarm (Eq. 13).

τ is the trace of the location block of the covariance P (the components the
detections measure). During normal
tracking it shrinks towards convergence; it rises when an update is skipped
(no observation accepted), which is what an attack that hides detections
causes. The alarm fires when τ rises: Eq. 13's Γ = 0. Both equations live in the
semantics kernel (lesmc/model/kernel.py); this module runs the unattacked track.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from lesmc.model.kernel import alarm, tau
from lesmc.scene.scene import Scene, TruthTrack
from lesmc.tracking.association import gate_radius
from lesmc.tracking.design import Design
from lesmc.tracking.kalman import Matrices, innovation, matrices, measure, position_spread


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


#: The unattacked track should take a detection within this many steps of the target's frame.
FIRST_STEPS = 3
#: It ends "far" from the target's truth beyond this many gate radii of its final estimate.
FAR_GATES = 3.0


def follow_warnings(design: Design, points: Sequence[TrackPoint]) -> list[str]:
    """Signs that the unattacked track does not follow its target, as sentences: a tracker
    whose H measures the wrong components, or whose gate or noise rejects the target's
    detections, verifies vacuously (nothing to attack). Two signs (docs/own-system.md,
    "Does the tracker follow the target?"):

    * no detection taken in steps 1..FIRST_STEPS (every step when the track is shorter);
    * the scene's truth has the target's track (the truth track nearest the target's start
      at its frame, within the gate of the initial estimate) and the track's last estimate
      is farther from it than FAR_GATES gate radii (of that estimate's S = H P Hᵀ + R) at
      the last frame both have.
    """
    out: list[str] = []
    first = points[1 : FIRST_STEPS + 1]
    if first and all(p.obs is None for p in first):
        out.append(
            f"the unattacked track takes no detection in its first {len(first)} steps "
            f"(frames {first[0].frame}..{first[-1].frame}): the tracker may not follow the "
            "target (check H measures the detection's x, y, and the gate and R), and "
            "properties of its attacked tracks may hold vacuously"
        )
    scene = design.scene
    m = matrices(scene.tracker, scene.dt)
    truth = _target_truth(design, m, points[0])
    if truth is None:
        return out
    at = {k: (x, y) for k, x, y in truth.positions}
    last = next((p for p in reversed(points) if p.frame in at), None)
    if last is None or last.step == 0:
        return out
    off = np.asarray(at[last.frame]) - measure(m, last.x)
    dist = float(np.hypot(off[0], off[1]))
    radius = _gate_radius(scene, m, last.P)
    if dist > FAR_GATES * radius:
        out.append(
            f"the unattacked track ends {dist:.1f} px from the target's truth (track "
            f"'{truth.id}') at frame {last.frame}, more than {FAR_GATES:g} gate radii "
            f"({radius:.1f} px): the tracker may not follow the target"
        )
    return out


def _gate_radius(scene: Scene, m: Matrices, P: np.ndarray) -> float:
    """No detection farther than this from the estimate of covariance ``P`` passes the gate."""
    cfg = scene.tracker
    return gate_radius(innovation(m, P), float(position_spread(m, P)), cfg.gate, cfg.gate_type)


def _target_truth(design: Design, m: Matrices, start: TrackPoint) -> TruthTrack | None:
    """The truth track of the target: the nearest to its start at its frame, if a detection
    there would pass the initial estimate's gate."""
    scene = design.scene
    here = [
        (float(np.hypot(x - scene.target.start[0], y - scene.target.start[1])), t)
        for t in scene.truth
        for k, x, y in t.positions
        if k == start.frame
    ]
    if not here:
        return None
    dist, best = min(here, key=lambda dt: dt[0])
    return best if dist <= _gate_radius(scene, m, start.P) else None
