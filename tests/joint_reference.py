"""Independent oracle: the joint design as it was before it was batched (one state at a time).

A copy of lesmc/tracking/joint.py at 1fb958b (its per-state Python loop, ``JointState``
objects and greedy association by ``pairs.sort()``), made standalone: it keeps
its states in :class:`ObjectList` payloads so the unfolder can run it in place
of the batched design (tests/test_joint.py monkeypatches ``make_design``).
It uses only the Kalman and gate helpers of lesmc.tracking (checked against
filterpy in tests/test_tracking.py).
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass

import numpy as np

from lesmc.tracking.association import gate_mask, gate_radius
from lesmc.tracking.design import Batch, CovarianceTable, Successors
from lesmc.tracking.kalman import (
    Innovation,
    Matrices,
    innovation,
    mahalanobis2,
    matrices,
    predict,
    update_means,
    warp,
)
from lesmc.tracking.scene import Scene


class ObjectList(list):  # type: ignore[type-arg]
    """Whole states as Python objects, with the payload interface the unfolder uses."""

    def take(self, idx: np.ndarray) -> ObjectList:
        return ObjectList(self[int(i)] for i in idx)

    def store(self) -> ObjectList:
        return ObjectList()


@dataclass(frozen=True, eq=False)
class JointState:
    """The whole joint tracker: primary and refining (x, P), and pending detections."""

    tracks: tuple[tuple[np.ndarray, np.ndarray], ...]  # tracks[0] is the primary
    pending: np.ndarray  # (n, 2) unassociated detections of the previous frame
    halted: bool = False

    @property
    def x(self) -> np.ndarray:
        return self.tracks[0][0]

    @property
    def P(self) -> np.ndarray:
        return self.tracks[0][1]

    def estimate(self) -> tuple[np.ndarray, np.ndarray]:
        return self.tracks[0]

    def key(self) -> bytes:
        parts = [a.tobytes() for x, P in self.tracks for a in (x, P)]
        return b"|".join([*parts, self.pending.tobytes()])


class ReferenceJointDesign:
    """Primary plus refining tracks with likelihood-sorted one-to-one association."""

    name = "joint"

    def __init__(self, scene: Scene) -> None:
        self.scene = scene
        self.cfg = scene.tracker
        self.m: Matrices = matrices(self.cfg, scene.dt)
        self.covariances = CovarianceTable()

    def initial(self) -> Batch:
        t = self.scene.target
        x0 = np.array([*t.start, *t.velocity], dtype=float)
        Z = self.scene.frame(t.step).positions()
        near = Z[np.hypot(*(Z - x0[:2]).T) <= self.cfg.init_radius] if len(Z) else Z
        return self._batch([JointState(((x0, self.m.P0.copy()),), near.reshape(-1, 2))])

    def _batch(self, states: list[JointState]) -> Batch:
        """Joint states as a batch: the primary's estimate and covariance are the model's."""
        X = np.array([st.x for st in states], dtype=float).reshape(-1, 4)
        cov = np.array([self.covariances.add(st.P) for st in states], dtype=np.int64)
        halted = np.array([st.halted for st in states], dtype=bool)
        return Batch(X, cov, halted, ObjectList(states))

    def keys(self, batch: Batch) -> np.ndarray:
        """A 128-bit digest of each whole joint state (tracks and pending detections)."""
        assert batch.objects is not None
        digests = b"".join(
            hashlib.blake2b(st.key(), digest_size=16).digest() for st in batch.objects
        )
        return np.frombuffer(digests, dtype=np.uint64).reshape(-1, 2)

    def successors(self, batch: Batch, step: int, attacked: bool) -> Successors:
        """Every state's outcomes, one state at a time (association is greedy and per state)."""
        assert batch.objects is not None
        src: list[int] = []
        rank: list[int] = []
        pay: list[float] = []
        det: list[int] = []
        states: list[JointState] = []
        for i, st in enumerate(batch.objects):
            opts = self.options(st, step)
            if not attacked:
                opts = opts[:1]  # its own payoff is kept: it is part of no combined payoff
            for r, (nxt, d, p) in enumerate(opts):
                src.append(i)
                rank.append(r)
                pay.append(p)
                det.append(d)
                states.append(nxt)
        return Successors(
            np.array(src, dtype=np.int64),
            np.array(rank, dtype=np.int64),
            np.array(pay, dtype=float),
            np.array(det, dtype=np.int64),
            self._batch(states),
        )

    def options(self, st: JointState, step: int) -> list[tuple[JointState, int, float]]:
        """Outcomes of hiding the j detections nearest to the primary's prediction, j = 0, 1, ..."""
        scene, cfg = self.scene, self.cfg
        Hm = scene.frame(step - 1).to_next
        preds = []
        for x, P in st.tracks:
            x = x.copy()
            x[:2] = warp(Hm, x[:2])
            xp, Pp = predict(self.m, x, P)
            preds.append((xp, Pp, innovation(self.m, Pp)))
        pending = warp(Hm, st.pending) if len(st.pending) else st.pending
        frame = scene.frame(step)
        Z = frame.positions()
        xp0, Pp0, inn0 = preds[0]
        y0 = Z - xp0[:2]
        dist = np.sqrt(y0[:, 0] ** 2 + y0[:, 1] ** 2)
        order = np.argsort(dist, kind="stable")
        radius = gate_radius(inn0, Pp0, cfg.gate, cfg.gate_type)
        near = order[dist[order] <= radius]
        gated = gate_mask(y0[near], inn0, Pp0, cfg.gate, cfg.gate_type)
        last = int(np.nonzero(gated)[0].max()) + 1 if gated.any() else 0
        payoffs = frame.payoffs()
        kept: list[tuple[float, JointState, int]] = []  # (cost of hiding, state, detection)
        seen: set[bytes] = set()
        cost = 0.0
        for j in range(last + 1):  # option j hides the j nearest detections
            if j > 0:
                p = float(payoffs[near[j - 1]])
                if not math.isfinite(p):
                    break  # an unattackable detection cannot be hidden
                cost += p
            visible = np.ones(len(Z), dtype=bool)
            visible[near[:j]] = False
            nxt, obs = self._associate(preds, pending, Z, visible, frame)
            if nxt.key() not in seen:  # identical joint states: keep the cheapest
                seen.add(nxt.key())
                kept.append((cost, nxt, obs))
        # own payoffs so that Eq. 5 (sum over lower ranks) gives each option's cost
        return [
            (st_, obs, (kept[r + 1][0] - c) if r + 1 < len(kept) else 0.0)
            for r, (c, st_, obs) in enumerate(kept)
        ]

    def _associate(
        self,
        preds: list[tuple[np.ndarray, np.ndarray, Innovation]],
        pending: np.ndarray,
        Z: np.ndarray,
        visible: np.ndarray,
        frame: object,
    ) -> tuple[JointState, int]:
        cfg = self.cfg
        idx = np.nonzero(visible)[0]
        pairs: list[tuple[float, int, int]] = []
        for ti, (xp, Pp, inn) in enumerate(preds):
            y = Z[idx] - xp[:2]
            ok = gate_mask(y, inn, Pp, cfg.gate, cfg.gate_type) if len(idx) else np.zeros(0, bool)
            d2 = mahalanobis2(y, inn.S_inv) if len(idx) else np.zeros(0)
            norm = 2 * math.pi * math.sqrt(float(np.linalg.det(inn.S)))
            for r in np.nonzero(ok)[0]:
                like = math.exp(-0.5 * float(d2[r])) / norm
                pairs.append((-like, ti, int(idx[r])))
        pairs.sort()
        used_t: set[int] = set()
        used_z: set[int] = set()
        assign: dict[int, int] = {}
        for _, ti, zi in pairs:
            if ti in used_t or zi in used_z:
                continue
            used_t.add(ti)
            used_z.add(zi)
            assign[ti] = zi
        tracks = []
        for ti, (xp, Pp, inn) in enumerate(preds):
            if ti in assign:
                z = Z[assign[ti]]
                tracks.append((update_means(xp, inn.K, z), inn.P_post))
            else:
                tracks.append((xp, Pp))
        primary = tracks[0]
        halted = float(np.trace(primary[1])) > cfg.max_trace
        # track initiation from unassociated detections near the primary
        free = [i for i in idx if i not in used_z]
        free_z = Z[free].reshape(-1, 2)
        near_p = (
            free_z[np.hypot(*(free_z - primary[0][:2]).T) <= cfg.init_radius]
            if len(free_z)
            else free_z
        )
        pool = [p for p in pending]
        keep: list[np.ndarray] = []
        for z in near_p:
            if pool:
                dd = [float(np.hypot(*(z - p))) for p in pool]
                b = int(np.argmin(dd))
                if dd[b] < cfg.init_distance:
                    v = (z - pool.pop(b)) / self.scene.dt
                    tracks.append((np.array([z[0], z[1], v[0], v[1]]), self.m.P0.copy()))
                    continue
            keep.append(z)
        refining = [
            t
            for t in tracks[1:]
            if float(np.hypot(*(t[0][:2] - primary[0][:2]))) <= cfg.prune_radius
            and float(np.trace(t[1])) <= cfg.max_trace
        ]
        pend = np.array(keep, dtype=float).reshape(-1, 2)
        return JointState((primary, *refining), pend, halted), assign.get(0, -1)
