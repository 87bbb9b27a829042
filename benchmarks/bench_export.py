"""Exporting a model, side by side with building it (issue 27: export <= build).

    python benchmarks/bench_export.py [--scene SCENE] [--window 4..8] [--read-back]

In one run, on one scene (default: the dense benchmark scene of
benchmarks/bench_unfold.py, single design; `--scene out/scene.json` after
`lesmc verify --out out` for the default video):

* engine seconds: the unfolding alone, then each writer alone on the built
  model (JSON .lts, what `lesmc build` writes; GraphML, streamed; DOT when the
  model is small enough; DRN and PRISM for a robustness property of the window);
* wall seconds a user waits: `lesmc build SCENE -o m.lts` beside
  `lesmc export SCENE --format F -o OUT` for each format, as fresh processes;
* with --read-back, `networkx.read_graphml` of the GraphML and its counts.

Ratios to the build are printed: the machine is shared, so compare them, not
the seconds.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import networkx as nx
from bench_unfold import dense_scene

from lesmc.api import export_model, load_scene
from lesmc.common.errors import LesmcError
from lesmc.exporters import formats
from lesmc.language.parser import parse_spec
from lesmc.scene import save_scene
from lesmc.unfold.unfold import build_model

FORMATS = formats.names()  # every registered format
MDP = formats.where(lambda f: f.states_property)  # the ones that export a property


def _engine(scene_file: Path, window: tuple[int, int], d: Path) -> float:
    """Unfolding, then each writer alone; returns the unfolding's seconds."""
    lo, hi = window
    t0 = time.perf_counter()
    model = build_model(load_scene(scene_file), window)
    build = time.perf_counter() - t0
    print(f"model: {model.n_states} states, {model.n_transitions} transitions")
    print(f"engine  unfold          {build:6.2f} s   1.0x")
    spec = parse_spec(
        f"property robustness {{ attack window {lo}..{hi} minimize payoff "
        "subject to dist.sum(0..end) > 120 holds if optimum > 3 on x, y }",
        "<bench>",
    )
    for fmt in FORMATS:
        out = d / f"m.{fmt}"
        t0 = time.perf_counter()
        try:
            export_model(model, out, fmt, spec if fmt in MDP else None)
        except LesmcError as exc:  # a size limit: said, not hidden
            print(f"engine  write {fmt:8s}  refused: {exc.message}")
            continue
        secs = time.perf_counter() - t0
        size = out.stat().st_size / 2**20
        print(f"engine  write {fmt:8s} {secs:6.2f} s {secs / build:5.1f}x  {size:7.1f} MiB")
    return build


def _wall(scene_file: Path, window: str, d: Path) -> None:
    """`lesmc build` and `lesmc export` from the scene file, as a user runs them."""

    def run(*args: str) -> tuple[float, str]:
        """Wall seconds, and why the command refused (its last stderr line), if it did."""
        t0 = time.perf_counter()
        r = subprocess.run([sys.executable, "-m", "lesmc", *args], capture_output=True, text=True)
        secs = time.perf_counter() - t0
        return secs, "" if r.returncode == 0 else (r.stderr.strip().splitlines() or ["?"])[-1]

    build, why = run("build", str(scene_file), "--window", window, "-o", str(d / "w.lts"))
    if why:
        raise SystemExit(f"lesmc build failed: {why}")
    print(f"wall    lesmc build     {build:6.2f} s   1.0x")
    lo, hi = window.split("..")
    spec = d / "r.spec"
    spec.write_text(
        f"property robustness {{ attack window {lo}..{hi} minimize payoff "
        "subject to dist.sum(0..end) > 120 holds if optimum > 3 on x, y }\n"
    )
    for fmt in FORMATS:
        extra = ["--spec", str(spec)] if fmt in MDP else []
        args = ["export", str(scene_file), "--window", window, "--format", fmt, *extra]
        secs, why = run(*args, "-o", str(d / f"w.{fmt}"))
        shown = f"refused: {why}" if why else f"{secs:6.2f} s {secs / build:5.1f}x"
        print(f"wall    lesmc export {fmt:8s} {shown}")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", type=Path, default=None)
    ap.add_argument("--window", default="4..8")
    ap.add_argument("--read-back", action="store_true")
    args = ap.parse_args()
    lo, hi = (int(x) for x in args.window.split(".."))
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        scene_file = args.scene
        if scene_file is None:
            scene_file = d / "dense.json"
            save_scene(dense_scene(40, 20, seed=1, design="single"), scene_file)
        _engine(scene_file, (lo, hi), d)
        _wall(scene_file, args.window, d)
        if args.read_back:
            model = build_model(load_scene(scene_file), (lo, hi))
            t0 = time.perf_counter()
            g = nx.read_graphml(d / "m.graphml")
            counts = (g.number_of_nodes(), g.number_of_edges())
            same = counts == (model.n_states, model.n_transitions)
            print(f"networkx.read_graphml {time.perf_counter() - t0:6.2f} s; same counts: {same}")


if __name__ == "__main__":
    main()
