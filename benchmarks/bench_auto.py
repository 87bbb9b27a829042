"""Benchmark: engine ``auto`` against every other engine, per instance (issue 62, item 4).

Run ``python benchmarks/bench_auto.py`` (``--quick``: n = 40 only, one draw). The set is
the knapsack instances of bench_knapsack.py (n = 40 and 80, weights up to 10^3 and
10^6, uncorrelated and strongly correlated costs, ``--draws`` instances each from seeds
``--seed-base``, ... drawn from the operating system and printed when not given) and
bench_engines.py's models (random layered models, robustness and resilience, and its
knapsacks). Every engine (``levels``, ``bnb``, ``enumerate``, ``auto``) checks each
instance through ``check_bound`` (the probe of small trees included, as a user gets it)
within ``--timeout`` seconds and ENUMERATE_BUDGET labels; a run under SHORT seconds is
repeated (best of ``--repeat``, under TINY seconds of 3x as many, the engines in
another order each round, garbage collected before each run). The seconds compared are
the process's CPU time around ``check_bound`` (``--clock cpu``, the default: on a shared
machine the wall clock mostly measures the other jobs) or the engine's own wall-clock
seconds (``--clock wall``); the timeout is wall-clock either way. The table shows each engine's
seconds (a run that did not finish: "unfinished"), the engine ``auto`` chose
(``enumerate``: the probe answered), auto / best, the best being the fastest engine
that finished, and the chosen engine's own time / best (the rule's quality, free of the
jitter between auto's run and its engine's); every finished answer
must equal the others'. Target: the worst auto / best at most 1.2x. Figures:
docs/performance.md, "Issue 62, fourth round".
"""

from __future__ import annotations

import argparse
import gc
import math
import os
import statistics
import sys
import time
from pathlib import Path

from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_engines import knapsack_cases, layered_cases
from bench_knapsack import instance

from lesmc.common.budget import Budget
from lesmc.engines.check import check_bound
from lesmc.engines.result import CheckResult
from lesmc.language.parser import parse_spec
from lesmc.language.semantics import BoundProperty, bind
from lesmc.model.arrays import ArrayModel
from lesmc.model.knapsack import Item, knapsack_lts, knapsack_spec
from lesmc.model.lts import LTS, to_arrays

ENGINES = ("levels", "bnb", "enumerate", "auto")
#: Labels any engine may expand (enumerate's tree beyond it is "over budget").
ENUMERATE_BUDGET = 6_000_000
#: Runs shorter than this (seconds) are repeated: best of --repeat ...
SHORT = 1.0
#: ... and runs shorter than this, best of TINY_TIMES × --repeat (milliseconds on a
#: loaded 2-core machine are mostly jitter).
TINY = 0.05
TINY_TIMES = 3


def knapsack_set(draws: int, base: int, quick: bool) -> list[tuple[str, ArrayModel, BoundProperty]]:
    """bench_knapsack.py's instances, ``draws`` of each size, range and class."""
    out = []
    for n in (40,) if quick else (40, 80):
        for r in (1000, 1_000_000):
            for cls in ("uncorrelated", "strong"):
                for seed in range(base, base + draws):
                    cost, cap, demand = instance(n, r, cls, seed)
                    items = [Item(float(c), float(g)) for c, g in zip(cost, cap, strict=True)]
                    model = knapsack_lts(items)
                    spec = parse_spec(knapsack_spec(n, demand, 0.0), "<knapsack>")
                    bp = bind(spec, spec.properties[0], model.end, model.components, False)
                    out.append((f"knapsack {seed} n={n} R={r:g} {cls}", model, bp))
    return out


def engines_set(quick: bool) -> list[tuple[str, ArrayModel, BoundProperty]]:
    """bench_engines.py's layered models (both properties) and knapsacks."""
    out = []
    models: list[tuple[str, LTS | ArrayModel, str]] = list(layered_cases(quick))
    models += [(name, m, s) for name, m, s, _ in knapsack_cases(quick)]
    for name, model, text in models:
        spec = parse_spec(text)
        cm = model if isinstance(model, ArrayModel) else to_arrays(model)
        for p in spec.properties:
            bp = bind(spec, p, model.end, model.components, False)
            out.append((f"{name} {p.name}", cm, bp))
    return out


