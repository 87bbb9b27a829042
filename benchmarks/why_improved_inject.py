"""Why ``improved`` (joint KFs + monitor) under ``allow hide, inject`` with every candidate
does not finish on seed 2 (docs/results.md, "Injection on `single`"; docs/performance.md,
"Issue 61 (round 24): improved under inject"): the model the `rob` property's search has
to unfold, step by step.

From the window's root, each attacked step expands the states of the previous level
(the cheapest label per state; with ``--cut X`` only labels of cost <= X, the
property's threshold: a path above it cannot make the verdict ``violated``; with
``--sample N`` a random N of them, seeded) and counts the transitions built, those the
monitor allows (Eq. 13: τ does not rise; lesmc/engines/lazy.py, the same mask the
search reads), those of them whose path costs at most the threshold, the distinct
successors and the seconds. The counts of a sampled level scale with the level's size
(printed: per state expanded).

Usage: PYTHONPATH=. python benchmarks/why_improved_inject.py SCENE SPEC \
    [--sample N] [--cut X] [--steps K]
(SPEC: one property, e.g. `rob` of /tmp/lesmc-inject-video/p.spec; ``--steps``: how many
steps past the window's first to go, default to the window's end)
"""

from __future__ import annotations

import argparse
import itertools
import math
import time

import numpy as np


def _level(
    model: object, space: object, q: np.ndarray, cost: np.ndarray, k: int
) -> tuple[np.ndarray, np.ndarray, dict[str, float]]:
    """Expand states ``q`` (labels of cost ``cost``) into step ``k``: the successors'
    states and path costs that the monitor allows, and the counts."""
    from lesmc.engines.lazy import LazySpace
    from lesmc.engines.space import ranges
    from lesmc.model.growing import GrowingModel

    assert isinstance(model, GrowingModel) and isinstance(space, LazySpace)
    t0 = time.perf_counter()
    todo = np.unique(q)
    todo = todo[(model.out_lo[todo] < 0) & ~model.halted[todo]]
    if todo.size:
        model.expand(todo, k - 1)
    space.sync()
    live = model.out_lo[q] >= 0
    q, cost = q[live], cost[live]
    owner, t = ranges(model.out_lo[q], model.out_hi[q])
    ok = space.allowed_mask()[t]
    dst, c = model.dst[t[ok]], cost[owner[ok]] + space.c_obj[t[ok]]
    facts = {
        "labels": float(q.size),
        "built": float(t.size),
        "allowed": float(ok.sum()),
        "seconds": time.perf_counter() - t0,
        "distinct": float(np.unique(dst).size),
        "states": float(model.n_states),
    }
    return dst, c, facts


def _all_updates(scene: object, bp: object) -> str:
    """τ (Eq. 12) of the primary along the pattern that updates at every step from the
    window's root to the end (the design's own gains, frame by frame), and the steps
    where it rises past Eq. 13's tolerance: τ depends only on the steps at which the
    primary updated, so a state whose every pattern alarms has no completion the
    monitor allows."""
    from lesmc.language.semantics import BoundProperty
    from lesmc.model.kernel import tau
    from lesmc.scene import Scene
    from lesmc.tracking.joint import JointDesign
    from lesmc.tracking.monitor import track
    from lesmc.tracking.trackers import make_tracker

    assert isinstance(scene, Scene) and isinstance(bp, BoundProperty)
    design = make_tracker(scene)
    assert isinstance(design, JointDesign)
    loc = scene.tracker.measured
    P = track(design, bp.l - 1)[-1].P
    ci = design.track_covariances.add(P.copy())
    taus = [float(tau(P, loc))]
    for k in range(bp.l, bp.end + 1):
        _, gains = design.schedule.at(scene.target.step + k)
        ci = int(gains.rows(np.array([ci])).post[0])
        taus.append(float(tau(design.track_covariances[ci], loc)))
    tol = 1.0 + float(bp.monitor_parameter)
    rises = [bp.l + i for i, (a, b) in enumerate(itertools.pairwise(taus)) if b > a * tol]
    return (
        f"τ updating at every step {bp.l - 1}..{bp.end}: "
        + ", ".join(f"{t:.5f}" for t in taus)
        + f"; rises entering {rises or 'no step'}"
    )


