"""Independent oracle for the joint design, written from the paper (section 7.2) and
docs/tracking.md ("The joint design"), not from lesmc/tracking/joint.py.

Every run of the joint tracker under attack is enumerated one path at a time, as
a tree: each track is a filterpy ``KalmanFilter`` (predict, update in Joseph
form), association is the greedy one-to-one scan of gated (track, detection)
pairs by likelihood N(z; Hx̂, S), and the attacker's options are "hide the j
detections nearest the primary's prediction". Nothing of lesmc.tracking,
lesmc.build or lesmc.model is used: only the scene (its detections, payoffs,
homographies and tracker settings) is read through lesmc.scene.

:func:`oracle_paths` gives each complete path as (primary estimates per step,
halted, attack cost); tests/test_joint.py compares them with the paths of the
model lesmc unfolds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from filterpy.common import Q_continuous_white_noise
from filterpy.kalman import KalmanFilter

from lesmc.scene import Scene

Track = tuple[np.ndarray, np.ndarray]  # (x (4,), P (4, 4))


@dataclass(frozen=True)
class Joint:
    """A joint state: tracks[0] is the primary; pending: last frame's unused detections."""

    tracks: tuple[Track, ...]
    pending: np.ndarray
    halted: bool

    def key(self) -> bytes:
        return b"|".join([a.tobytes() for x, P in self.tracks for a in (x, P)] + [
            self.pending.tobytes(), bytes([self.halted])
        ])  # fmt: skip


