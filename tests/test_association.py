"""The batched attacker's options against a scalar oracle: the scan of docs/tracking.md."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from lesmc.tracking.parts.attacker import attack_option_rows


def scan(gated: list[bool], pay: list[float], same: list[int]) -> list[tuple[int, float]]:
    """One row, candidates nearest first: (column or −1 for the skip, own payoff)."""
    opts: list[tuple[int, float]] = []
    skip_seen = False
    broke = False
    for c, (g, p) in enumerate(zip(gated, pay, strict=True)):
        if g:
            opts.append((c, p))
        elif not skip_seen:
            opts.append((-1, p))
            skip_seen = True
        else:
            opts[-1] = (opts[-1][0], opts[-1][1] + p)
        if not math.isfinite(p):
            broke = True
            break
    if not broke and not skip_seen:
        opts.append((-1, 0.0))
    if opts and not math.isfinite(opts[-1][1]):
        opts[-1] = (opts[-1][0], 0.0)
    # outcomes reaching the same state (same detection position) merge into the one before
    out: list[tuple[int, float]] = []
    seen: set[int] = set()
    for c, p in opts:
        key = -1 if c < 0 else same[c]
        if c >= 0 and key in seen:
            out[-1] = (out[-1][0], out[-1][1] + p)
            continue
        if c >= 0:
            seen.add(key)
        out.append((c, p))
    return out


row = st.integers(0, 7).flatmap(
    lambda k: st.tuples(
        st.lists(st.booleans(), min_size=k, max_size=k),
        st.lists(
            st.one_of(st.floats(0, 5, allow_nan=False), st.just(math.inf)), min_size=k, max_size=k
        ),
        st.lists(st.integers(0, 3), min_size=k, max_size=k),
    )
)


@settings(max_examples=300, deadline=None)
@given(rows=st.lists(row, min_size=1, max_size=6))
def test_batched_options_equal_the_scan(rows) -> None:  # type: ignore[no-untyped-def]
    k = max(len(r[0]) for r in rows)
    g = np.zeros((len(rows), k), bool)
    p = np.zeros((len(rows), k))
    same = np.zeros((len(rows), k), np.int64)
    valid = np.zeros((len(rows), k), bool)
    for i, (gr, pr, sr) in enumerate(rows):
        n = len(gr)
        g[i, :n], p[i, :n], same[i, :n], valid[i, :n] = gr, pr, sr, True
    got = attack_option_rows(g, p, valid, same)
    for i, (gr, pr, sr) in enumerate(rows):
        mine = [
            (int(c), float(x))
            for r, c, x in zip(got.row, got.col, got.payoff, strict=True)
            if r == i
        ]
        assert mine == scan(gr, pr, sr), i
