"""Benchmark: engine ``auto`` against every other engine, per instance (issue 62, item 4).

Run ``python benchmarks/bench_auto.py`` (``--quick``: n = 40 only, one draw; ``--only
TEXT``: the instances whose name contains TEXT). The set is
the knapsack instances of bench_knapsack.py (n = 40 and 80, weights up to 10^3 and
10^6, uncorrelated and strongly correlated costs, ``--draws`` instances each from seeds
``--seed-base``, ... drawn from the operating system and printed when not given) and
bench_engines.py's models (random layered models, robustness and resilience, and its
knapsacks). Every engine (``auto``, ``levels``, ``bnb``, ``enumerate``) checks each
instance through ``check_bound`` (the probe of small trees included, as a user gets it)
within ``--timeout`` seconds and ENUMERATE_BUDGET labels.

The runs of one instance are interleaved: ``--repeat`` rounds (default 7), each running
every engine once, the order rotated by one each round (auto, levels, bnb, enumerate;
then levels, bnb, enumerate, auto; ...), garbage collected before each run, so that the
machine's drift between runs falls on every engine alike. A short instance then gets more
rounds, until the fastest engine's median times the rounds reaches TARGET seconds (at
most MAX_TIMES x ``--repeat`` rounds), run by auto and the engines within CONTENDER x
the fastest; an engine whose first run took SHORT seconds or more runs LONG_RUNS times
only, and one that did not finish is not run again ("unfinished"). Each engine's figure
is the MEDIAN of its runs; auto / best is auto's median over the smallest median of the
other engines that finished, and chosen / best is the median of the engine ``auto``
chose (``enumerate``: the probe answered), run by itself, over the same: the rule's own
quality.

The seconds are the process's CPU time around ``check_bound`` (``--clock cpu``, the
default: on a shared machine the wall clock mostly measures the other jobs) or the
engine's own wall-clock seconds (``--clock wall``); the timeout is wall-clock either way.
"decide" is the CPU time of ``auto``'s decision alone (``auto.choose`` and
``auto.probes`` on the instance's search space, median of ``--repeat`` calls): what auto
spends before the engine it runs, so that an excess of auto / best over chosen / best is
either that or the jitter between runs. Every finished answer (optimum and θ*) must
equal the others' (else MISMATCH and exit 1). Target: the worst auto / best at most 1.2x.
Figures: docs/performance.md, "Issue 62, sixth round" and "seventh round".
"""

from __future__ import annotations

import argparse
import gc
import math
import os
import statistics
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_engines import knapsack_cases, layered_cases
from bench_knapsack import instance

from lesmc.common.budget import Budget
from lesmc.engines.auto import choose, probes
from lesmc.engines.check import check_bound
from lesmc.engines.result import CheckResult
from lesmc.engines.space import Space, build_space
from lesmc.language.parser import parse_spec
from lesmc.language.semantics import BoundProperty, bind
from lesmc.model.arrays import ArrayModel
from lesmc.model.knapsack import Item, knapsack_lts, knapsack_spec
from lesmc.model.lts import LTS, to_arrays

#: The engines, in the first round's order (each later round rotated by one).
ENGINES = ("auto", "levels", "bnb", "enumerate")
#: Labels any engine may expand (enumerate's tree beyond it is "over budget").
ENUMERATE_BUDGET = 6_000_000
#: An engine whose first run took this many seconds or more runs LONG_RUNS times only.
SHORT = 1.0
LONG_RUNS = 3
#: After --repeat rounds, a short instance gets more, until the fastest engine's median
#: times the rounds reaches TARGET seconds, at most MAX_TIMES x --repeat rounds in all;
#: the extra rounds run auto and the engines within CONTENDER x the fastest median only
#: (a median of 7 runs of 3 ms still moves by 1.3x on a loaded 2-core machine).
TARGET = 1.0
MAX_TIMES = 3
CONTENDER = 2.0

Case = tuple[str, ArrayModel, BoundProperty]


@dataclass(frozen=True)
class Args:
    """How each instance is measured (the command line's ``--repeat``, ``--timeout``
    and ``--clock``)."""

    repeat: int = 7
    timeout: float = 20.0
    clock: str = "cpu"


def knapsack_set(draws: int, base: int, quick: bool) -> list[Case]:
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


def engines_set(quick: bool) -> list[Case]:
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
    """What every engine must agree on: the optimum and θ*."""
    return (math.inf if r.optimum is None else r.optimum, r.witness_value)