def once(
    cm: ArrayModel, bp: BoundProperty, engine: str, timeout: float
) -> tuple[CheckResult, float]:
    """One check and the CPU seconds this process spent in it; the garbage of the previous
    one collected first (bnb's labels, for instance, would otherwise be collected in the
    next engine's seconds)."""
    gc.collect()
    t = time.process_time()
    r = check_bound(cm, bp, engine, Budget(timeout=timeout, max_states=ENUMERATE_BUDGET))
    return r, time.process_time() - t


def answer(r: CheckResult) -> tuple[float, float | None]:
    return (math.inf if r.optimum is None else r.optimum, r.witness_value)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="n = 40 knapsacks, fewer models")
    ap.add_argument("--timeout", type=float, default=20.0)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--seed-base", type=int, default=None)
    ap.add_argument("--draws", type=int, default=1)
    ap.add_argument(
        "--clock",
        choices=("cpu", "wall"),
        default="cpu",
        help="seconds compared: this process's CPU time (default: free of the other jobs"
        " of a shared machine) or the engine's own wall-clock seconds",
    )
    args = ap.parse_args()
    base = args.seed_base
    if base is None:
        base = (1 << 16) + int.from_bytes(os.urandom(4), "little")
    print(f"seed base {base} (repeat with --seed-base {base} --draws {args.draws})", flush=True)
    cases = knapsack_set(args.draws, base, args.quick) + engines_set(args.quick)
    warm = cases[-1]
    for e in ENGINES:  # imports and first calls out of the figures
        once(warm[1], warm[2], e, args.timeout)
    table = Table(
        title=f"auto against every engine: {args.clock} seconds (check_bound, probe included)"
    )
    for col in ("instance", *ENGINES, "auto chose", "best", "auto / best", "chosen / best"):
        table.add_column(col, justify="left" if col == "instance" else "right")
    ratios: list[float] = []
    rules: list[float] = []
    ok = True
    for name, cm, bp in cases:
        secs: dict[str, float] = {}
        runs: dict[str, CheckResult] = {}
        for k in range(args.repeat * TINY_TIMES):
            # each round in another order, so that no engine always follows the same one
            for e in ENGINES[k % len(ENGINES) :] + ENGINES[: k % len(ENGINES)]:
                if k and (e not in runs or secs[e] >= SHORT):
                    continue
                if k >= args.repeat and secs[e] >= TINY:
                    continue
                r, cpu = once(cm, bp, e, args.timeout)
                if r.stats.stopped != "finished":
                    runs.pop(e, None)
                    secs[e] = math.inf
                    continue
                runs[e] = r
                took = cpu if args.clock == "cpu" else r.stats.seconds
                secs[e] = min(secs.get(e, math.inf), took)
        answers = {answer(r) for r in runs.values()}
        if len(answers) > 1:
            ok = False
            print(f"MISMATCH {name}: {answers}", file=sys.stderr)
        finished = {e: s for e, s in secs.items() if math.isfinite(s) and e != "auto"}
        best = min(finished, key=finished.__getitem__) if finished else None
        ratio = secs["auto"] / finished[best] if best else math.nan
        if math.isfinite(ratio):
            ratios.append(ratio)
        chose = runs["auto"].stats.extra.get("auto", "-") if "auto" in runs else "-"
        # the rule's own quality: the chosen engine's time run by itself against the best
        # (auto's time and its engine's differ only by the machine's jitter)
        rule = secs[chose] / finished[best] if best and chose in finished else math.nan
        if math.isfinite(rule):
            rules.append(rule)
        table.add_row(
            name,
            *(f"{secs[e]:.4f}" if math.isfinite(secs[e]) else "unfinished" for e in ENGINES),
            chose,
            best or "-",
            f"{ratio:.2f}x" if math.isfinite(ratio) else "-",
            f"{rule:.2f}x" if math.isfinite(rule) else "-",
        )
        print(f"done: {name}", file=sys.stderr, flush=True)
    Console(width=170).print(table)
    print(
        f"auto / best over {len(ratios)} instances: median {statistics.median(ratios):.2f}x,"
        f" worst {max(ratios):.2f}x; the chosen engine alone / best: median"
        f" {statistics.median(rules):.2f}x, worst {max(rules):.2f}x"
    )
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
