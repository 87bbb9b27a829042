"""Benchmark: building and checking scenes (tracker expansion speed, on-the-fly checking).

Run ``python benchmarks/bench_builder.py``. Figures and targets: docs/performance.md.
"""

from __future__ import annotations

import sys
import time

import numpy as np
from rich.console import Console
from rich.table import Table

from lesmc.engines.check import check_bound, check_scene
from lesmc.engines.space import CompiledModel
from lesmc.language.parser import parse_spec
from lesmc.language.semantics import bind
from lesmc.model.builder import build_model
from lesmc.tracking.toy import Vehicle, vehicle_scene


def dense_scene(n: int, frames: int, seed: int, design: str = "single"):  # type: ignore[no-untyped-def]
    """A target among n random straight-line vehicles, some in a platoon around it."""
    rng = np.random.default_rng(seed)
    t = Vehicle("t", 500, 500, 10, 0, 3.0)
    platoon = [
        Vehicle(f"p{i}", 500 + float(dx), 500 + float(dy), 10, 0, float(rng.uniform(1, 5)))
        for i, (dx, dy) in enumerate(rng.uniform(-12, 12, size=(6, 2)))
    ]
    others = [
        Vehicle(
            f"v{i}",
            *map(float, rng.uniform(0, 1000, 2)),
            *map(float, rng.uniform(-10, 10, 2)),
            float(rng.uniform(1, 5)),
        )
        for i in range(n)
    ]
    return vehicle_scene([t, *platoon, *others], frames, t).with_tracker(design=design)


SPEC = """
property robustness { attack window %(l)d..%(u)d minimize payoff subject to dist.sum(0..end) > 120
                      holds if optimum > 3 }
property resilience { attack window %(l)d..%(u)d minimize dist.max(%(l)d..%(u)d)
                      subject to dist.at(end) > 1 holds if optimum > 30 }
"""


def expansion_rate(scene, spec) -> tuple[int, float]:  # type: ignore[no-untyped-def]
    """Transitions per second when the on-the-fly space is expanded completely."""
    from lesmc.engines.check import bind_scene
    from lesmc.engines.lazy import LazySpace
    from lesmc.model.builder import original_run
    from lesmc.tracking.design import make_design

    bp = bind_scene(scene, [spec])[0]
    t0 = time.perf_counter()
    design = make_design(scene)
    space = LazySpace(design, original_run(design), bp)
    stack = [space.root]
    while stack:
        q = stack.pop()
        if not space.is_leaf(q):
            stack.extend(space.cm.dst[t] for t in space.successors(q))
    return len(space.cm.dst), time.perf_counter() - t0


def main() -> int:
    console = Console(width=170)
    table = Table(title="scene -> model -> check (20 frames)")
    for c in (
        "scene",
        "design",
        "window",
        "states",
        "transitions",
        "build s",
        "build trans/s",
        "check bnb s",
        "on-the-fly check s",
        "on-the-fly states",
        "full expansion trans/s",
    ):
        table.add_column(c, justify="right")
    make_design_warm = dense_scene(10, 3, seed=0)
    build_model(make_design_warm, (1, 1))  # import and warm-up costs out of the figures
    for n, (l, u), design in [
        (300, (6, 9), "single"),
        (300, (6, 8), "joint"),
        (300, (8, 10), "single"),
        (20, (6, 9), "single"),
    ]:
        scene = dense_scene(n, 20, seed=1, design=design)
        spec = parse_spec(SPEC % {"l": l, "u": u})
        t0 = time.perf_counter()
        model = build_model(scene, (l, u))
        t_build = time.perf_counter() - t0
        cm = CompiledModel.from_lts(model)
        bps = [bind(spec, p, model.end, model.components, True) for p in spec.properties]
        t0 = time.perf_counter()
        for bp in bps:
            check_bound(cm, bp, "bnb")
        t_check = time.perf_counter() - t0
        t0 = time.perf_counter()
        lazy = check_scene(scene, [spec])
        t_lazy = time.perf_counter() - t0
        m = model.graph.number_of_edges()
        n_exp, t_exp = expansion_rate(scene, spec)
        table.add_row(
            f"{n + 7} vehicles",
            design,
            f"{l}..{u}",
            f"{model.graph.number_of_nodes():,}",
            f"{m:,}",
            f"{t_build:.3f}",
            f"{m / t_build:,.0f}",
            f"{t_check:.3f}",
            f"{t_lazy:.3f}",
            "/".join(str(r.stats.extra["states_built"]) for r in lazy),
            f"{n_exp / t_exp:,.0f}",
        )
    console.print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
