"""Benchmark: one unfolding and one tree walk for every property of a spec (issue 31).

``lesmc check DENSE.json ONE.spec --engine enumerate`` (one property) against the same
with a spec of two properties sharing the attack window (robustness and resilience),
as fresh processes, alternately, best of ``--repeat``: the wall time a user sees, and
the engine seconds of each property. DENSE is the dense benchmark scene of
bench_unfold.py (a target in a platoon among 40 vehicles), window 4..9: 1.5 M states.

Run ``python benchmarks/bench_properties.py [--repeat 3] [--window 4..9]``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_unfold import dense_scene

from lesmc.scene import save_scene

ROBUST = """property robust {{
    attack window {w}
    minimize payoff
    subject to dist.sum(0..end) > 120
    holds if optimum > 3
    on x, y
}}
"""
RESIL = """property resil {{
    attack window {w}
    minimize dist.max({w})
    subject to dist.at(end) > 1
    holds if optimum > 30
    on x, y
}}
"""


def run(scene: Path, spec: Path) -> tuple[float, list[float]]:
    """Wall seconds of one ``lesmc check --engine enumerate --json``, and each property's
    engine seconds."""
    t0 = time.perf_counter()
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "lesmc",
            "check",
            str(scene),
            str(spec),
            "--engine",
            "enumerate",
            "--json",
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    wall = time.perf_counter() - t0
    if out.returncode not in (0, 1):
        raise SystemExit(out.stderr)
    return wall, [r["stats"]["seconds"] for r in json.loads(out.stdout)["results"]]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--window", default="4..9")
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp())
    scene = tmp / "dense.json"
    save_scene(dense_scene(40, 20, seed=1), scene)
    one, two = tmp / "one.spec", tmp / "two.spec"
    one.write_text(ROBUST.format(w=args.window))
    two.write_text(ROBUST.format(w=args.window) + RESIL.format(w=args.window))
    best: dict[str, tuple[float, list[float]]] = {}
    for _ in range(args.repeat):
        for name, spec in (("one property", one), ("two properties", two)):
            got = run(scene, spec)
            if name not in best or got[0] < best[name][0]:
                best[name] = got
    table = Table(title=f"lesmc check DENSE --engine enumerate, window {args.window}, best of "
                  f"{args.repeat}")  # fmt: skip
    for col in ("spec", "wall s", "vs one", "engine s per property"):
        table.add_column(col)
    base = best["one property"][0]
    for name, (wall, secs) in best.items():
        table.add_row(
            name, f"{wall:.2f}", f"{wall / base:.2f}x", ", ".join(f"{s:.2f}" for s in secs)
        )
    Console().print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
