"""The attacker's options: what an attacker who hides detections can make a tracker do, and
at what cost (paper section 4, Eq. 5). One part that every tracker uses: the threat model is
written here and nowhere else (docs/trackers.md, "Parts").

The threat model. At an attacked step the attacker hides detections of the frame, each at
its payoff (the cost of flipping the detector there); a detection with an infinite payoff
(unattackable) cannot be hidden. Hidden detections are gone for every track.

Point trackers gated on one track (``single``; ``joint``, on its primary track). The
attacker hides the detections nearest the track's prediction, nearest first (ties: the
lower index): option j hides the j nearest and costs the sum of their payoffs. No option
hides past the first unattackable candidate (:func:`first_unattackable`), and none past the
last candidate the gate admits (hiding more changes nothing). Two views of these options:

* :func:`attack_option_rows` (and :func:`attack_options`, one row of it), for a tracker
  whose outcome is the nearest visible candidate (``single``): the distinct outcomes in
  rank order, each with its own payoff, so that Eq. 5's combined payoff (the sum of the own
  payoffs of the lower ranks) is the cost of forcing the outcome.
  ``attack_option_rows(gated (g, k) bool, payoffs (g, k) float, valid (g, k) bool,
  same (g, k) int | None) -> OptionRows(row, col, payoff)``.
* :func:`hiding_options`, for a tracker that builds each option's whole state and merges
  equal ones (``joint``): how many options each track has and what each costs
  (:func:`option_costs`), and which detections an option leaves visible
  (:func:`visible`); :func:`ranks_and_payoffs` turns the costs of the merged outcomes
  into ranks and own payoffs (Eq. 5).
  ``hiding_options(u0, track, pz, dx, dy, ok, radius, payoffs, U, nz) -> (n_opt, cost,
  rank_of, near_z, per)``; ``option_costs(pays (U, w), n_opt (U,)) -> cost (U, w + 1)``;
  ``visible(rank (R, z), opt (R,)) -> (R, z) bool``;
  ``ranks_and_payoffs(src (n,), cost (n,)) -> (rank, own payoff)``.

Multi-target trackers (``sort``, ``gnn``): any subset of the frame's attackable
detections and, under ``allow hide, inject``, of its injection candidates, at the sum of
their payoffs. That view of the same threat model lives beside this module, in
lesmc/tracking/parts/attacker_subsets.py (the two modules are one part).

``single`` under ``allow hide, inject``: :func:`injection_option_rows` (``(gated, payoffs,
valid, injected, key)``, each (g, k), detections and candidates merged nearest first ->
OptionRows``): the distinct outcomes, each at its cheapest cost, ranked by cost, and
(``OptionRows.via``) the column whose way is the cheapest. ``joint`` under inject: each of
:func:`hiding_options`' options (which never hide the injected measurements, those past
its ``payoffs``) with every subset of the candidates that can change the state's
successor (attacker_subsets.py ``relevant_candidates``), merged and
ranked by cost with :func:`ranks_and_payoffs` (lesmc/tracking/joint.py).
:func:`forcing_update` says which detections and candidates that cheapest way hides and
injects to make the tracker update with a given measurement (a replay applies them).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lesmc.tracking.parts.groups import within


def first_unattackable(payoffs: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Per row of candidates (nearest first), the column of the first real (``valid``)
    candidate the attacker cannot hide (payoff not finite); the row's width if none. The
    attacker reaches no candidate beyond it."""
    k = int(payoffs.shape[1])
    if not k:
        return np.zeros(payoffs.shape[0], dtype=np.int64)
    bad = valid & ~np.isfinite(payoffs)
    out: np.ndarray = np.where(bad.any(axis=1), bad.argmax(axis=1), k)
    return out


@dataclass(frozen=True)
class Option:
    """One outcome the attacker can force: update with ``detection`` (index) or skip (None).

    ``payoff`` is the transition's own payoff in the LTS; the combined payoff of
    the option at rank r is the sum of the payoffs of the options before it.
    """

    detection: int | None
    payoff: float


def attack_options(dist: np.ndarray, gated: np.ndarray, payoffs: np.ndarray) -> list[Option]:
    """The outcomes, nearest first, for detections at distances ``dist`` from the prediction.

    One row of :func:`attack_option_rows` (ties in distance go to the lower index).
    """
    order = np.argsort(dist, kind="stable")
    rows = attack_option_rows(
        np.asarray(gated, bool)[order][None, :],
        np.asarray(payoffs, float)[order][None, :],
        np.ones((1, len(order)), dtype=bool),
    )
    return [
        Option(None if c < 0 else int(order[c]), float(p))
        for c, p in zip(rows.col.tolist(), rows.payoff.tolist(), strict=True)
    ]