def _dead(model: object, space: object, q: np.ndarray) -> int:
    """How many of the model's states ``q`` have no completion the property's monitor
    allows, by the joint design's relaxation to its primary (the question lazy.py asks of
    the window's root: lesmc/tracking/parts/relaxed.py)."""
    from lesmc.engines.lazy import LazySpace
    from lesmc.model.growing import GrowingModel

    assert isinstance(model, GrowingModel) and isinstance(space, LazySpace)
    cut = space.monitor_cut()
    ask = getattr(model.expander, "primary_alive", None)
    assert cut is not None and ask is not None
    return sum(ask(s, space.bp.end, cut) is False for s in q.tolist())


def _cheapest(q: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One label per state: the cheapest."""
    o = np.lexsort((c, q))
    q, c = q[o], c[o]
    first = np.r_[q[:1] >= 0, q[1:] != q[:-1]]
    return q[first], c[first]


def main() -> None:
    from lesmc.engines.lazy import LazySpace
    from lesmc.language.parser import load_spec
    from lesmc.pipeline.check import bind_scene
    from lesmc.scene import load_scene
    from lesmc.unfold.unfold import lazy_model

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene")
    ap.add_argument("spec")
    ap.add_argument("--sample", type=int, default=None, help="labels expanded a level at most")
    ap.add_argument("--cut", type=float, default=None, help="drop labels costing more")
    ap.add_argument("--steps", type=int, default=None)
    ap.add_argument(
        "--relax", action="store_true", help="count each level's states with no relaxed path"
    )
    args = ap.parse_args()
    scene = load_scene(args.scene).with_tracker(design="joint")
    bp = bind_scene(scene, [load_spec(args.spec).with_monitor()])[0]
    model = lazy_model(scene, (bp.l, bp.u), bp.end, inject=True)
    space = LazySpace(model, bp)
    last = bp.u if args.steps is None else min(bp.end, bp.l + args.steps - 1)
    cut = math.inf if args.cut is None else args.cut
    thr = float(bp.prop.threshold)
    rng = np.random.default_rng(0)
    q, c = np.array([space.root]), np.array([space.root_obj])
    print(f"window {bp.l}..{bp.u}, end {bp.end}; improved = joint + Eq. 13's monitor")
    print(_all_updates(scene, bp), flush=True)
    for k in range(bp.l, last + 1):
        q, c = _cheapest(q, c)
        q, c = q[c <= cut], c[c <= cut]
        whole = q.size
        if args.sample is not None and q.size > args.sample:
            pick = np.sort(rng.choice(q.size, args.sample, replace=False))
            q, c = q[pick], c[pick]
        if not q.size:
            print(f"step {k}: no path the monitor allows is left")
            break
        if args.relax:
            t0 = time.perf_counter()
            n = _dead(model, space, q)
            print(
                f"  relaxed primary: {n:,} of the {q.size:,} states at step {k - 1} have no "
                f"completion the monitor allows ({time.perf_counter() - t0:.1f} s)",
                flush=True,
            )
        q, c, f = _level(model, space, q, c, k)
        per = f["built"] / max(f["labels"], 1.0)
        print(
            f"step {k}: {int(f['labels']):,} of {whole:,} states expanded; built "
            f"{int(f['built']):,} transitions ({per:.0f} a state), the monitor allows "
            f"{int(f['allowed']):,}, of which {int((c <= thr).sum()):,} cost <= {thr:g}; "
            f"{int(f['distinct']):,} distinct successors; {f['seconds']:.1f} s; "
            f"model {int(f['states']):,} states",
            flush=True,
        )


if __name__ == "__main__":
    main()
