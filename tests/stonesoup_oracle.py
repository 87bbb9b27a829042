"""An independent tracker for declared models: Stone Soup's Kalman predictor and updater.

Written from docs/scene-format.md ("Tracker models") and docs/tracking.md, reading the
scene and tracker dictionaries directly (no lesmc code): the predicted measurement and
its covariance S come from Stone Soup, the association is the nearest detection
(Euclidean, first of equals), accepted if it passes the gate, and the track halts when
trace(P) exceeds ``max_trace``. Also the generator of random declared models and of
scenes simulated from them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from stonesoup.base import Property
from stonesoup.models.measurement.linear import LinearGaussian
from stonesoup.models.transition.linear import LinearGaussianTransitionModel
from stonesoup.predictor.kalman import KalmanPredictor
from stonesoup.types.array import CovarianceMatrix, StateVector
from stonesoup.types.detection import Detection
from stonesoup.types.hypothesis import SingleHypothesis
from stonesoup.types.state import GaussianState
from stonesoup.updater.kalman import KalmanUpdater


class DeclaredTransition(LinearGaussianTransitionModel):
    """x' = F x + w, w ~ N(0, Q), with the per-step F and Q given (no time interval)."""

    F: np.ndarray = Property(doc="transition matrix")
    Q: np.ndarray = Property(doc="process noise covariance")

    @property
    def ndim_state(self) -> int:
        return int(self.F.shape[0])

    def matrix(self, **kwargs: Any) -> np.ndarray:
        return self.F

    def covar(self, **kwargs: Any) -> CovarianceMatrix:
        return CovarianceMatrix(self.Q)


@dataclass
class Point:
    x: np.ndarray
    P: np.ndarray
    obs: str | None
    halted: bool
    borderline: bool  # the gate decision was within rounding of the threshold


def oracle_track(scene: dict[str, Any], tracker: dict[str, Any]) -> list[Point]:
    """The unattacked track of ``scene`` (a scene dictionary) with ``tracker`` (a tracker
    block declaring ``model`` by its matrices)."""
    m = tracker["model"]
    F, Hm, Q, R, P0 = (np.array(m[k], dtype=float) for k in ("F", "H", "Q", "R", "P0"))
    d = F.shape[0]
    mapping = tuple(int(np.flatnonzero(row)[0]) for row in Hm)
    meas = LinearGaussian(ndim_state=d, mapping=mapping, noise_covar=CovarianceMatrix(R))
    predictor = KalmanPredictor(DeclaredTransition(F=F, Q=Q))
    updater = KalmanUpdater(meas, use_joseph_cov=True)
    gate, gate_type = tracker.get("gate", 2.0), tracker.get("gate_type", "mahalanobis")
    max_trace = tracker.get("max_trace", 1e5)

    target = scene["target"]
    x0 = np.zeros(d)
    x0[list(mapping)] = target["start"]
    names = m["state"]
    if "vx" in names and "vy" in names:
        x0[[names.index("vx"), names.index("vy")]] = target.get("velocity", [0.0, 0.0])
    state = GaussianState(StateVector(x0), CovarianceMatrix(P0))
    frames = {f["step"]: f for f in scene["frames"]}
    points = [Point(x0, P0, None, False, False)]
    step = target["step"] + 1
    while step in frames:
        pred = predictor.predict(state)
        mp = updater.predict_measurement(pred)
        zp = np.asarray(mp.state_vector, dtype=float).ravel()
        S = np.asarray(mp.covar, dtype=float)
        dets = frames[step].get("detections", [])
        obs, borderline = None, False
        if dets:
            Z = np.array([[dd["x"], dd["y"]] for dd in dets])
            dist = np.hypot(Z[:, 0] - zp[0], Z[:, 1] - zp[1])
            j = int(np.flatnonzero(dist == dist.min())[0])
            y = Z[j] - zp
            if gate_type == "mahalanobis":
                value, limit = math.sqrt(float(y @ np.linalg.inv(S) @ y)), gate
            else:
                Pp = np.asarray(pred.covar, dtype=float)
                value = float(np.hypot(*y))
                limit = gate * math.sqrt(Pp[mapping[0], mapping[0]] + Pp[mapping[1], mapping[1]])
            borderline = abs(value - limit) <= 1e-9 * max(limit, 1.0)
            if value <= limit:
                obs = dets[j]["id"]
                hyp = SingleHypothesis(pred, Detection(StateVector(Z[j]), measurement_model=meas))
                state = updater.update(hyp)
            else:
                state = pred
        else:
            state = pred
        x = np.asarray(state.state_vector, dtype=float).ravel()
        P = np.asarray(state.covar, dtype=float)
        halted = float(np.trace(P)) > max_trace
        points.append(Point(x, P, obs, halted, borderline))
        if halted:
            break
        step += 1
    return points


# ---------------------------------------------------------------- random models and scenes