@dataclass(frozen=True)
class OptionRows:
    """The options of many rows, flattened in (row, rank) order.

    ``col`` is the candidate column the option updates with, −1 for the skip.
    """

    row: np.ndarray
    col: np.ndarray
    payoff: np.ndarray
    #: under inject (:func:`injection_option_rows`): the column whose way the outcome is
    #: forced at its least cost (hide every detection before it, inject it if a
    #: candidate; the row's width: hide every detection); None otherwise
    via: np.ndarray | None = None


def attack_option_rows(
    gated: np.ndarray, payoffs: np.ndarray, valid: np.ndarray, same: np.ndarray | None = None
) -> OptionRows:
    """The attacker's options for many predictions at once (g rows of k candidates).

    Each row lists its candidate detections nearest first (``valid`` marks real
    ones). Scanning a row: a gated candidate is an update outcome (reached by
    hiding every nearer one); the first non-gated one is the skip outcome (the
    nearest visible detection fails the gate). Later non-gated candidates lead
    to the same skip, so their payoffs fold into the previous outcome's own
    payoff, which keeps every later combined payoff (Eq. 5) exact. An
    unattackable candidate (payoff ∞) ends the row: nothing beyond it can be
    reached, and the last outcome's own payoff, never part of a combined
    payoff, is 0. Hiding everything skips (own payoff 0).

    ``same`` (g, k), optional, identifies candidates at identical positions: a
    gated one that repeats an earlier outcome's detection leads to the same
    state and is dropped, its own payoff added to the outcome before it (so
    later combined payoffs do not change).

    Payoffs are accumulated column by column, left to right, so every own
    payoff is summed in the order of the scan whatever the batch.
    """
    k = int(gated.shape[1])
    cols = np.arange(k)
    stop = first_unattackable(payoffs, valid)
    included = valid & (cols <= stop[:, None])
    broke = stop < k
    nongated = included & ~gated
    first_ng = nongated & (np.cumsum(nongated, axis=1) == 1)
    update = included & gated
    produce = update | first_ng
    own = np.where(produce, payoffs, 0.0)
    prev = np.maximum.accumulate(np.where(produce, cols, -1), axis=1)
    fold = included & ~produce
    for j in np.nonzero(fold.any(axis=0))[0]:
        r = np.nonzero(fold[:, j])[0]
        own[r, prev[r, j]] += payoffs[r, j]
    # a row that broke off at an unattackable candidate: its last outcome costs nothing
    last = np.where(produce, cols, -1).max(axis=1, initial=-1)
    rb = np.nonzero(broke)[0]
    own[rb, last[rb]] = 0.0
    if same is not None:
        produce = _drop_repeats(update, produce, own, same)
    return _collect(produce, first_ng, broke, own)


def _drop_repeats(
    update: np.ndarray, produce: np.ndarray, own: np.ndarray, same: np.ndarray
) -> np.ndarray:
    """``produce`` without the gated candidates that repeat an earlier outcome's detection.

    Each dropped candidate's own payoff is added (in place, to ``own``) to the
    outcome before it in its row, so later combined payoffs do not change.
    """
    k = int(update.shape[1])
    cols = np.arange(k)
    dup = np.zeros_like(update)
    for c in range(1, k):
        earlier = update[:, :c] & (same[:, :c] == same[:, c : c + 1])
        dup[:, c] = update[:, c] & earlier.any(axis=1)
    if not dup.any():
        return produce
    for j in np.nonzero(dup.any(axis=0))[0]:
        keep = produce & ~dup
        keep[:, j:] = False
        before = np.where(keep, cols, -1).max(axis=1, initial=-1)
        r = np.nonzero(dup[:, j])[0]
        own[r, before[r]] += own[r, j]
    kept: np.ndarray = produce & ~dup
    return kept


def _collect(
    produce: np.ndarray, first_ng: np.ndarray, broke: np.ndarray, own: np.ndarray
) -> OptionRows:
    """The outcomes as flat rows, in (row, column) order, each row's skip last (column k)."""
    k = int(produce.shape[1])
    r_idx, c_idx = np.nonzero(produce)
    trailing = np.nonzero(~broke & ~first_ng.any(axis=1))[0]
    row = np.concatenate([r_idx, trailing])
    col = np.concatenate([c_idx, np.full(trailing.size, k)])
    order = np.lexsort((col, row))
    row, col = row[order], col[order]
    is_skip = col == k
    skip_col = np.zeros(col.size, dtype=bool)
    skip_col[~is_skip] = first_ng[row[~is_skip], col[~is_skip]]
    pay = np.zeros(col.size)
    pay[~is_skip] = own[row[~is_skip], col[~is_skip]]
    out_col = np.where(is_skip | skip_col, -1, col)
    return OptionRows(row, out_col, pay)


