"""filterpy's KalmanFilter as the reference the tracker is tested against (test-only)."""

from __future__ import annotations

import numpy as np
from filterpy.kalman import KalmanFilter

from lesmc.tracking.kalman import Matrices


def reference_filter(m: Matrices, x0: np.ndarray, P: np.ndarray | None = None) -> KalmanFilter:
    """A filterpy KalmanFilter in the given state (the reference implementation)."""
    kf = KalmanFilter(dim_x=4, dim_z=2)
    kf.F, kf.Q, kf.H, kf.R = m.F.copy(), m.Q.copy(), m.H.copy(), m.R.copy()
    kf.x = np.asarray(x0, dtype=float).reshape(4, 1).copy()
    kf.P = (m.P0 if P is None else P).copy()
    return kf
