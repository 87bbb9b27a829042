"""Benchmark: a sweep over 20 values of epsilon against one check (issue 30: at most 2x).

Side by side in one run, alternately, best of ``--repeat``: the wall time a user sees
for ``lesmc check SCENE SPEC`` and for the same with ``--sweep eps=LO..HI:STEP``
(20 values), on the dense scene of bench_unfold.py (a target in a platoon of 6 among
40 other vehicles; attack windows 4..6 and 4..8, whose tree is too large to walk whole)
and on examples/merge.json; and the engine seconds the results
report (the sum over the variants against the one check's).

Run ``python benchmarks/bench_sweep.py [--repeat 3]``.
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

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_unfold import dense_scene  # noqa: E402

from lesmc.scene import save_scene  # noqa: E402

SPEC = """property robustness {
    attack window 4..6
    minimize payoff
    subject to dist.sum(0..end) > 60
    holds if optimum > 3
    on x, y
}
"""


def run(args: list[str]) -> tuple[float, float]:
    """Wall seconds of ``lesmc ARGS --json`` and the engine seconds its results report."""
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "lesmc", *args, "--json"], capture_output=True,
                       text=True, cwd=ROOT)  # fmt: skip
    wall = time.perf_counter() - t0
    assert r.returncode in (0, 1), r.stderr
    engine = sum(float(x["stats"]["seconds"]) for x in json.loads(r.stdout)["results"])
    return wall, engine


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    table = Table(title="one check against a sweep of 20 epsilon values")
    for c in ("scene", "one check: wall s", "sweep: wall s", "wall ratio", "engine s (1 / 20)"):
        table.add_column(c, justify="right")
    with tempfile.TemporaryDirectory() as d:
        dense = Path(d) / "dense.json"
        save_scene(dense_scene(40, 12, seed=1), dense)
        spec = Path(d) / "r.spec"
        spec.write_text(SPEC)
        wide = Path(d) / "r48.spec"  # the hard instance: a 226k-state tree, too big to walk
        wide.write_text(SPEC.replace("attack window 4..6", "attack window 4..8"))
        cases = [
            ("dense (40 vehicles)", [str(dense), str(spec)], "eps=10..200:10"),
            ("dense, window 4..8", [str(dense), str(wide)], "eps=10..200:10"),
            ("examples/merge.json", ["examples/merge.json", "specs/robustness.spec"],
             "eps=10..200:10"),
        ]  # fmt: skip
        for name, base, sweep in cases:
            one, many = (float("inf"), 0.0), (float("inf"), 0.0)
            for _ in range(args.repeat):
                one = min(one, run(["check", *base]))
                many = min(many, run(["check", *base, "--sweep", sweep]))
            table.add_row(name, f"{one[0]:.2f}", f"{many[0]:.2f}", f"{many[0] / one[0]:.2f}x",
                          f"{one[1]:.3f} / {many[1]:.3f}")  # fmt: skip
    Console(width=140).print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
