"""Exporting a model, side by side with building it (issue 27: export <= build).

    python benchmarks/bench_export.py [--window 4..8]

On the dense benchmark scene (benchmarks/bench_unfold.py, single design), in one
run: the seconds to build the model, then to write it as JSON (.lts, what
`lesmc build` writes), GraphML (streamed) and, for the robustness property of
the window, Storm's DRN; and `networkx.read_graphml` reading the GraphML back
with the model's node and edge counts. Ratios to the build are printed: the
machine is shared, so compare them, not the seconds.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import networkx as nx
from bench_unfold import dense_scene

from lesmc.api import export_model
from lesmc.build.unfold import build_model
from lesmc.common.errors import LesmcError
from lesmc.language.parser import parse_spec


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--window", default="4..8")
    args = ap.parse_args()
    lo, hi = (int(x) for x in args.window.split(".."))
    scene = dense_scene(40, 20, seed=1, design="single")
    t0 = time.perf_counter()
    model = build_model(scene, (lo, hi))
    build = time.perf_counter() - t0
    print(f"build: {model.n_states} states, {model.n_transitions} transitions, {build:.2f} s")
    spec = parse_spec(
        f"property robustness {{ attack window {lo}..{hi} minimize payoff "
        "subject to dist.sum(0..end) > 120 holds if optimum > 3 on x, y }",
        "<bench>",
    )
    with tempfile.TemporaryDirectory() as d:
        for fmt in ("json", "graphml", "drn"):
            out = Path(d) / f"m.{fmt}"
            t0 = time.perf_counter()
            try:
                facts = export_model(model, out, fmt, spec if fmt == "drn" else None)
            except LesmcError as exc:  # the path-prefix tree past its limit: said, not hidden
                print(f"export {fmt:8s} refused: {exc.message}")
                continue
            secs = time.perf_counter() - t0
            extra = f", {facts['drn']['states']} MDP states" if fmt == "drn" else ""
            size = out.stat().st_size / 2**20
            print(
                f"export {fmt:8s} {secs:6.2f} s  {secs / build:5.1f}x build  {size:7.1f} MiB{extra}"
            )
        t0 = time.perf_counter()
        g = nx.read_graphml(Path(d) / "m.graphml")
        same = g.number_of_nodes() == model.n_states and g.number_of_edges() == model.n_transitions
        print(f"networkx.read_graphml {time.perf_counter() - t0:6.2f} s; same counts: {same}")


if __name__ == "__main__":
    main()
