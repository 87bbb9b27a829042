"""Experiment: would deviation bounds or deviation dominance prune the dense scenes' search?
(issue 62, item 1; figures: docs/performance.md, "Issue 62, fourth round").

``python benchmarks/exp_dense_bounds.py --seeds A,B,... [--window 4..12]`` runs ``levels``
on each dense scene (bench_dense_random.py's family, the model unfolded on demand) and
then reads the states it built:

1. *Where the exact pass spends its labels*: per level of the exact pass for the optimum,
   its labels; those past the attack window follow one transition each (the unattacked
   outcome) to the end, where ``dist.at(end) > 1`` is decided.
2. *What the dives' states could tell it*: a bound computed backwards over the states
   built before the exact pass can prune a label only at a state those built; the share
   of the exact pass's labels that sit on such states bounds what it could prune.
3. *Contraction*: for every state at the window's last step u whose unattacked
   continuation was built to the end, its deviation d_u and the final one d_e. A bound
   d_e ≥ κ·d_u (or ≤) valid for all of them needs κ at most (at least) the smallest
   (largest) ratio d_e/d_u: printed with the share of states that violate.
4. *Dominance by deviation*: among those states with the same covariance, the pairs in
   which the one with the larger deviation does not violate while the smaller one does
   (or the reverse): each such pair is a counterexample to dropping a state whose
   deviation is "no better" than another's.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_dfs import EPS, spec
from bench_unfold import dense_scene

from lesmc.engines import levels
from lesmc.engines.lazy import LazySpace
from lesmc.language.parser import parse_spec
from lesmc.pipeline.check import bind_scene
from lesmc.unfold.unfold import lazy_model


def _inversions(dev: np.ndarray, bad: np.ndarray) -> tuple[int, int]:
    """Pairs (smaller deviation violates, larger does not) and the reverse."""
    order = np.argsort(dev, kind="stable")
    b = bad[order].astype(np.int64)
    bad_before = np.cumsum(b) - b  # violating states with a smaller deviation
    good_before = np.arange(b.size) - bad_before
    return int((bad_before * (1 - b)).sum()), int((good_before * b).sum())


def one(seed: int, l: int, u: int) -> None:
    scene = dense_scene(40, 24, seed, "single")
    bp = bind_scene(scene, [parse_spec(spec(l, u), "<exp>")])[0]
    model = lazy_model(scene, (bp.l, bp.u), bp.end)
    space = LazySpace(model, bp)
    seen: dict[str, object] = {"built_before": None, "labels": [], "steps": []}
    run = levels._optimum_pass

    def exact_watch(sp, bounds, budget, stats, upper, beam, *a, **k):  # type: ignore[no-untyped-def]
        if beam is None and seen["built_before"] is None:
            seen["built_before"] = model.n_states
        return run(sp, bounds, budget, stats, upper, beam, *a, **k)

    add = levels._Trail.add

    def trail_watch(self, q, parent, t):  # type: ignore[no-untyped-def]
        if seen["built_before"] is not None:
            seen["labels"].append(q.copy())  # type: ignore[attr-defined]
        return add(self, q, parent, t)

    levels._optimum_pass = exact_watch  # type: ignore[assignment]
    levels._Trail.add = trail_watch  # type: ignore[method-assign]
    try:
        t0 = time.perf_counter()
        out = levels.level_search(space)
        sec = time.perf_counter() - t0
    finally:
        levels._optimum_pass = run
        levels._Trail.add = add  # type: ignore[method-assign]
    labels = seen["labels"]
    assert isinstance(labels, list) and labels
    before = int(seen["built_before"])  # type: ignore[call-overload]
    flat = np.concatenate(labels)
    steps = model.step[flat]
    past = int((steps > bp.u).sum())
    print(f"seed {seed}: optimum {out.optimum:.6g}, {sec:.2f} s, "
          f"{out.stats.states_expanded:,} labels ({out.stats.extra})")  # fmt: skip
    print(f"  exact pass: {flat.size:,} labels, {past:,} ({past / flat.size:.0%}) past the "
          f"window (one transition each); {int((flat < before).sum()):,} "
          f"({(flat < before).mean():.1%}) on states the dives built")  # fmt: skip
    # the unattacked continuation of every state at u built to the end
    dist = space.dist
    at_u = np.flatnonzero(
        (model.step[: model.n_states] == bp.u) & (model.out_lo[: model.n_states] >= 0)
    )
    q = at_u.copy()
    ok = np.ones(q.size, dtype=bool)
    for _ in range(bp.u, bp.end):
        lo = model.out_lo[q]
        ok &= (lo >= 0) & ~model.halted[q]
        q = np.where(ok, model.dst[np.maximum(lo, 0)], q)
    d_u, d_e = dist[at_u[ok]], dist[q[ok]]
    bad = d_e > EPS
    ratio = d_e / np.maximum(d_u, 1e-300)
    print(f"  {ok.sum():,} states at step {bp.u} continued to the end: {bad.mean():.1%} violate; "
          f"d_end/d_u from {ratio.min():.3g} to {ratio.max():.3g} (median "
          f"{np.median(ratio):.3g}); d_u of the violating ones from "
          f"{d_u[bad].min(initial=np.inf):.3g}, of the others up to "
          f"{d_u[~bad].max(initial=-np.inf):.3g}")  # fmt: skip
    cov = model.cov[at_u[ok]]
    inv = np.zeros(2, dtype=np.int64)
    pairs = 0
    for c in np.unique(cov):
        g = cov == c
        inv += _inversions(d_u[g], bad[g])
        pairs += int(g.sum()) * (int(g.sum()) - 1) // 2
    print(f"  same covariance: {pairs:,} pairs; {inv[0]:,} where the smaller deviation "
          f"violates and the larger does not, {inv[1]:,} the reverse")  # fmt: skip


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", required=True)
    ap.add_argument("--window", default="4..12")
    args = ap.parse_args()
    l, u = (int(x) for x in args.window.split(".."))
    for seed in (int(s) for s in args.seeds.split(",")):
        one(seed, l, u)
    return 0


if __name__ == "__main__":
    sys.exit(main())