def _spd(rng: np.random.Generator, n: int, scale: float) -> np.ndarray:
    A = rng.normal(size=(n, n))
    return scale * (A @ A.T / n + 0.2 * np.eye(n))


def random_model(rng: np.random.Generator, kind: str) -> dict[str, Any]:
    """A tracker block declaring a model by its matrices: ``cv2d`` or ``ca2d`` (the
    presets' textbook matrices for a random dt and noise) or ``random`` (a random stable
    F, random SPD Q, R, P0, random names and measured components)."""
    dt = float(rng.uniform(0.05, 2.0))
    q, r = float(rng.uniform(0.5, 10.0)), float(rng.uniform(1.0, 8.0))
    if kind == "cv2d":
        names = ["x", "y", "vx", "vy"]
        F = np.eye(4)
        F[0, 2] = F[1, 3] = dt
        qb = np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
        Q = np.kron(qb, np.eye(2)) * q * q
        mapping = (0, 1)
        P0 = np.diag(np.square(rng.uniform(5.0, 40.0, size=4)))
    elif kind == "ca2d":
        names = ["x", "y", "vx", "vy", "ax", "ay"]
        f = np.array([[1, dt, dt * dt / 2], [0, 1, dt], [0, 0, 1]])
        F = np.kron(f, np.eye(2))
        qb = np.array(
            [
                [dt**5 / 20, dt**4 / 8, dt**3 / 6],
                [dt**4 / 8, dt**3 / 3, dt**2 / 2],
                [dt**3 / 6, dt**2 / 2, dt],
            ]
        )
        Q = np.kron(qb, np.eye(2)) * q * q
        mapping = (0, 1)
        P0 = np.diag(np.square(rng.uniform(5.0, 40.0, size=6)))
    else:
        d = int(rng.integers(2, 7))
        names = [f"s{i}" for i in range(d)]
        mapping = tuple(int(i) for i in rng.choice(d, size=2, replace=False))
        names[mapping[0]], names[mapping[1]] = "x", "y"
        if d >= 4 and rng.random() < 0.5:
            rest = [i for i in range(d) if i not in mapping]
            names[rest[0]], names[rest[1]] = "vx", "vy"
        A = rng.normal(size=(d, d))
        rho = max(abs(np.linalg.eigvals(A)))
        F = A / rho * float(rng.uniform(0.6, 0.999))
        Q = _spd(rng, d, q)
        P0 = _spd(rng, d, float(rng.uniform(10.0, 500.0)))
    d = len(names)
    H = np.zeros((2, d))
    H[0, mapping[0]] = H[1, mapping[1]] = 1.0
    R = _spd(rng, 2, r * r)
    return {
        "design": "single",
        "gate": float(rng.uniform(1.5, 4.0)),
        "gate_type": str(rng.choice(["mahalanobis", "euclidean"])),
        "max_trace": float(np.trace(P0)) * float(rng.uniform(2.0, 50.0)),
        "model": {
            "state": names,
            "F": F.tolist(),
            "H": H.tolist(),
            "Q": Q.tolist(),
            "R": R.tolist(),
            "P0": P0.tolist(),
        },
    }


def simulated_scene(rng: np.random.Generator, tracker: dict[str, Any]) -> dict[str, Any]:
    """A scene whose detections follow a track simulated from the model (missed now and
    then), with clutter nearby; its target starts at the first detection."""
    m = tracker["model"]
    F, H = np.array(m["F"]), np.array(m["H"])
    Q, R = np.array(m["Q"]), np.array(m["R"])
    d = F.shape[0]
    x = rng.normal(size=d) * 20.0
    x[np.flatnonzero(H.sum(axis=0))] = rng.uniform(100.0, 900.0, size=2)
    frames = []
    n = int(rng.integers(4, 12))
    spread = float(rng.uniform(5.0, 60.0))
    for k in range(n):
        dets = []
        z = H @ x
        if k == 0 or rng.random() > 0.2:
            zz = z + rng.multivariate_normal(np.zeros(2), R)
            dets.append({"id": f"{k}:t", "x": float(zz[0]), "y": float(zz[1]), "payoff": 1.0})
        for c in range(int(rng.integers(0, 4))):
            cz = z + rng.normal(size=2) * spread
            pay = float(rng.uniform(0.1, 3.0))
            dets.append({"id": f"{k}:c{c}", "x": float(cz[0]), "y": float(cz[1]), "payoff": pay})
        rng.shuffle(dets)  # type: ignore[arg-type]
        frames.append({"step": k, "detections": dets})
        x = F @ x + rng.multivariate_normal(np.zeros(d), Q)
    first = next(dd for dd in frames[0]["detections"] if dd["id"] == "0:t")
    target: dict[str, Any] = {"step": 0, "start": [first["x"], first["y"]]}
    return {
        "format": "lesmc-scene",
        "version": 1,
        "dt": 1.0,
        "frames": frames,
        "target": target,
        "tracker": tracker,
    }