# ---------------------------------------- the nearest-neighbour tracker under inject (single)


def injection_option_rows(
    gated: np.ndarray,
    payoffs: np.ndarray,
    valid: np.ndarray,
    injected: np.ndarray,
    key: np.ndarray,
) -> OptionRows:
    """The attacker's options under ``allow hide, inject`` for many predictions at once
    (g rows of k columns): each row lists the frame's detections and injection candidates
    together, nearest first (``valid`` marks real ones, ``injected`` the candidates;
    at equal distance a detection comes first), ``payoffs`` the price of hiding a
    detection or of injecting a candidate, ``gated`` whether the gate admits it, ``key``
    its position's id (equal ids: the same updated state).

    The tracker updates with the nearest visible column if the gate admits it, else
    skips. Column c is the nearest visible at the least cost by hiding every detection
    before it and injecting no candidate before it (and, if c is a candidate, injecting
    it): cost = the payoffs of the detections before c (+ c's own if injected);
    unreachable past an unattackable detection. Hiding every detection of the row and
    injecting nothing skips. Each distinct outcome (update at a position; skip) keeps its
    cheapest cost. A cheap candidate far out may cost less than hiding one near
    detection, so the outcomes are ranked by cost (ties: the unattacked one, rank 0,
    first, then by column), their own payoffs the differences of consecutive costs
    (:func:`ranks_and_payoffs`): Eq. 5's combined payoff of a rank is then the cheapest
    cost of forcing its outcome (docs/semantics.md, "Injection on the nearest-neighbour
    tracker"). Returns the options in (row, rank) order; ``col`` −1 is the skip.
    """
    g, k = gated.shape
    det = valid & ~injected
    prefix = np.zeros((g, k + 1))
    prefix[:, 1:] = np.cumsum(np.where(det, payoffs, 0.0), axis=1)  # nearest first
    cost = prefix[:, :k] + np.where(injected & valid, payoffs, 0.0)
    ok = valid & np.isfinite(cost)
    first = det.argmax(axis=1) if k else np.zeros(g, dtype=np.int64)
    first_det = np.where(det.any(axis=1), first, k)  # the unattacked choice
    r, c = np.nonzero(ok)
    row = np.concatenate([r, np.arange(g)])
    col = np.concatenate([c, np.full(g, k)])  # column k: every detection hidden
    outcome = np.concatenate([np.where(gated[r, c], key[r, c], -1), np.full(g, -1)])
    price = np.concatenate([cost[r, c], prefix[:, k]])
    unatt = col == first_det[row]
    keep = np.isfinite(price)
    row, col, outcome, price, unatt = row[keep], col[keep], outcome[keep], price[keep], unatt[keep]
    # the cheapest way to each (row, outcome): the unattacked column first among equal costs
    order = np.lexsort((col, ~unatt, price, outcome, row))
    row, col, outcome, price, unatt = (a[order] for a in (row, col, outcome, price, unatt))
    head = np.r_[True, (row[1:] != row[:-1]) | (outcome[1:] != outcome[:-1])]
    row, col, outcome, price, unatt = (a[head] for a in (row, col, outcome, price, unatt))
    # rank order: by cost, the unattacked outcome first, then by column
    order = np.lexsort((col, ~unatt, price, row))
    row, col, outcome, price = row[order], col[order], outcome[order], price[order]
    _, payoff = ranks_and_payoffs(row, price)
    return OptionRows(row, np.where(outcome < 0, -1, col), payoff, col)


def forcing_update(
    det_dist: np.ndarray, cand_dist: np.ndarray, taken: int, candidate: bool
) -> tuple[np.ndarray, np.ndarray]:
    """The cheapest way (:func:`injection_option_rows`) to make ``single`` update with one
    measurement: detection ``taken`` (``candidate`` False) or injection candidate ``taken``,
    at distances ``det_dist`` (the frame's detections) and ``cand_dist`` (its candidates)
    from the prediction. Every detection before it in the merged order (nearest first;
    ties: a detection before a candidate, then the lower index) is hidden; no candidate
    before it is injected; a candidate is itself injected. Returns (detections hidden,
    candidates injected), as indices."""
    if candidate:
        d = cand_dist[taken]
        hidden = np.flatnonzero(det_dist <= d)  # at equal distance a detection comes first
        return hidden, np.array([taken], dtype=np.int64)
    d = det_dist[taken]
    order = np.arange(len(det_dist))
    hidden = np.flatnonzero((det_dist < d) | ((det_dist == d) & (order < taken)))
    return hidden, np.zeros(0, dtype=np.int64)


# ---------------------------------------- trackers that build each option (joint)


