"""benchmarks/bench_auto.py (issue 62, item 4): its runs interleaved in rotated rounds,
each engine's figure the median of its runs, auto / best the medians' ratio, and auto's
decision timed apart. The engines' runs are replaced by a script of seconds here, so the
figures are checked against sums done by hand; one real instance checks the decision's
timing and the whole table's path through ``check_bound``."""

from __future__ import annotations

import importlib.util
import math
import os
import subprocess
import sys
from collections.abc import Iterator
from types import ModuleType, SimpleNamespace
from typing import Any

import pytest
from cli_run import ROOT


def _bench() -> ModuleType:
    """benchmarks/bench_auto.py as a module (benchmarks/ is no package)."""
    path = ROOT / "benchmarks" / "bench_auto.py"
    spec = importlib.util.spec_from_file_location("bench_auto", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["bench_auto"] = module
    spec.loader.exec_module(module)
    return module


bench = _bench()
ENGINES = ("auto", "levels", "bnb", "enumerate")


def _fake(secs: dict[str, list[float]], chose: str = "levels") -> tuple[list[str], Any]:
    """A stand-in for ``bench.once``: engine e's i-th run takes ``secs[e][i]`` seconds
    (nan: it does not finish); the calls are recorded in the list returned."""
    calls: list[str] = []
    left: dict[str, Iterator[float]] = {e: iter(s) for e, s in secs.items()}

    def once(cm: object, bp: object, engine: str, timeout: float) -> tuple[Any, float]:
        calls.append(engine)
        took = next(left[engine])
        stats = SimpleNamespace(
            stopped="timeout" if math.isnan(took) else "finished",
            seconds=took,
            extra={"auto": chose} if engine == "auto" else {},
        )
        return SimpleNamespace(stats=stats, optimum=7.0, witness_value=5.0), took

    return calls, once


def test_the_rounds_are_rotated_so_each_engine_holds_each_place_once() -> None:
    assert bench.ENGINES == ENGINES
    orders = [bench.rotated(k) for k in range(4)]
    assert orders[0] == ENGINES
    assert orders[1] == ("levels", "bnb", "enumerate", "auto")
    for place in range(4):
        assert sorted(o[place] for o in orders) == sorted(ENGINES)
    assert bench.rotated(5) == orders[1]


def test_runs_are_interleaved_and_each_engine_reads_its_median(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Five rounds of runs of 0.1-0.5 s (five times the fastest median is past TARGET:
    no more rounds)."""
    secs = {
        "auto": [0.30, 0.10, 0.50, 0.12, 0.11],  # median 0.12 (the best of them: 0.10)
        "levels": [0.11, 0.13, 0.09, 0.20, 0.10],  # median 0.11
        "bnb": [0.40, 0.41, 0.42, 0.43, 0.44],
        "enumerate": [math.nan],  # does not finish: run once
    }
    calls, once = _fake(secs)
    monkeypatch.setattr(bench, "once", once)
    monkeypatch.setattr(bench, "TARGET", 0.5)
    runs = bench.measure(None, None, bench.Args(5))
    first = ["auto", "levels", "bnb", "enumerate"]
    assert calls[:4] == first
    assert calls[4:7] == ["levels", "bnb", "auto"]  # round 1: rotated, enumerate left out
    assert calls[7:10] == ["bnb", "auto", "levels"]
    assert len(calls) == 4 + 4 * 3
    assert runs.median("auto") == pytest.approx(0.12)
    assert runs.median("levels") == pytest.approx(0.11)
    assert runs.median("enumerate") == math.inf
    r = bench.row("x", runs, 0.001)
    assert r.best == "levels"
    assert r.chose == "levels"
    assert r.ratio == pytest.approx(0.12 / 0.11)  # the old best-of-runs said 0.10 / 0.09
    assert r.rule == pytest.approx(1.0)
    assert r.spread == pytest.approx(0.50 / 0.10)


def test_a_short_instance_gets_more_rounds_for_auto_and_the_close_engines(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Medians of 2 and 3 ms: TARGET / 2 ms rounds (at most MAX_TIMES x repeat) for auto
    and levels (within CONTENDER x 2 ms); repeat runs for bnb (100x slower) and LONG_RUNS
    for enumerate (past SHORT)."""
    repeat = 4
    monkeypatch.setattr(bench, "TARGET", 0.02)  # 10 rounds of 2 ms
    secs = {
        "auto": [0.002] * 10,
        "levels": [0.003] * 10,
        "bnb": [0.2] * 4,
        "enumerate": [2.0] * 3,
    }
    calls, once = _fake(secs, chose="enumerate")
    monkeypatch.setattr(bench, "once", once)
    runs = bench.measure(None, None, bench.Args(repeat))
    assert bench.LONG_RUNS == 3 and bench.CONTENDER >= 1.5
    assert {e: calls.count(e) for e in ENGINES} == {
        "auto": 10,
        "levels": 10,
        "bnb": 4,
        "enumerate": 3,
    }
    assert bench.MAX_TIMES * repeat >= 10
    assert calls[-2:] == ["levels", "auto"]  # round 9: levels, bnb, enumerate, auto
    r = bench.row("x", runs, 0.0)
    assert r.best == "levels"
    assert r.ratio == pytest.approx(2 / 3)
    assert r.rule == pytest.approx(2.0 / 0.003)


def test_the_extra_rounds_are_capped(monkeypatch: pytest.MonkeyPatch) -> None:
    """Runs of 1 µs: MAX_TIMES x repeat rounds, not TARGET / 1 µs."""
    calls, once = _fake({e: [1e-6] * 1000 for e in ENGINES})
    monkeypatch.setattr(bench, "once", once)
    bench.measure(None, None, bench.Args(2))
    assert calls.count("auto") == 2 * bench.MAX_TIMES
    assert calls.count("enumerate") == 2 * bench.MAX_TIMES


def test_wall_clock_reads_the_engines_own_seconds(monkeypatch: pytest.MonkeyPatch) -> None:
    _, once = _fake({e: [0.2, 0.4, 0.3] for e in ENGINES})

    def slower(cm: object, bp: object, engine: str, timeout: float) -> tuple[Any, float]:
        r, took = once(cm, bp, engine, timeout)
        return r, 10 * took  # CPU seconds that wall-clock mode must not read

    monkeypatch.setattr(bench, "once", slower)
    monkeypatch.setattr(bench, "TARGET", 0.1)
    runs = bench.measure(None, None, bench.Args(3, 20.0, "wall"))
    assert runs.median("bnb") == pytest.approx(0.3)


def test_a_mismatch_is_found(capsys: pytest.CaptureFixture[str]) -> None:
    runs = bench.Runs()
    runs.results = {
        "auto": SimpleNamespace(optimum=3.0, witness_value=1.0),
        "levels": SimpleNamespace(optimum=3.0, witness_value=2.0),
    }
    assert bench.mismatch("inst", runs)
    assert "MISMATCH inst" in capsys.readouterr().err
    runs.results["levels"] = SimpleNamespace(optimum=3.0, witness_value=1.0)
    assert not bench.mismatch("inst", runs)


def test_one_real_knapsack_through_check_bound(monkeypatch: pytest.MonkeyPatch) -> None:
    """n = 20, one round: every engine finishes with the same optimum, auto chooses
    ``levels``, and its decision takes a sliver of its run."""
    cm, bp = bench.engines_set(True)[-2][1:]  # bench_engines' knapsack n = 20
    monkeypatch.setattr(bench, "TARGET", 0.0)  # one round
    runs = bench.measure(cm, bp, bench.Args(1, 60.0))
    assert not bench.mismatch("n=20", runs)
    assert set(runs.results) == set(ENGINES)
    decide = bench.decide_seconds(cm, bp, 3)
    r = bench.row("n=20", runs, decide)
    assert r.chose == "levels"
    assert 0 < decide < r.medians["auto"]
    table = bench.table([r], "cpu")
    assert table.row_count == 1
    assert "auto / best over 1 instances" in bench.summary([r])


def test_the_summary_of_instances_no_two_engines_finished() -> None:
    med = dict.fromkeys(ENGINES, math.inf)
    r = bench.Row("n=80", med, "-", None, math.nan, math.nan, 0.001, math.nan)
    assert bench.summary([r]) == "no instance where auto and another engine finished"


def test_the_pairs_script_alternates_auto_and_its_partner() -> None:
    """benchmarks/bench_auto_pairs.py through its command line: 3 pairs on a small
    layered model; an unknown name exits 2 with a one-line message and no traceback."""
    script = str(ROOT / "benchmarks" / "bench_auto_pairs.py")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    run = [sys.executable, script, "--pairs", "3", "--engine", "bnb", "--only"]
    ok = subprocess.run([*run, "b=2 w=8 resilience"], capture_output=True, text=True, env=env)
    assert ok.returncode == 0, ok.stderr
    assert "layered b=2 w=8 resilience: 3 pairs" in ok.stdout
    assert "auto / bnb (medians)" in ok.stdout
    bad = subprocess.run([*run, "no such instance"], capture_output=True, text=True, env=env)
    assert bad.returncode == 2
    assert bad.stderr == "bench_auto_pairs.py: no instance's name contains 'no such instance'\n"
