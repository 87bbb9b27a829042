"""Benchmark: the search engines on scenes over long attack windows, side by side.

Run ``python benchmarks/bench_search.py [--scene lesmc-verify/scene.json]``.
The scene defaults to the dense synthetic one of bench_unfold.py (a target in a
6-vehicle platoon among 40 other vehicles); ``lesmc verify`` writes the default
video's scene to ``lesmc-verify/scene.json``. For each window (6 to 20 steps)
and design, resilience and robustness are checked on the fly by ``levels``
(the default engine) and ``bnb``, each under ``--timeout``; the table shows
each engine's seconds (search and on-the-fly unfolding, the wall time a user
sees inside ``lesmc check``), labels expanded, and whether the answers agree.
Figures: docs/performance.md.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_unfold import dense_scene

from lesmc.api import check
from lesmc.language.parser import parse_spec
from lesmc.scene import load_scene


def spec_text(kind: str, l: int, u: int) -> str:
    if kind == "resilience":
        return (
            f"property resilience {{ attack window {l}..{u} minimize dist.max({l}..{u}) "
            f"subject to dist.at(end) > 1 holds if optimum > 30 on x, y }}"
        )
    return (
        f"property robustness {{ attack window {l}..{u} minimize payoff "
        f"subject to dist.sum(0..end) > 120 holds if optimum > 3 on x, y }}"
    )


def run(scene, kind: str, l: int, u: int, engine: str, timeout: float):  # type: ignore[no-untyped-def]
    spec = parse_spec(spec_text(kind, l, u), "<bench>")
    t0 = time.perf_counter()
    r = check(scene, [spec], engine=engine, timeout=timeout)[0]  # type: ignore[arg-type]
    return r, time.perf_counter() - t0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default=None, help="a scene file [default: the dense scene]")
    ap.add_argument("--windows", default="4..14", help="comma-separated L..U windows")
    ap.add_argument("--designs", default="single", help="comma-separated: single,joint")
    ap.add_argument("--kinds", default="resilience,robustness")
    ap.add_argument("--engines", default="levels,bnb")
    ap.add_argument("--timeout", type=float, default=120.0)
    args = ap.parse_args()
    table = Table(title="on-the-fly search over long windows")
    for col in (
        "scene",
        "design",
        "property",
        "window",
        "engine",
        "verdict",
        "optimum",
        "θ*",
        "labels",
        "built",
        "seconds",
        "agree",
    ):
        table.add_column(col, justify="right")
    for design in args.designs.split(","):
        if args.scene:
            scene = load_scene(args.scene).with_tracker(design=design)
            name = Path(args.scene).parent.name or args.scene
        else:
            scene = dense_scene(40, 24, 0, design)
            name = "dense"
        for w in args.windows.split(","):
            l, u = (int(x) for x in w.split(".."))
            for kind in args.kinds.split(","):
                answers = []
                for engine in args.engines.split(","):
                    r, secs = run(scene, kind, l, u, engine, args.timeout)
                    answers.append((r.optimum, r.witness_value))
                    agree = (
                        ""
                        if len(answers) == 1
                        else (
                            "yes"
                            if answers[-1] == answers[0]
                            else "timeout"
                            if r.stats.stopped != "finished"
                            else "NO"
                        )
                    )
                    table.add_row(
                        name,
                        design,
                        kind,
                        f"{l}..{u}",
                        engine,
                        r.verdict,
                        "-" if r.optimum is None else f"{r.optimum:.4g}",
                        "-" if r.witness_value is None else f"{r.witness_value:.4g}",
                        str(r.stats.states_expanded),
                        str(r.stats.extra.get("states_built", "")),
                        f"{secs:.2f}" + ("" if r.stats.stopped == "finished" else " (stopped)"),
                        agree,
                    )
                    print(
                        name,
                        design,
                        kind,
                        w,
                        engine,
                        r.verdict,
                        r.optimum,
                        r.witness_value,
                        r.stats.states_expanded,
                        round(secs, 2),
                        r.stats.stopped,
                        flush=True,
                    )
    Console(width=160).print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
