"""The runtime monitor of section 7.1: uncertainty τ (Eq. 12) and its alarm (Eq. 13).

τ is the trace of the location block of the covariance P. During normal
tracking it shrinks towards convergence; it rises when an update is skipped
(no observation accepted), which is what an attack that hides detections
causes. The alarm fires when τ rises: Eq. 13's Γ = 0.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from lesmc.tracking.design import Design

LOCATION = (0, 1)
"""Indices of the location block (x, y) in the state (x, y, vx, vy)."""

DEFAULT_TOLERANCE = 1e-9
"""Relative rise of τ ignored by the alarm: only absorbs rounding."""


def tau(P: np.ndarray, components: Sequence[int] = LOCATION) -> np.ndarray:
    """τ = tr(Σ_ll) of one covariance (d, d) or of a stack (n, d, d) (Eq. 12)."""
    idx = list(components)
    sub = P[..., idx, :][..., :, idx]
    out: np.ndarray = np.trace(sub, axis1=-2, axis2=-1)
    return out


def alarm(
    tau_prev: ArrayLike, tau_next: ArrayLike, tolerance: float = DEFAULT_TOLERANCE
) -> np.ndarray:
    """Γ = 0 of Eq. 13: τ rose from one step to the next (beyond the relative tolerance)."""
    out: np.ndarray = np.asarray(tau_next) > np.asarray(tau_prev) * (1.0 + tolerance) + 1e-300
    return out


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


def track(design: Design, end: int | None = None) -> list[TrackPoint]:
    """The unattacked track from the target's frame, with τ and the alarm per step."""
    scene = design.scene
    last = scene.last_step - scene.target.step if end is None else end
    st = design.initial()
    x, P = st.estimate()
    t0 = float(tau(P))
    points = [TrackPoint(0, scene.target.step, None, x, P, t0, False, st.halted)]
    for k in range(1, last + 1):
        if st.halted:
            break
        o = design.unattacked([st], scene.target.step + k)[0]
        st = o.state
        x, P = st.estimate()
        t = float(tau(P))
        points.append(
            TrackPoint(
                k, scene.target.step + k, o.obs, x, P, t, bool(alarm(points[-1].tau, t)), st.halted
            )
        )
    return points