def rotated(k: int) -> tuple[str, ...]:
    """Round ``k``'s order: :data:`ENGINES` rotated by ``k``, so that no engine always
    runs first or always follows the same one."""
    i = k % len(ENGINES)
    return ENGINES[i:] + ENGINES[:i]


@dataclass
class Runs:
    """One instance's runs: each engine's seconds (one a round it ran) and its last
    answer; an engine that once did not finish is ``unfinished`` and not run again."""

    secs: dict[str, list[float]] = field(default_factory=dict)
    results: dict[str, CheckResult] = field(default_factory=dict)
    unfinished: set[str] = field(default_factory=set)
    extra: set[str] = field(default_factory=set)  #: the engines run past --repeat

    def median(self, engine: str) -> float:
        """The engine's median seconds; inf when it did not finish."""
        if engine in self.unfinished or not self.secs.get(engine):
            return math.inf
        return statistics.median(self.secs[engine])

    def due(self, engine: str, k: int, repeat: int) -> bool:
        """Whether ``engine`` runs in round ``k`` (the module's docstring gives the rule)."""
        if engine in self.unfinished:
            return False
        if k >= repeat:
            return engine in self.extra
        return k == 0 or k < LONG_RUNS or self.secs[engine][0] < SHORT

    def extend(self, repeat: int) -> int:
        """The rounds in all, after ``repeat``: more for a short instance (TARGET), run
        by auto and the engines close to the fastest (:attr:`extra`)."""
        med = {e: self.median(e) for e in ENGINES if math.isfinite(self.median(e))}
        if not med:
            return repeat
        fastest = max(min(med.values()), 1e-9)
        self.extra = {e for e, s in med.items() if e == "auto" or s <= CONTENDER * fastest}
        return min(repeat * MAX_TIMES, max(repeat, math.ceil(TARGET / fastest)))


def one_round(runs: Runs, case: tuple[ArrayModel, BoundProperty], k: int, args: Args) -> None:
    """Round ``k``: each engine due in it once, in the round's rotated order."""
    for e in rotated(k):
        if not runs.due(e, k, args.repeat):
            continue
        r, cpu = once(*case, e, args.timeout)
        if r.stats.stopped != "finished":
            runs.unfinished.add(e)
            runs.results.pop(e, None)
            continue
        runs.results[e] = r
        runs.secs.setdefault(e, []).append(cpu if args.clock == "cpu" else r.stats.seconds)


def measure(cm: ArrayModel, bp: BoundProperty, args: Args) -> Runs:
    """Every engine on one instance, in interleaved rotated rounds: ``args.repeat``,
    then more for a short instance (:meth:`Runs.extend`)."""
    runs = Runs()
    for k in range(args.repeat):
        one_round(runs, (cm, bp), k, args)
    for k in range(args.repeat, runs.extend(args.repeat)):
        one_round(runs, (cm, bp), k, args)
    return runs


def decide_seconds(cm: ArrayModel, bp: BoundProperty, repeat: int) -> float:
    """CPU seconds of ``auto``'s decision alone (``choose``, and ``probes`` on an explicit
    model): the median of ``repeat`` calls on the instance's search space."""
    space = build_space(cm, bp)
    took = []
    for _ in range(repeat):
        t = time.process_time()
        choose(space)
        if isinstance(space, Space):
            probes(space)
        took.append(time.process_time() - t)
    return statistics.median(took)


@dataclass
class Row:
    """One instance's figures."""

    name: str
    medians: dict[str, float]
    chose: str
    best: str | None
    ratio: float  #: auto / best
    rule: float  #: chosen / best
    decide: float  #: seconds of auto's decision
    spread: float  #: auto's slowest run over its fastest


def row(name: str, runs: Runs, decide: float) -> Row:
    """The figures of one instance's runs."""
    med = {e: runs.median(e) for e in ENGINES}
    others = {e: s for e, s in med.items() if math.isfinite(s) and e != "auto"}
    best = min(others, key=others.__getitem__) if others else None
    res = runs.results.get("auto")
    chose = str(res.stats.extra.get("auto", "-")) if res is not None else "-"
    ratio = med["auto"] / others[best] if best else math.nan
    rule = others[chose] / others[best] if best and chose in others else math.nan
    auto = runs.secs.get("auto", [])
    spread = max(auto) / min(auto) if auto and min(auto) > 0 else math.nan
    return Row(name, med, chose, best, ratio, rule, decide, spread)


