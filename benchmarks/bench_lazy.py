"""Benchmark: checks on models unfolded on demand, over several dense scenes (issue 31).

    python benchmarks/bench_lazy.py [--root DIR] [--repeat 5] [--set NAME=VALUE ...]

Times ``lesmc.api.check`` (min of ``--repeat``, after one warm-up) on the dense scenes
of bench_unfold.py (seeds 0-3, the single design; seed 0 also joint) with
bench_search.py's resilience and robustness specs, and prints one line per case:
milliseconds, optimum, states built. ``--root`` runs another checkout's lesmc and
benchmarks (a ``git worktree`` of an earlier commit), so that two versions can be
compared side by side, alternately, in fresh processes; ``--set`` overrides a constant
of ``lesmc.engines.levels`` (for example ``LAZY_BEAM=64``). Figures:
docs/performance.md, fifteenth round.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

CASES = [
    *[(0, "single", "resilience", w) for w in ("4..10", "4..12", "4..14", "6..16")],
    *[(0, "single", "robustness", w) for w in ("4..8", "4..10")],
    *[
        (seed, "single", kind, w)
        for seed in (1, 2, 3)
        for kind, w in (("resilience", "4..12"), ("resilience", "6..16"), ("robustness", "4..10"))
    ],
    (0, "joint", "resilience", "4..8"),
    (0, "joint", "robustness", "4..7"),
]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", default=str(Path(__file__).resolve().parents[1]))
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE")
    args = ap.parse_args()
    root = str(Path(args.root).resolve())
    sys.path[:0] = [root, root + "/benchmarks"]
    from bench_search import spec_text
    from bench_unfold import dense_scene

    import lesmc
    import lesmc.engines.levels as levels
    from lesmc.api import check
    from lesmc.language.parser import parse_spec

    assert lesmc.__file__ is not None and lesmc.__file__.startswith(root), lesmc.__file__
    for item in args.set:
        name, value = item.split("=")
        setattr(levels, name, type(getattr(levels, name))(value))
    scenes: dict[tuple[int, str], object] = {}
    print(f"lesmc from {root} {' '.join(args.set)}")
    for seed, design, kind, w in CASES:
        scene = scenes.setdefault((seed, design), dense_scene(40, 24, seed, design))
        l, u = (int(x) for x in w.split(".."))
        specs = [parse_spec(spec_text(kind, l, u), "<bench>")]
        r = check(scene, specs)[0]  # type: ignore[arg-type]
        best = float("inf")
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            r = check(scene, specs)[0]  # type: ignore[arg-type]
            best = min(best, time.perf_counter() - t0)
        built = r.stats.extra.get("states_built")
        print(f"{seed} {design:6} {kind:10} {w:6} {best * 1000:7.1f} ms  "
              f"optimum {r.optimum:.6g}  built {built}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
