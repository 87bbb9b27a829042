"""The designed (not yet reachable) pieces of the multi-target model: the packed state of
lesmc/tracking/parts/states.py and the ``switches`` contributions of lesmc/model/identity.py."""

from __future__ import annotations

import numpy as np

from lesmc.model.identity import switches
from lesmc.tracking.design import CovarianceTable
from lesmc.tracking.multi import MultiState, sort_tracker
from lesmc.tracking.parts.states import MultiBatch


def _by_definition(ids: list[int | None], lo: int, hi: int) -> int:
    """Steps k in lo..hi where the target's track exists and its id differs from the id at
    the last earlier step at which it existed."""
    n = 0
    for k in range(lo, min(hi, len(ids) - 1) + 1):
        earlier = [i for i in ids[:k] if i is not None]
        if ids[k] is not None and earlier and ids[k] != earlier[-1]:
            n += 1
    return n


def test_switches_summed_per_transition_is_the_definition() -> None:
    rng = np.random.default_rng(3)
    seen = 0
    for _ in range(2000):
        n = int(rng.integers(0, 12))
        ids = [None if rng.random() < 0.3 else int(rng.integers(1, 4)) for _ in range(n)]
        lo = int(rng.integers(0, 12))
        hi = int(rng.integers(lo, 13))
        want = _by_definition(ids, lo, hi)
        assert switches(ids, lo, hi) == want, (ids, lo, hi)
        seen += want > 0
    assert seen > 300


def _states(rng: np.random.Generator) -> list[tuple[MultiState, int]]:
    tracker = sort_tracker()
    state = tracker.initial()
    out = []
    for _ in range(int(rng.integers(1, 12))):
        k = int(rng.integers(0, 5))
        c = rng.uniform(0, 100, (k, 2))
        s = rng.uniform(5, 30, (k, 2))
        state, _ = tracker.step(state, np.concatenate([c - s / 2, c + s / 2], axis=1))
        out.append((state, int(rng.integers(-1, 4))))
    return out


def test_packed_states_round_trip_and_their_words_tell_them_apart() -> None:
    rng = np.random.default_rng(11)
    for _ in range(50):
        got = _states(rng)
        table = CovarianceTable()
        rows = [(s.tracks, s.next_id, s.frames, last) for s, last in got]
        b = MultiBatch.pack(rows, 7, table)
        for i, (s, last) in enumerate(got):
            t = b.tracks(i, table)
            for name in ("X", "P", "id", "hits", "streak", "age", "since"):
                assert np.array_equal(getattr(t, name), getattr(s.tracks, name)), name
            assert (b.next_id[i], b.frames[i], b.last[i]) == (s.next_id, s.frames, last)
        width = int(b.count.max(initial=0)) + 2
        w = b.words(width)
        # the same states packed again, in reverse order, in another batch: the same words
        again = MultiBatch.pack(rows[::-1], 7, table).words(width)[::-1]
        assert np.array_equal(w, again)
        # distinct states (frames differ along a run) have distinct words
        assert len({r.tobytes() for r in w}) == len(rows)
        # one bit of one mean, or the target's last id, makes another state
        k = int(np.argmax(b.count))
        if b.count[k]:
            X = b.X.copy()
            X[k, 0, 0] = np.nextafter(X[k, 0, 0], np.inf)
            moved = MultiBatch(
                X,
                *(
                    getattr(b, f)
                    for f in ("cov", "id", "counts", "count", "next_id", "frames", "last")
                ),
            )
            assert not np.array_equal(moved.words(width)[k], w[k])
        other = b.take(np.array([k]))
        other = MultiBatch(
            *(
                getattr(other, f)
                for f in ("X", "cov", "id", "counts", "count", "next_id", "frames")
            ),
            other.last + 1,
        )
        assert not np.array_equal(other.words(width)[0], w[k])
