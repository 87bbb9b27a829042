"""The dead root under a monitor (lesmc/tracking/parts/relaxed.py, asked by
lesmc/engines/lazy.py ``DEAD_ROOT``; docs/semantics.md, "A root no monitored path
leaves") against the explicit model: whenever the relaxation of the joint design to its
primary says that no path from the window's root passes Eq. 13's monitor to the end, no
path of the whole model (built by unfold.build_model, hide + inject) does, checked path
by path with τ written out here; and the checker's results are the same with and without
the test."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from cli_run import lesmc
from test_inject_joint import random_scene

import lesmc.engines.lazy as lazy
import lesmc.unfold.unfold as unfold
from lesmc import api
from lesmc.model.arrays import ArrayModel
from lesmc.scene import Scene, save_scene
from lesmc.tracking.trackers import make_tracker

TOL = 1e-9  # Eq. 13's default tolerance (monitor uncertainty)


def _tau(P: np.ndarray, pos: tuple[int, ...]) -> float:
    """Eq. 12: the trace of P's position block, written out."""
    return float(sum(P[i, i] for i in pos))


def _survives(cm: ArrayModel, l: int, pos: tuple[int, ...]) -> bool:
    """Some path of the explicit model from the window's root to a leaf has no transition
    into a step >= l on which τ rises by more than TOL (relatively)."""
    root = int(cm.original[l - 1])
    todo, seen = [root], {root}
    while todo:
        q = todo.pop()
        lo, hi = int(cm.ptr[q]), int(cm.ptr[q + 1])
        if lo == hi:
            return True
        t0 = _tau(cm.P_table[int(cm.cov[q])], pos)
        for t in range(lo, hi):
            d = int(cm.dst[t])
            rises = _tau(cm.P_table[int(cm.cov[d])], pos) > t0 * (1 + TOL)
            if (int(cm.step[d]) >= l and rises) or d in seen:
                continue
            seen.add(d)
            todo.append(d)
    return False


def _relaxed(scene: Scene, window: tuple[int, int], end: int) -> bool | None:
    """The relaxation's answer for the window's root (None: no answer)."""
    model = unfold.lazy_model(scene, window, end, inject=True)
    pos = scene.tracker.measured

    def cut(k: int, p0: np.ndarray, p1: np.ndarray) -> bool:
        return k >= window[0] and _tau(p1, pos) > _tau(p0, pos) * (1 + TOL)

    ask = model.expander.primary_alive  # type: ignore[union-attr]
    return ask(int(model.original[window[0] - 1]), end, cut)  # type: ignore[no-any-return]


def _cases(n: int, seed: int) -> list[tuple[Scene, tuple[int, int], int]]:
    """Random joint scenes with injection candidates and a window of one or two steps."""
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < n:
        scene = random_scene(rng)
        end = unfold.original_end(scene, make_tracker(scene))
        if end < 2:
            continue
        lo = int(rng.integers(1, end))
        out.append((scene, (lo, min(end, lo + int(rng.integers(0, 2)))), end))
    return out


def test_a_dead_root_has_no_path_the_monitor_allows() -> None:
    """Sound: every root the relaxation calls dead has no monitored path in the explicit
    model; and the test fires on some of these scenes (else it would check nothing)."""
    dead = alive = 0
    for scene, window, end in _cases(60, 61):
        got = _relaxed(scene, window, end)
        assert got is not None
        cm = unfold.build_model(scene, window, end, inject=True)
        survives = _survives(cm, window[0], scene.tracker.measured)
        if not got:
            assert not survives, window
        dead += not got
        alive += survives
    assert dead and alive


def _spec(window: tuple[int, int], end: int) -> str:
    return (
        f"property p {{ attack window {window[0]}..{window[1]} allow hide, inject end {end} "
        "minimize payoff subject to dist.max(0..end) > 3 holds if optimum > 1000 "
        "monitor uncertainty }\n"
    )


def _results(scene: Scene, window: tuple[int, int], end: int) -> tuple[object, ...]:
    res = api.check(scene, api.parse_spec(_spec(window, end)))[0]
    opt = math.inf if res.optimum is None else float(res.optimum)
    return res.verdict, opt


@pytest.mark.parametrize("seed", [5, 6])
def test_checks_are_the_same_with_and_without_the_dead_root(
    seed: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The verdict and optimum of `lesmc check` under the monitor do not change when the
    dead-root test is switched off."""
    for scene, window, end in _cases(12, seed):
        with_test = _results(scene, window, end)
        monkeypatch.setattr(lazy, "DEAD_ROOT", False)
        without = _results(scene, window, end)
        monkeypatch.setattr(lazy, "DEAD_ROOT", True)
        assert with_test[0] == without[0]
        assert with_test[1] == pytest.approx(without[1], abs=1e-9)


def test_the_cli_says_holds_vacuous_for_a_dead_root(tmp_path: Path) -> None:
    """Through the real entry point: on a scene whose root the relaxation calls dead, `lesmc
    check --design improved` exits 0 with no traceback, and its verdict and optimum are those
    the API gives with the test switched off (the full search)."""
    scene, window, end = next(c for c in _cases(60, 61) if _relaxed(*c) is False)
    save_scene(scene, tmp_path / "scene.json")
    (tmp_path / "p.spec").write_text(_spec(window, end).replace("monitor uncertainty ", ""))
    run = lesmc(
        "check",
        str(tmp_path / "scene.json"),
        str(tmp_path / "p.spec"),
        "--design",
        "improved",
        "--json",
    )
    assert run.returncode == 0 and "Traceback" not in run.stderr, run.stderr
    got = json.loads(run.stdout)["results"][0]
    old = lazy.DEAD_ROOT
    try:
        lazy.DEAD_ROOT = False
        want = _results(scene.with_tracker(design="joint"), window, end)
    finally:
        lazy.DEAD_ROOT = old
    assert got["verdict"] == want[0] == "holds"
    assert got["optimum"] in ("inf", None, math.inf) and want[1] == math.inf