def mismatch(name: str, runs: Runs) -> bool:
    """Whether the finished engines disagree on the optimum or θ* (printed if so)."""
    answers = {answer(r) for r in runs.results.values()}
    if len(answers) > 1:
        print(f"MISMATCH {name}: {answers}", file=sys.stderr)
    return len(answers) > 1


def ratio_text(x: float) -> str:
    """A ratio as ``1.03x``; ``-`` where there is none."""
    return f"{x:.2f}x" if math.isfinite(x) else "-"


def table(rows: list[Row], clock: str) -> Table:
    """The per-instance table."""
    t = Table(title=f"auto against every engine: median {clock} seconds, interleaved runs")
    cols = ("instance", *ENGINES, "auto chose", "best", "auto / best", "chosen / best")
    for col in (*cols, "decide ms", "auto spread"):
        t.add_column(col, justify="left" if col == "instance" else "right")
    for r in rows:
        t.add_row(
            r.name,
            *(
                f"{r.medians[e]:.4f}" if math.isfinite(r.medians[e]) else "unfinished"
                for e in ENGINES
            ),
            r.chose,
            r.best or "-",
            ratio_text(r.ratio),
            ratio_text(r.rule),
            f"{r.decide * 1e3:.3f}",
            ratio_text(r.spread),
        )
    return t


def summary(rows: list[Row]) -> str:
    """The medians and worsts over the instances, and auto's decision against its time."""
    ratios = [r.ratio for r in rows if math.isfinite(r.ratio)]
    if not ratios:
        return "no instance where auto and another engine finished"
    rules = [r.rule for r in rows if math.isfinite(r.rule)] or [math.nan]
    share = [r.decide / r.medians["auto"] for r in rows if math.isfinite(r.ratio)]
    worst = max((r for r in rows if math.isfinite(r.ratio)), key=lambda r: r.ratio)
    return (
        f"auto / best over {len(ratios)} instances: median {statistics.median(ratios):.2f}x,"
        f" worst {max(ratios):.2f}x ({worst.name}: chosen / best {ratio_text(worst.rule)},"
        f" decide {worst.decide * 1e3:.3f} ms of {worst.medians['auto'] * 1e3:.1f} ms);"
        f" chosen / best: median {statistics.median(rules):.2f}x, worst {max(rules):.2f}x;"
        f" decide: median {statistics.median(r.decide for r in rows) * 1e3:.3f} ms,"
        f" at most {max(r.decide for r in rows) * 1e3:.3f} ms,"
        f" at most {100 * max(share):.2f}% of auto's time"
    )


def seed_base(given: int | None, draws: int) -> int:
    """``--seed-base``, or one drawn from the operating system; printed either way."""
    base = (1 << 16) + int.from_bytes(os.urandom(4), "little") if given is None else given
    print(f"seed base {base} (repeat with --seed-base {base} --draws {draws})", flush=True)
    return base


def parse_args() -> argparse.Namespace:
    """The command line (the module's docstring says what each option does)."""
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="n = 40 knapsacks, fewer models")
    ap.add_argument("--timeout", type=float, default=20.0)
    ap.add_argument("--repeat", type=int, default=7, help="interleaved rounds (default 7)")
    ap.add_argument("--seed-base", type=int, default=None)
    ap.add_argument("--draws", type=int, default=1)
    ap.add_argument("--only", default="", help="the instances whose name contains this text")
    ap.add_argument(
        "--clock",
        choices=("cpu", "wall"),
        default="cpu",
        help="seconds compared: this process's CPU time (default: free of the other jobs"
        " of a shared machine) or the engine's own wall-clock seconds",
    )
    return ap.parse_args()


def main() -> int:
    """Measure every instance; the table, the summary; 1 on a mismatch."""
    args = parse_args()
    base = seed_base(args.seed_base, args.draws)
    cases = knapsack_set(args.draws, base, args.quick) + engines_set(args.quick)
    cases = [c for c in cases if args.only in c[0]]
    if not cases:
        print(f"bench_auto.py: no instance's name contains {args.only!r}", file=sys.stderr)
        return 2
    for e in ENGINES:  # imports and first calls out of the figures
        once(*cases[-1][1:], e, args.timeout)
    rows, ok = [], True
    for name, cm, bp in cases:
        runs = measure(cm, bp, Args(args.repeat, args.timeout, args.clock))
        ok = not mismatch(name, runs) and ok
        rows.append(row(name, runs, decide_seconds(cm, bp, args.repeat)))
        print(f"done: {name}", file=sys.stderr, flush=True)
    Console(width=200).print(table(rows, args.clock))
    print(summary(rows))
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