def hiding_options(
    u0: np.ndarray,
    track: np.ndarray,
    pz: np.ndarray,
    dx: np.ndarray,
    dy: np.ndarray,
    ok: np.ndarray,
    radius: np.ndarray,
    payoffs: np.ndarray,
    U: int,
    nz: int,
) -> tuple[np.ndarray, ...]:
    """The attacker's options: hide the j detections nearest the primary's prediction (the
    primary tracks' candidates within its radius, by distance, then index). Per primary
    track: how many options, their costs (cost[j]: hiding the j nearest, Eq. 5 summed
    nearest first); per distinct track: each detection's position among its nearest
    (nz: far), the nearest detections and how many there are.

    ``u0`` (n,): each state's primary among the U distinct tracks; the candidate pairs
    (hypothesiser ``pairs``): ``track``, detection ``pz``, offsets ``dx``, ``dy`` from the
    track's predicted position, ``ok`` whether the gate admits the pair; ``radius`` (U,)
    the tracks' gate radii; ``payoffs`` (n,) the frame's detections' payoffs (detections
    from n on, up to nz, are injected candidates: never hidden, never among the nearest;
    ``allow hide, inject`` on ``joint``, docs/semantics.md). Returns
    ``n_opt`` (n,), ``cost`` (n, w + 1), ``rank_of`` (U, nz), ``near_z`` (U, w) and
    ``per`` (U,)."""
    primary = np.zeros(U, dtype=bool)
    primary[u0] = True
    c0 = np.flatnonzero(primary[track] & (pz < len(payoffs)))  # injected ones: not hidden
    dist = np.sqrt(dx[c0] ** 2 + dy[c0] ** 2)
    inside = dist <= radius[track[c0]]
    c0, dist = c0[inside], dist[inside]
    s0 = track[c0]
    per = np.bincount(s0, minlength=U)
    w = int(per.max(initial=0))
    at = within(per)
    D = np.full((U, w), np.inf)
    D[s0, at] = dist
    by_d = np.argsort(D, axis=1, kind="stable")
    inv = np.empty((U, w), dtype=np.int64)
    np.put_along_axis(inv, by_d, np.broadcast_to(np.arange(w), (U, w)), axis=1)
    col = inv[s0, at]  # each near candidate's position among its track's nearest
    near_z = np.zeros((U, w), dtype=np.int64)
    near_z[s0, col] = pz[c0]
    gated = np.zeros((U, w), dtype=bool)
    gated[s0, col] = ok[c0]
    cols = np.arange(w)
    last = np.where(gated, cols + 1, 0).max(axis=1, initial=0)
    pays = np.zeros((U, w))  # the candidates' payoffs (0 past a track's candidates: unused)
    if nz:
        pays[s0, col] = payoffs[pz[c0]]
    n_opt = np.minimum(last, first_unattackable(pays, np.ones((U, w), dtype=bool))) + 1
    cost = option_costs(pays, n_opt)
    rank_of = np.full((U, nz), nz, dtype=np.int64)
    rank_of[s0, pz[c0]] = col
    return n_opt[u0], cost[u0], rank_of, near_z, per


def option_costs(pays: np.ndarray, n_opt: np.ndarray) -> np.ndarray:
    """(U, w + 1) the cost of option j of each row: hiding its j nearest candidates (payoffs
    ``pays`` (U, w), nearest first), summed nearest first; 0 for options past ``n_opt``'s
    (their hidden candidates' payoffs are left out)."""
    U, w = pays.shape
    cols = np.arange(w)
    cost = np.zeros((U, w + 1))
    cost[:, 1:] = np.cumsum(np.where(cols < n_opt[:, None] - 1, pays, 0.0), axis=1)
    return cost


def visible(rank: np.ndarray, opt: np.ndarray) -> np.ndarray:
    """Which detections option ``opt[i]`` leaves visible, from each detection's place
    ``rank`` (R, z) among row i's nearest (option j hides the j nearest)."""
    out: np.ndarray = rank >= opt[:, None]
    return out


def ranks_and_payoffs(src: np.ndarray, cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ranks of outcomes grouped by source (cheapest first, costs ``cost``) and their own
    payoffs: the next outcome's cost minus this one's, 0 for the last, so that the
    combined payoff of Eq. 5 (the sum over lower ranks) is each outcome's cost."""
    head = np.r_[True, src[1:] != src[:-1]] if src.size else np.zeros(0, dtype=bool)
    rank = within(np.diff(np.r_[np.nonzero(head)[0], src.size]))
    last = np.r_[head[1:], True] if src.size else head
    payoff = np.where(last, 0.0, np.r_[cost[1:], 0.0] - cost)
    return rank.astype(np.int64), payoff


# ---------------------------------------- multi-target trackers: any subset
