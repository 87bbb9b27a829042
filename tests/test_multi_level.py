"""The multi-target unfolder's level-wide pieces against independent computations
(issue 62): SORT's assignment shortcut decided for many (track set, detections kept) pairs
at once (``GlobalAssociator.by_shortcut``) against the reference SORT's own
``associate_detections_to_trackers`` on each pair, and the exact merging of equal rows
(``distinct_rows``) against a dictionary of tuples."""

from __future__ import annotations

import numpy as np
import pytest

from lesmc.tracking.parts.associator import GlobalAssociator
from lesmc.tracking.parts.states import distinct_rows


def _boxes(rng: np.random.Generator, n: int) -> np.ndarray:
    """n boxes crowded into a small area, so that many pairs overlap."""
    xy = rng.uniform(0, 60, (n, 2))
    wh = rng.uniform(15, 40, (n, 2))
    return np.hstack([xy, xy + wh])


@pytest.mark.parametrize("seed", range(40))
def test_the_shortcut_decides_as_the_reference_sort(seed: int) -> None:
    """Where ``by_shortcut`` says SORT's shortcut decides (or there is nothing to pair),
    its pairs and the order of the unmatched detections are the reference SORT's; and it
    says so exactly where the reference takes that branch. Track sets of 0 to 4 tracks,
    empty ones anywhere (the last included); 0 to 6 detections; random subsets kept."""
    sort = pytest.importorskip("sort_tracker.sort")
    rng = np.random.default_rng(7100 + seed)
    thr = float(rng.choice([0.1, 0.3, 0.5]))
    widths = rng.integers(0, 5, rng.integers(1, 6))
    if seed % 3 == 0:
        widths[-1] = 0
    groups = np.concatenate([[0], np.cumsum(widths)]).astype(np.int64)
    tracks = _boxes(rng, int(groups[-1]))
    n = int(rng.integers(0, 7))
    dets = _boxes(rng, n)
    keeps = [np.flatnonzero(rng.random(n) < 0.6) for _ in range(6)] + [np.arange(n)]
    km = np.zeros((len(keeps), n), dtype=bool)
    for j, k in enumerate(keeps):
        km[j, k] = True
    score = sort.iou_batch(dets, tracks).reshape(n, len(tracks))
    ok, partner = GlobalAssociator.by_shortcut(score > thr, groups, km)
    for g in range(len(widths)):
        mine = tracks[groups[g] : groups[g + 1]]
        for j, keep in enumerate(keeps):
            sub = score[keep][:, groups[g] : groups[g + 1]]
            a = (sub > thr).astype(int)
            shortcut = min(sub.shape) == 0 or (a.sum(1).max() == 1 and a.sum(0).max() == 1)
            assert ok[g, j] == shortcut
            if not shortcut:
                continue
            matches, unmatched, _ = sort.associate_detections_to_trackers(dets[keep], mine, thr)
            p = partner[g, keep]
            want = {(int(d), int(t)) for d, t in matches}
            got = {(d, int(p[d] - groups[g])) for d in np.flatnonzero(p >= 0)}
            assert got == want
            assert np.flatnonzero(p < 0).tolist() == [int(x) for x in unmatched]


def test_distinct_rows_number_classes_in_order_of_first_sight() -> None:
    """Each row's class, numbered in order of first sight, and each class's first row, as a
    dictionary keyed by the rows' values gives them (bit patterns: −0.0 and 0.0 differ)."""
    rng = np.random.default_rng(5)
    pool = np.array([[0.0, 1.0], [-0.0, 1.0], [2.5, np.nan], [1.0, 0.0]])
    rows = pool[rng.integers(0, len(pool), 50)]
    rank, first = distinct_rows(rows.view(np.uint64))
    seen: dict[tuple[int, ...], int] = {}
    want = [seen.setdefault(tuple(r.view(np.uint64)), len(seen)) for r in rows]
    assert rank.tolist() == want
    assert first.tolist() == [want.index(c) for c in range(len(seen))]
