"""One step of the joint design (lesmc/tracking/joint.py) for a chunk of states: what all
options of a state share (:func:`prepare`: predictions, gains, gated pairs, the attacker's
options), the primary's NIS, and the shortcut that spares building option 1.

A track's prediction, gains, gated detections and likelihoods depend only on the track
(its mean and covariance), and the states of a batch share most of their tracks; all of
that is computed once per distinct track (:func:`distinct_tracks`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from lesmc.scene import Scene
from lesmc.tracking.design import GainRows, Schedule
from lesmc.tracking.kalman import (
    Matrices,
    mahalanobis2,
    measure,
    positions,
    predict_means,
    update_means,
    warp,
)
from lesmc.tracking.parts.associator import GreedyAssociator
from lesmc.tracking.parts.attacker import hiding_options
from lesmc.tracking.parts.attacker_subsets import relevant_candidates
from lesmc.tracking.parts.deleter import DistanceDeleter, TraceDeleter
from lesmc.tracking.parts.groups import starts, within
from lesmc.tracking.parts.hypothesiser import GateHypothesiser
from lesmc.tracking.parts.initiator import NearTargetInitiator
from lesmc.tracking.parts.joint_digest import hash_tracks
from lesmc.tracking.parts.joint_states import (
    JointStates,
    digest,
    same_states,
    track_hashes,
    used_rows,
)


@dataclass(frozen=True)
class JointParts:
    """The parts the joint design is composed of (docs/trackers.md, "Parts"); its predictor
    and updater are lesmc/tracking/kalman.py's functions (in the design's Schedule), its
    attacker's options lesmc/tracking/parts/attacker.py's."""

    hypothesiser: GateHypothesiser  # gated (track, detection) pairs
    associator: GreedyAssociator  # ordered greedy by likelihood
    initiator: NearTargetInitiator  # births near the target
    deleter: TraceDeleter  # trace(P) > max_trace halts a track
    pruner: DistanceDeleter  # refining tracks far from the primary end


@dataclass
class Prepared:
    """What the options of a chunk of states share (see :func:`prepare`).

    Predictions, gains and the primary's nearest detections are kept per distinct
    track (``tu`` maps each state's track slots to them; padding maps to 0).
    """

    Z: np.ndarray  # (z, 2) the frame's detections
    X: np.ndarray  # (u, d) predicted distinct tracks
    g: GainRows  # (u,) their gains
    tu: np.ndarray  # (n, T) each state's tracks among the distinct ones
    live: np.ndarray  # (n, T) real tracks
    pend: np.ndarray  # (n, K, 2) pending detections, in this frame's coordinates
    npend: np.ndarray
    n_opt: np.ndarray  # (n,) the attacker's options
    cost: np.ndarray  # (n, w + 1) cost of option j: hiding the j nearest
    rank_of: np.ndarray  # (u, z) each detection's position among a primary's nearest
    ps: np.ndarray  # gated pairs (state, track, detection), grouped by state
    pt: np.ndarray
    pz: np.ndarray
    prio: np.ndarray  # each pair's place in its state's scan (smaller first), unique per state
    pu: np.ndarray  # each pair among the distinct (track, detection) pairs
    # every track a state's track can become: the u predicted ones (a skipped update),
    # then the distinct pairs' updated ones (Eq. 2); means, covariance indices, hashes, halts
    child_X: np.ndarray  # (u + distinct pairs, d)
    child_cov: np.ndarray
    child_h: np.ndarray  # (u + distinct pairs, 2)
    child_halt: np.ndarray
    near_z: np.ndarray  # (u, w) a primary's nearest detections (valid up to n_near)
    n_near: np.ndarray  # (u,)
    pos: tuple[int, int] = (0, 1)  # the measured components (Matrices.pos)

    def visible_rank(self, s: np.ndarray) -> np.ndarray:
        """(len(s), z): each detection's position among the nearest of state s's primary."""
        out: np.ndarray = self.rank_of[self.tu[s, 0]]
        return out


@dataclass
class Expanded:
    """Successors of one chunk of states (lesmc/tracking/joint.py, ``JointDesign._expand``)."""

    src: np.ndarray
    rank: np.ndarray
    payoff: np.ndarray
    det: np.ndarray
    halted: np.ndarray
    states: JointStates
    nis: np.ndarray  # the primary's NIS yᵀ S⁻¹ y where it updates, NaN where it skips
    #: at an attacked frame, the cheapest option kept for each outcome: how many of the
    #: detections nearest the primary it hides, and which subset of the frame's candidates
    #: it injects (its index into ``subsets``, candidate indices); None: unattacked
    opt: np.ndarray | None = None
    subset: np.ndarray | None = None
    subsets: list[tuple[int, ...]] | None = None
    #: the chunk's work: the (state, option) rows it evaluated before merging equal outcomes,
    #: times the tracks of a row (each row moves every track of its joint state)
    track_rows: int = 0


def prepare(
    scene: Scene,
    schedule: Schedule,
    parts: JointParts,
    pos: tuple[int, int],
    js: JointStates,
    step: int,
    inject: bool = False,
    hide: bool = True,
) -> Prepared:
    """What every option of the states ``js`` at frame ``step`` shares: predictions, gains,
    the primary's nearest detections and what hiding them costs (the attacker's options),
    the gated pairs with their priorities; once per distinct track (``inject``, ``hide``:
    :func:`measurements`)."""
    Z, pays = measurements(scene, step, inject, hide)
    nz = len(Z)
    T = js.width
    Hm = scene.frame(step - 1).to_next
    live = np.arange(T) < js.ntrack[:, None]
    tu, X, cu = distinct_tracks(js, live)
    m, X, g, gated = predict_and_gate(scene, schedule, parts.hypothesiser, X, cu, Z, step)
    pend = warp(Hm, js.pending) if Hm is not None else js.pending
    U = len(cu)
    track, pz, dx, dy, d2, ok = gated
    hiding = hiding_options(tu[:, 0], track, pz, dx, dy, ok, g.radius, pays, U, nz)
    (n_opt, cost, rank_of, near_z, per), (track, pz, d2) = hiding, (track[ok], pz[ok], d2[ok])
    del dx, dy, ok, hiding  # the candidates' arrays: only the gated pairs go on
    ranked = parts.associator.ranked_pairs(track, pz, d2, g.norm, tu, live, U, T, nz)
    ps, pt, pair_z, prio, idx = ranked
    X_up = update_means(m, X[track], g.K[track], Z[pz])
    child_cov = np.concatenate([g.pred, g.post[track]])
    child_X = np.concatenate([X, X_up])
    return Prepared(
        Z=Z,
        X=X,
        g=g,
        tu=tu,
        live=live,
        pend=pend,
        npend=js.npend,
        n_opt=n_opt,
        cost=cost,
        rank_of=rank_of,
        ps=ps,
        pt=pt,
        pz=pair_z,
        prio=prio,
        pu=idx,
        child_X=child_X,
        child_cov=child_cov,
        child_h=hash_tracks(child_X, child_cov),
        child_halt=np.concatenate([g.halt_pred, g.halt_post[track]]),
        near_z=near_z,
        n_near=per,
        pos=pos,
    )


def predict_and_gate(
    scene: Scene,
    schedule: Schedule,
    hypothesiser: GateHypothesiser,
    X: np.ndarray,
    cu: np.ndarray,
    Z: np.ndarray,
    step: int,
) -> tuple[Matrices, np.ndarray, GainRows, tuple[np.ndarray, ...]]:
    """Tracks of means ``X`` (u, d; overwritten) and covariance indices ``cu`` (u,) moved
    into frame ``step``: warped by the camera's motion, predicted, their gains, and the
    pairs (track, measurement of ``Z``) the gate admits (``hypothesiser.pairs``). Used by
    :func:`prepare` and by the relaxation to the primary (relaxed.py)."""
    m, gains = schedule.at(step)
    Hm = scene.frame(step - 1).to_next
    if Hm is not None:
        X[:, list(m.pos)] = warp(Hm, positions(m, X))
    X = predict_means(m, X)
    g = gains.rows(cu)
    return m, X, g, hypothesiser.pairs(Z, measure(m, X), g.radius, g.S_inv, g.spread)


def candidate_relevance(p: Prepared, initiator: NearTargetInitiator, nd: int) -> np.ndarray:
    """(n, m) which of the frame's m injection candidates (measurements nd.. of ``p.Z``)
    can change each state's successor (the attacker's rule: attacker_subsets.py
    ``relevant_candidates``): gated by one of its tracks, or in the initiator's birth
    region around a position its primary can take. Depends on the primary track only for
    the births, so those are computed once per distinct primary."""
    n, m = len(p.tu), len(p.Z) - nd
    u0, first, inv = np.unique(p.tu[:, 0], return_index=True, return_inverse=True)
    inv = inv.reshape(-1)
    mine = np.flatnonzero((p.pt == 0) & (first[inv[p.ps]] == p.ps))  # the first states' pairs
    owner = np.concatenate([np.arange(u0.size), inv[p.ps[mine]]])
    child = np.concatenate([u0, len(p.X) + p.pu[mine]])  # predicted; updated by each pair
    centres = p.child_X[child][:, list(p.pos)]
    births = initiator.in_region(p.Z[nd:], centres)
    per_u = np.zeros((u0.size, m), dtype=bool)
    hit_c, hit_j = np.nonzero(births)
    per_u[owner[hit_c], hit_j] = True
    return relevant_candidates(n, nd, (p.ps, p.pz), (np.arange(n), inv), per_u)


def with_subsets(p: Prepared, state: np.ndarray, shown: np.ndarray) -> Prepared:
    """``p`` for virtual states: row v is state ``state[v]`` seeing only the measurements
    ``shown[v]`` (the frame's detections and one subset of its injection candidates), its
    gated pairs those of its state whose measurement it sees (in the same order)."""
    cnt = np.bincount(p.ps, minlength=len(p.tu))
    reps = cnt[state]
    idx = np.repeat(starts(cnt)[state], reps) + within(reps)
    vs = np.repeat(np.arange(len(state)), reps)
    keep = shown[vs, p.pz[idx]]
    idx, vs = idx[keep], vs[keep]
    return dataclasses.replace(
        p,
        tu=p.tu[state],
        live=p.live[state],
        pend=p.pend[state],
        npend=p.npend[state],
        n_opt=p.n_opt[state],
        cost=p.cost[state],
        ps=vs,
        pt=p.pt[idx],
        pz=p.pz[idx],
        prio=p.prio[idx],
        pu=p.pu[idx],
    )


def measurements(
    scene: Scene, step: int, inject: bool, hide: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Frame ``step``'s measurements (z, 2) and what hiding each detection costs (n,):
    under ``inject`` its injection candidates follow its detections (candidate j is
    measurement n + j; what an option shows of them is the caller's choice, and they are
    never hidden); ``hide`` False: no detection can be hidden (``allow inject`` alone)."""
    frame = scene.frame(step)
    Z = frame.positions()
    pays = frame.payoffs() if hide else np.full(len(Z), np.inf)
    if inject:
        Z = np.vstack([Z, frame.injectable.positions()])
    return Z, pays


def distinct_tracks(js: JointStates, live: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The distinct tracks (mean bits and covariance index) among the live ones of ``js``:
    each slot's index among them (n, T; padding 0), their means (u, d) and covariance
    indices (u,).

    Only "each slot's track is its row" matters to the caller: every row's
    results are a function of the track alone, so neither the order of the rows
    nor a duplicate row (possible when the states carry ids of a shared
    :class:`TrackTable`) changes them. Without ids, tracks are told apart by
    their hash, checked bit for bit.
    """
    ls, lt = np.nonzero(live)
    if js.tid is not None and js.table is not None:  # ids of a shared table: keep those used
        ids = js.tid[ls, lt]
        rows, at = used_rows(len(js.table.X), ids)
        tu = np.zeros(live.shape, dtype=np.int64)
        tu[ls, lt] = at[ids]
        return tu, js.table.X[rows], js.table.cov[rows]
    h = track_hashes(js)[ls, lt, 0]
    _, first, inv = np.unique(h, return_index=True, return_inverse=True)
    x = np.ascontiguousarray(js.tracks[ls, lt]).view(np.uint64)
    c = js.tcov[ls, lt]
    rep = first[inv.reshape(-1)]
    if not (np.array_equal(x, x[rep]) and np.array_equal(c, c[rep])):  # a 64-bit collision
        t = np.concatenate([x, c[:, None].astype(np.uint64)], axis=1)
        _, first, inv = np.unique(t, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")  # first appearance
    rename = np.empty_like(order)
    rename[order] = np.arange(order.size)
    first = first[order]
    tu = np.zeros(live.shape, dtype=np.int64)
    tu[ls, lt] = rename[inv.reshape(-1)]
    return tu, js.tracks[ls[first], lt[first]].copy(), js.tcov[ls[first], lt[first]]


def primary_nis(p: Prepared, s: np.ndarray, det: np.ndarray) -> np.ndarray:
    """The NIS yᵀ S⁻¹ y of the primary's update in each outcome (state ``s``, detection
    ``det`` of the frame, −1: it skips the update, NaN)."""
    out = np.full(len(s), np.nan)
    upd = det >= 0
    if upd.any():
        u = p.tu[s[upd], 0]
        y = p.Z[det[upd]] - p.X[u][:, list(p.pos)]
        out[upd] = mahalanobis2(y, p.g.S_inv[u])
    return out


def option_one_differs(p: Prepared, primary: np.ndarray) -> np.ndarray:
    """States whose option 1 surely leads elsewhere than option 0, without building it.

    When option 0's primary updates with the nearest detection, hiding it
    leaves the primary either skipping (its P differs) or updating with another
    detection within its gate; if every such detection lies at least δ away
    and K's position block (nonsingular) moves the estimate by at least
    σ_min(K)·δ, far above rounding, the primary's estimate differs.
    """
    n, w = len(primary), p.near_z.shape[1]
    u0 = p.tu[:, 0]
    if not w:
        return np.zeros(n, dtype=bool)
    ok: np.ndarray = (p.n_opt > 1) & (p.n_near[u0] > 0)
    ok[ok] = primary[ok] == p.near_z[u0[ok], 0]
    if not ok.any():
        return ok
    u = np.unique(u0[ok])  # what follows depends on the primary track only
    z0 = p.Z[p.near_z[u, 0]]
    dz = p.Z[p.near_z[u]] - z0[:, None]
    gap = np.where(np.arange(w) < p.n_near[u, None], np.hypot(dz[..., 0], dz[..., 1]), np.inf)
    delta = gap[:, 1:].min(axis=1, initial=np.inf)
    K = p.g.K[u][:, list(p.pos), :]  # (u, 2, 2): how the position moves with the innovation
    sigma_min = np.sqrt(np.maximum(np.linalg.eigvalsh(np.swapaxes(K, 1, 2) @ K)[:, 0], 0.0))
    at = p.X[u][:, list(p.pos)]
    scale = 1.0 + np.abs(at).max(axis=1) + np.abs(dz).max(axis=(1, 2), initial=0.0)
    moves = np.zeros(len(p.X), dtype=bool)
    moves[u] = sigma_min * delta > 1e-6 * scale
    out: np.ndarray = ok & moves[u0]
    return out


def first_of_equals(states: JointStates, s: np.ndarray) -> np.ndarray:
    """Which rows (outcomes, from sources ``s``) come first among their source's identical
    outcomes (the rows in cost order: the cheapest); sets ``states.key``."""
    states.key = key = digest(states)
    o = np.lexsort((np.arange(len(s)), key[:, 1], key[:, 0], s))
    ks, k0, k1 = s[o], key[o, 0], key[o, 1]
    head = np.r_[True, (ks[1:] != ks[:-1]) | (k0[1:] != k0[:-1]) | (k1[1:] != k1[:-1])]
    rep = np.empty(len(s), dtype=np.int64)
    rep[o] = o[np.maximum.accumulate(np.where(head, np.arange(len(s)), 0))]
    if not same_states(states, rep):  # two different outcomes share a 128-bit digest
        raise AssertionError("joint state digest collision")
    kept = np.zeros(len(s), dtype=bool)
    kept[o[head]] = True
    return kept


def track_table(
    p: Prepared, m: Matrices, p0: int, mz: np.ndarray, v: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Means, covariance indices and hashes of the children, a padding row, then new tracks.

    A new track starts at position ``mz`` with velocity ``v`` and covariance ``p0`` (its
    index in the design's covariance table).
    """
    new_X = np.zeros((mz.shape[0], m.dim))
    new_X[:, list(m.pos)] = mz
    if m.vel is not None:
        new_X[:, list(m.vel)] = v
    new_cov = np.full(mz.shape[0], p0, dtype=np.int64)
    table_X = np.concatenate([p.child_X, np.zeros((1, m.dim)), new_X])
    table_cov = np.concatenate([p.child_cov, np.zeros(1, dtype=np.int64), new_cov])
    table_h = np.concatenate(
        [p.child_h, np.zeros((1, 2), dtype=np.uint64), hash_tracks(new_X, new_cov)]
    )
    return table_X, table_cov, table_h