class Oracle:
    """The joint tracker of one scene (section 7.2), one state at a time."""

    def __init__(self, scene: Scene) -> None:
        cfg = scene.tracker
        self.scene, self.cfg, dt = scene, cfg, scene.dt
        self.F = np.eye(4)
        self.F[0, 2] = self.F[1, 3] = dt  # Eq. 16
        self.Q = Q_continuous_white_noise(  # Eq. 17
            dim=2, dt=dt, spectral_density=cfg.sigma_q**2, block_size=2, order_by_dim=False
        )
        self.H = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0]])  # Eq. 18
        self.R = np.eye(2) * cfg.sigma_r**2
        self.P0 = np.diag(np.square(np.asarray(cfg.P0_sd, dtype=float)))

    def _kf(self, x: np.ndarray, P: np.ndarray) -> KalmanFilter:
        kf = KalmanFilter(dim_x=4, dim_z=2)
        kf.x, kf.P = x.reshape(4, 1).copy(), P.copy()
        kf.F, kf.Q, kf.H, kf.R = self.F, self.Q, self.H, self.R
        return kf

    def initial(self) -> Joint:
        t = self.scene.target
        x0 = np.array([*t.start, *t.velocity], dtype=float)
        Z = self.scene.frame(t.step).positions().reshape(-1, 2)
        near = [z for z in Z if math.dist(z, x0[:2]) <= self.cfg.joint.init_radius]
        return Joint(((x0, self.P0.copy()),), np.array(near, dtype=float).reshape(-1, 2), False)

    def options(self, st: Joint, frame_step: int, attacked: bool) -> list[tuple[float, Joint]]:
        """(attack cost, next state) of each distinct outcome, cheapest first."""
        Hm = self.scene.frame(frame_step - 1).to_next
        preds = []
        for x, P in st.tracks:
            x = x.copy()
            x[:2] = _warp(Hm, x[:2])
            kf = self._kf(x, P)
            kf.predict()
            preds.append(kf)
        pending = np.array([_warp(Hm, p) for p in st.pending]).reshape(-1, 2)
        frame = self.scene.frame(frame_step)
        Z = frame.positions().reshape(-1, 2)
        pays = frame.payoffs()
        xp = preds[0].x[:2, 0]
        by_dist = sorted(range(len(Z)), key=lambda i: (math.dist(Z[i], xp), i))
        gated = [i for i, z in enumerate(by_dist) if self._gate(preds[0], Z[z])]
        last = max(gated) + 1 if gated else 0
        out: list[tuple[float, Joint]] = []
        seen: set[bytes] = set()
        for j in range(last + 1 if attacked else 1):
            hidden = by_dist[:j]
            if any(not math.isfinite(pays[i]) for i in hidden):
                break  # a detection the attack cannot hide
            nxt = self._step(preds, pending, Z, set(hidden))
            if nxt.key() not in seen:  # the same outcome: the cheapest way is kept
                seen.add(nxt.key())
                out.append((float(sum(pays[i] for i in hidden)), nxt))
        return out

    def _gate(self, kf: KalmanFilter, z: np.ndarray) -> bool:
        y = z - kf.x[:2, 0]
        if self.cfg.gate_type == "euclidean":
            return bool(math.hypot(*y) <= self.cfg.gate * math.sqrt(kf.P[0, 0] + kf.P[1, 1]))
        S = self.H @ kf.P @ self.H.T + self.R
        return bool(math.sqrt(max(float(y @ np.linalg.solve(S, y)), 0.0)) <= self.cfg.gate)

    def _likelihood(self, kf: KalmanFilter, z: np.ndarray) -> float:
        S = self.H @ kf.P @ self.H.T + self.R
        y = z - kf.x[:2, 0]
        d2 = float(y @ np.linalg.solve(S, y))
        return math.exp(-0.5 * d2) / (2 * math.pi * math.sqrt(float(np.linalg.det(S))))

    def _step(
        self, preds: list[KalmanFilter], pending: np.ndarray, Z: np.ndarray, hidden: set[int]
    ) -> Joint:
        cfg = self.cfg
        visible = [i for i in range(len(Z)) if i not in hidden]
        pairs = sorted(
            (-self._likelihood(kf, Z[i]), t, i)
            for t, kf in enumerate(preds)
            for i in visible
            if self._gate(kf, Z[i])
        )
        assign: dict[int, int] = {}
        for _, t, i in pairs:  # greedy, one to one, likeliest first
            if t not in assign and i not in assign.values():
                assign[t] = i
        tracks: list[Track] = []
        for t, kf in enumerate(preds):
            if t in assign:
                kf = self._kf(kf.x[:, 0], kf.P)
                kf.update(Z[assign[t]])
            tracks.append((kf.x[:, 0].copy(), kf.P.copy()))
        primary = tracks[0]
        pool = [p for p in pending]
        keep = []
        for i in visible:  # new tracks: free detections near the primary, in index order
            z = Z[i]
            if i in assign.values() or math.dist(z, primary[0][:2]) > cfg.joint.init_radius:
                continue
            d = [math.dist(z, p) for p in pool]
            b = min(range(len(d)), key=lambda k: (d[k], k)) if d else -1
            if b >= 0 and d[b] < cfg.joint.init_distance:
                v = (z - pool.pop(b)) / self.scene.dt
                tracks.append((np.array([z[0], z[1], v[0], v[1]]), self.P0.copy()))
            else:
                keep.append(z)
        refining = tuple(
            t
            for t in tracks[1:]
            if math.dist(t[0][:2], primary[0][:2]) <= cfg.joint.prune_radius
            and np.trace(t[1]) <= cfg.max_trace
        )
        halted = bool(np.trace(primary[1]) > cfg.max_trace)
        return Joint((primary, *refining), np.array(keep, dtype=float).reshape(-1, 2), halted)


def oracle_paths(
    scene: Scene, window: tuple[int, int], end: int
) -> list[tuple[tuple[tuple[float, ...], ...], bool, float]]:
    """Every complete path of the attacked joint tracker, steps 0..end (or to a halt):
    the primary's estimates, whether it halted, and the attack's total cost (the
    combined payoffs of Eq. 5 summed over the path)."""
    oracle = Oracle(scene)
    out = []
    todo = [(0, oracle.initial(), (), 0.0)]
    while todo:
        k, st, xs, cost = todo.pop()
        xs = (*xs, tuple(st.tracks[0][0]))
        if st.halted or k == end:
            out.append((xs, st.halted, cost))
            continue
        attacked = window[0] <= k + 1 <= window[1]
        for c, nxt in oracle.options(st, scene.target.step + k + 1, attacked):
            todo.append((k + 1, nxt, xs, cost + c))
    return out


def _warp(H: np.ndarray | None, p: np.ndarray) -> np.ndarray:
    """A point through the homography H (None: the camera did not move)."""
    if H is None:
        return np.asarray(p, dtype=float).copy()
    v = np.asarray(H, dtype=float) @ np.array([p[0], p[1], 1.0])
    return v[:2] / v[2]
