"""Benchmark: start-up wall time of the command line, against importing its light dependencies.

Run ``python benchmarks/bench_startup.py [-n 10]``. Each command runs as a user
runs it, in a fresh process; the commands alternate (round-robin, after one
unmeasured warm-up round) so that drift of the machine hits all of them alike.

(a) ``python -c "import numpy, lark, networkx"``, the floor for ``lesmc check``;
(b) ``lesmc --help``;
(c) ``lesmc check tests/golden/tiny/model.lts tests/golden/tiny/properties.spec``
    (exit status 1 is expected: the tiny model violates some properties).

``lesmc`` is the console script found on PATH. When that is not the script
installed beside this interpreter (e.g. a pyenv shim, which adds its own
start-up), (b) and (c) are also timed with the script beside the interpreter.
Targets: (b) well under 1 s, (c) at most 2x (a). tests/test_startup.py checks
which modules each verb imports; this script only measures.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "tests" / "golden" / "tiny"
CHECK_ARGS = ["check", str(TINY / "model.lts"), str(TINY / "properties.spec")]
BASELINE = [sys.executable, "-c", "import numpy, lark, networkx"]
MAIN = "import sys; from lesmc.cli.main import main; sys.argv[0] = 'lesmc'; main()"


def lesmc_scripts() -> list[tuple[str, list[str]]]:
    """(label, argv prefix) of the lesmc console scripts to time."""
    beside = Path(sys.executable).parent / "lesmc"
    on_path = shutil.which("lesmc")
    out: list[tuple[str, list[str]]] = []
    if on_path is not None:
        out.append(("lesmc", [on_path]))
    if beside.exists() and (on_path is None or Path(on_path).resolve() != beside.resolve()):
        out.append((f"{beside}", [str(beside)]))
    if not out:  # not installed as a script: the same entry point, still without -m
        out.append(("python -c main()", [sys.executable, "-c", MAIN]))
    return out


def commands() -> list[tuple[str, list[str], int]]:
    """(label, argv, expected exit status)."""
    cmds = [("(a) python -c 'import numpy, lark, networkx'", BASELINE, 0)]
    for i, (label, prefix) in enumerate(lesmc_scripts()):
        tag = "" if i == 0 else "'"
        cmds.append((f"(b{tag}) {label} --help", [*prefix, "--help"], 0))
        cmds.append((f"(c{tag}) {label} check tiny", [*prefix, *CHECK_ARGS], 1))
    return cmds


def run_once(argv: list[str], expected: int) -> float:
    t0 = time.perf_counter()
    r = subprocess.run(argv, capture_output=True, text=True, cwd=ROOT)
    wall = time.perf_counter() - t0
    if r.returncode != expected:
        sys.exit(f"{' '.join(argv)}: exit status {r.returncode}, expected {expected}\n{r.stderr}")
    return wall


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", type=int, default=10, help="measured repetitions of each command")
    n = ap.parse_args().n
    cmds = commands()
    for _, argv, expected in cmds:  # warm-up: page cache, .pyc files
        run_once(argv, expected)
    walls: list[list[float]] = [[] for _ in cmds]
    for _ in range(n):
        for i, (_, argv, expected) in enumerate(cmds):
            walls[i].append(run_once(argv, expected))
    base = statistics.median(walls[0])
    width = max(len(label) for label, _, _ in cmds)
    print(f"python {sys.version.split()[0]} at {sys.executable}; n={n}, alternating\n")
    print(f"{'command':<{width}}  {'median s':>9}  {'min s':>7}  {'max s':>7}  {'/ (a)':>6}")
    for (label, _, _), w in zip(cmds, walls, strict=True):
        med = statistics.median(w)
        print(f"{label:<{width}}  {med:>9.3f}  {min(w):>7.3f}  {max(w):>7.3f}  {med / base:>6.2f}")


if __name__ == "__main__":
    main()
