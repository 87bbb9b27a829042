"""Benchmark: `lesmc check` of a large .lts file against a bare `json.load` of it.

Row of docs/performance.md ("A fast core"): the whole process wall time of
``lesmc check BIG.lts SPEC`` (start-up, strict JSON reading, validation into
arrays, one check) against ``python -c "import json; json.load(open(BIG))"``,
alternated N times in one run after one warm-up run of each (bytecode caches
written, as pip leaves them); also the in-process stages. BIG is a layered
68,890-state model (steps 0..20, fan-out 1-4), made here with a fixed seed.

The binary form (issue 31, lesmc/model/lts_binary.py) of the same model side by
side: ``lesmc check BIG.npz SPEC`` against a bare process that ``numpy.load``s the
same arrays, and in process ``load_lts_npz`` (read + every rule checked) against
``numpy.load`` of its arrays; also for the same model with the ids ``lesmc build -o
MODEL.npz`` gives (``k{step}.{row}``, not stored), the others being 68,890 custom ids
(the binary form's ``ids`` array, which ``numpy.load`` reads too).

Run ``python benchmarks/bench_load.py [-n 7] [--keep DIR]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from lesmc.common.files import read_json
from lesmc.model.lts_binary import load_lts_npz
from lesmc.model.lts_format import lts_from_dict, save_lts

SPEC = (
    "property p { attack window 1..3 minimize payoff subject to dist.max(0..end) > 600 "
    "holds if optimum > 1 }\n"
)


def make(n: int = 68890, e: int = 20, seed: int = 0) -> dict:  # type: ignore[type-arg]
    """The model document: states in layers of growing width, 1-4 successors each."""
    rng = np.random.default_rng(seed)
    sizes = [1]
    while len(sizes) <= e and sizes[-1] * 3 < (n - sum(sizes)) / (e + 1 - len(sizes)):
        sizes.append(sizes[-1] * 3)
    rest, left = n - sum(sizes), e + 1 - len(sizes)
    sizes += [rest // left + (1 if i < rest % left else 0) for i in range(left)]
    assert sum(sizes) == n and len(sizes) == e + 1
    layers: list[list[str]] = []
    c = 0
    for k, w in enumerate(sizes):
        layers.append([f"k{k}.{c + i}" for i in range(w)])
        c += w
    states = []
    for k, layer in enumerate(layers):
        S = np.round(rng.uniform(0, 1000, (len(layer), 4)), 3).tolist()
        for sid, s in zip(layer, S, strict=True):
            states.append({"id": sid, "step": k, "s": s})
    trans = []
    for k in range(e):
        A, B = len(layers[k]), len(layers[k + 1])
        succ = [set() for _ in range(A)]
        for j in range(B):
            succ[j * A // B].add(j)
        for i in range(A):
            if not succ[i]:
                succ[i].add(i * B // A)
        for i in range(0, A, 4):
            succ[i].add((min(succ[i]) + 1) % B)
        for i in range(A):
            for r, j in enumerate(sorted(succ[i], key=lambda j: layers[k + 1][j])):
                trans.append(
                    {
                        "src": layers[k][i],
                        "dst": layers[k + 1][j],
                        "payoff": round(float(rng.uniform(0, 5)), 3),
                        "rank": r,
                        "obs": f"{k + 1}:{r}",
                    }
                )
    first = {}
    for t in trans:
        if t["rank"] == 0:
            first[t["src"]] = t["dst"]
    original = [layers[0][0]]
    for _ in range(e):
        original.append(first[original[-1]])
    return {
        "format": "lesmc-lts",
        "version": 1,
        "components": ["x", "y", "vx", "vy"],
        "initial": original[0],
        "original": original,
        "states": states,
        "transitions": trans,
        "meta": {"source": "bench"},
    }


#: As a user runs it: with bytecode caches (pip writes them at install; a
#: PYTHONDONTWRITEBYTECODE in the caller's environment would make every run
#: compile lesmc's modules again).
ENV = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}


def timed(argv: list[str]) -> float:
    t0 = time.perf_counter()
    r = subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=ENV)
    assert r.returncode in (0, 1), argv
    return time.perf_counter() - t0


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("-n", type=int, default=7)
    ap.add_argument("--keep", type=Path, default=None, help="write the files here")
    args = ap.parse_args()
    d = args.keep or Path(tempfile.mkdtemp(prefix="lesmc-bench-"))
    d.mkdir(parents=True, exist_ok=True)
    big, npz, spec = d / "big.lts", d / "big.npz", d / "p.spec"
    model = lts_from_dict(make())
    save_lts(model, big)
    save_lts(model, npz)
    # what `lesmc build -o MODEL.npz` writes: the default ids k{step}.{row}, none stored
    built = d / "built.npz"
    save_lts(dataclasses.replace(model, ids=None), built)
    spec.write_text(SPEC)
    lesmc = shutil.which("lesmc") or "lesmc"
    bare = [sys.executable, "-c", f"import json; json.load(open({str(big)!r}))"]
    bare_np = [
        sys.executable,
        "-c",
        f"import numpy as np; z = np.load({str(npz)!r}); [z[k] for k in z.files]",
    ]
    check = [lesmc, "check", str(big), str(spec)]
    check_np = [lesmc, "check", str(npz), str(spec)]
    runs: dict[str, list[float]] = {
        "json.load": [],
        "lesmc check": [],
        "numpy.load": [],
        "lesmc check .npz": [],
    }
    stages: dict[str, list[float]] = {
        "json.load": [],
        "read_json": [],
        "lts_from_dict": [],
        "numpy.load": [],
        "load_lts_npz": [],
        "numpy.load, built ids": [],
        "load_lts_npz, built ids": [],
    }
    for argv in (bare, check, bare_np, check_np):  # warm-up: bytecode, page cache
        timed(argv)
    for _ in range(args.n):
        for name, argv in zip(runs, (bare, check, bare_np, check_np), strict=True):
            runs[name].append(timed(argv))
        t0 = time.perf_counter()
        with open(big) as fh:
            json.load(fh)
        t1 = time.perf_counter()
        data = read_json(big)
        t2 = time.perf_counter()
        lts_from_dict(data)
        t3 = time.perf_counter()
        with np.load(npz) as z:
            [z[k] for k in z.files]
        t4 = time.perf_counter()
        load_lts_npz(npz)
        t5 = time.perf_counter()
        with np.load(built) as z:
            [z[k] for k in z.files]
        t6 = time.perf_counter()
        load_lts_npz(built)
        t7 = time.perf_counter()
        spans = (t1 - t0, t2 - t1, t3 - t2, t4 - t3, t5 - t4, t6 - t5, t7 - t6)
        for k, v in zip(stages, spans, strict=True):
            stages[k].append(v)
    table = Table(
        title=f"{big.stat().st_size / 1e6:.1f} MB .lts, 68,890 states (min / median of {args.n})"
    )
    for c in ("what", "min s", "median s", "min / json.load"):
        table.add_column(c, justify="right")
    table.add_column("min / numpy.load", justify="right")
    base_p, base_s = min(runs["json.load"]), min(stages["json.load"])
    base_np, base_nps = min(runs["numpy.load"]), min(stages["numpy.load"])
    for name, vals in runs.items():
        table.add_row(
            f"process: {name}",
            f"{min(vals):.3f}",
            f"{statistics.median(vals):.3f}",
            f"{min(vals) / base_p:.2f}x",
            f"{min(vals) / base_np:.2f}x",
        )
    base_built = min(stages["numpy.load, built ids"])
    for name, vals in stages.items():
        to_np = base_built if name.endswith("built ids") else base_nps  # each its own file
        table.add_row(
            f"in process: {name}",
            f"{min(vals):.4f}",
            f"{statistics.median(vals):.4f}",
            f"{min(vals) / base_s:.2f}x",
            f"{min(vals) / to_np:.2f}x",
        )
    Console(width=120).print(table)
    if args.keep is None:
        shutil.rmtree(d)
    return 0


if __name__ == "__main__":
    sys.exit(main())
