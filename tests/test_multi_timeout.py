"""``--timeout`` bounds a multi-target check (issue 58): the unfolding and the search of
``--design sort|gnn`` look at the budget's deadline, and past it the property is
``unknown`` (exit status 3) with the reason, the states explored, the bounds and the best
attack found, as the point designs report a timeout; ``lesmc check``, ``lesmc.check``
and a campaign's units honour it, and usage errors come before the clock.

Whether a run cannot finish is decided by state count, not by the machine's speed: the
command-line runs use a deadline of 1e-9 s (past before the first look at the clock), and
the engine's stops are forced at a chosen look by a budget that counts its looks."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np
import pytest
from cli_run import lesmc

import lesmc as api
from lesmc.campaign.plan import Group, Unit
from lesmc.campaign.work import run_group
from lesmc.common.budget import Budget, SearchBudget
from lesmc.common.errors import BudgetError
from lesmc.engines import multi as engine
from lesmc.engines.multi import check_multi
from lesmc.language.parser import parse_spec
from lesmc.model.multi import MultiModel
from lesmc.pipeline import multi as pipeline
from lesmc.pipeline.multi import bind_multi, build_for, build_key, check_multi_design
from lesmc.schemas import schema
from lesmc.tracking.targets import TargetSpec
from lesmc.unfold.multi import UnfoldStopped

pytest.importorskip("sort_tracker")
# the two identity properties tests/test_multi_api.py checks without a clock
from test_multi_api import SPEC
from test_multi_attack import _brute, _doc, _frames, _reference_boxes, _score


def _small(tmp_path: Path, window: str = "2..3") -> tuple[Path, Path, list[Any], list[Any]]:
    """Three objects crossing in 5 frames (tests/test_multi_attack.py's generator)."""
    rng = np.random.default_rng(11)
    frames = _frames(rng, 5)
    pay = [rng.integers(1, 6, len(f)).astype(float) for f in frames]
    scene = tmp_path / "small.json"
    scene.write_text(json.dumps(_doc(frames, pay)))
    spec = tmp_path / "small.spec"
    lo, hi = window.split("..")
    spec.write_text(SPEC.format(l=lo, u=hi))
    return scene, spec, frames, pay


def _big(tmp_path: Path) -> tuple[Path, Path]:
    """14 frames of 9 detections each (the crossing objects and clutter), every detection
    attackable at steps 1..12: 2^9 subsets a frame, far more states than any check of a
    test lists."""
    rng = np.random.default_rng(3)
    frames = []
    for f in _frames(rng, 14):
        centres = rng.uniform(150, 400, (9 - len(f), 2))
        sizes = rng.uniform(10, 20, (9 - len(f), 2))
        clutter = np.hstack([centres - sizes / 2, centres + sizes / 2])
        frames.append(np.vstack([f, clutter]))
    pay = [rng.integers(1, 6, len(f)).astype(float) for f in frames]
    scene = tmp_path / "big.json"
    scene.write_text(json.dumps(_doc(frames, pay)))
    spec = tmp_path / "big.spec"
    spec.write_text(SPEC.format(l=1, u=12))
    return scene, spec


class _Looks(SearchBudget):
    """A deadline that passes at the ``n``-th look at the clock (0: the first), whatever
    the machine's speed; the estimate of work still to come never stops it."""

    def __init__(self, n: int) -> None:
        super().__init__(None, None)
        self.n = n
        self.looks = 0

    def over(self, more: int = 0) -> str | None:
        self.looks += 1
        return "timeout" if self.looks > self.n else None

    def would_pass(self, seconds: float) -> str | None:
        return None


# ------------------------------------------------------------------- the command line


def test_a_tiny_timeout_is_unknown_with_exit_3_through_the_cli(tmp_path: Path) -> None:
    scene, spec = _big(tmp_path)
    r = lesmc("check", str(scene), str(spec), "--design", "sort", "--timeout", "1e-9", "--json")
    assert "Traceback" not in r.stderr, r.stderr
    assert r.returncode == 3, r.stderr
    doc = json.loads(r.stdout)
    jsonschema.validate(doc, schema("multi-check"))
    assert [x["property"] for x in doc["results"]] == ["hijack", "lose"]
    for res in doc["results"]:
        assert res["verdict"] == "unknown" and res["optimum"] == "unknown"
        assert res["stopped"] == "timeout"
        assert res["bounds"] == {"lower": "-inf", "upper": "inf"}
        assert res["counterexample"] is None
        assert res["states"] == 1 and res["states_expanded"] == 0  # step 0 alone
        assert any("timeout" in n for n in res["notes"])


def test_usage_errors_come_before_the_clock(tmp_path: Path) -> None:
    """With a deadline long past when the options are checked, a refused option is still
    the usage error (exit 2), not a timeout (exit 3)."""
    scene, spec = _big(tmp_path)
    r = lesmc(
        "check", str(scene), str(spec), "--design", "sort", "--timeout", "1e-9", "--engine", "bnb"
    )
    assert "Traceback" not in r.stderr, r.stderr
    assert r.returncode == 2, r.stderr
    assert "--engine" in r.stderr and "timeout ran out" not in r.stderr


# ------------------------------------------------------------------------- the Python API


def test_a_generous_timeout_gives_the_optimum_of_no_timeout_and_the_brute_force(
    tmp_path: Path,
) -> None:
    scene, spec, frames, pay = _small(tmp_path)
    free = api.check(scene, spec)
    timed = api.check(scene, spec, timeout=600.0)
    assert [r.to_dict() for r in timed] == [r.to_dict() for r in free]
    assert all(r.stopped == "finished" and r.bounds is None for r in timed)
    runs = _brute(frames, pay, 2, 3)
    refs = _reference_boxes(frames)
    end = len(frames) - 1
    for r, cost_of, which in zip(timed, (0, 1), (0, 1), strict=True):
        want = min(
            (x[cost_of] for x in runs if _score(x[3], refs, 0, end)[which] > 0),
            default=math.inf,
        )
        assert r.optimum == want, (r.property, r.optimum, want)


def test_the_api_takes_a_timeout_on_a_scene_and_on_a_built_model(tmp_path: Path) -> None:
    scene, spec = _big(tmp_path)
    got = api.check(scene, spec, designs="sort", timeout=1e-9)
    assert [(r.verdict, r.stopped, r.optimum_known) for r in got] == [
        ("unknown", "timeout", False)
    ] * 2
    small, small_spec, _, _ = _small(tmp_path)
    model = api.build(small, None, spec=small_spec, property="hijack")
    assert isinstance(model, MultiModel)
    (r,) = api.check(model, small_spec, only="hijack", timeout=1e-9)
    assert r.verdict == "unknown" and r.stopped == "timeout" and r.states_expanded == 0
    assert r.states == model.n_states  # the model was there whole: the search stopped


def test_build_takes_a_timeout_too(tmp_path: Path) -> None:
    """``lesmc.build`` and ``lesmc build`` of a multi-target design: past the timeout a
    BudgetError (exit 3, nothing written); within it, the model built without one."""
    scene, spec = _big(tmp_path)
    with pytest.raises(BudgetError, match=r"timeout=1e-09 s ran out while unfolding"):
        api.build(scene, None, spec=spec, property="hijack", timeout=1e-9)
    out = tmp_path / "m.npz"
    args = ("--spec", str(spec), "--property", "hijack", "--timeout", "1e-9", "-o", str(out))
    r = lesmc("build", str(scene), *args)
    assert "Traceback" not in r.stderr, r.stderr
    assert r.returncode == 3 and "--timeout 1e-09 s ran out" in r.stderr, r.stderr
    assert not out.exists()
    small, small_spec, _, _ = _small(tmp_path)
    free = api.build(small, None, spec=small_spec, property="lose")
    timed = api.build(small, None, spec=small_spec, property="lose", timeout=600.0)
    assert isinstance(free, MultiModel) and isinstance(timed, MultiModel)
    assert (timed.n_states, timed.n_transitions) == (free.n_states, free.n_transitions)
    assert np.array_equal(timed.dst, free.dst) and np.array_equal(timed.payoff, free.payoff)


# ------------------------------------------------------------------ the engine's stops


#: Properties whose optimum on the small scene is finite, by payoff and by frames.
LOSE = """property lose_payoff {{ attack window 2..4 minimize payoff
  subject to lost(0..end) > 0 holds if optimum > 3 }}
property lose_frames {{ attack window 2..4 minimize count.frames
  subject to lost(0..end) > 0 holds if optimum > 1 }}
"""


def _model_and_property(tmp_path: Path, name: str) -> tuple[MultiModel, Any]:
    scene, _, _, _ = _small(tmp_path, "2..4")
    sc = api.load_scene(scene)
    sp = parse_spec(LOSE.format(), "lose.spec")
    (prop,) = [p for p in sp.properties if p.name == name]
    b = bind_multi(sp, prop, len(sc.frames) - 1)
    return build_for(sc, str(scene), build_key(b)), b


@pytest.mark.parametrize("name", ["lose_payoff", "lose_frames"])
def test_a_search_stopped_anywhere_brackets_the_exact_optimum(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, name: str
) -> None:
    """Stopped at each of many looks at the clock, the search's lower bound and incumbent
    bracket the optimum of the search run to the end, and the incumbent's path costs what
    it claims (its transitions' payoffs, or the frames it attacks)."""
    model, b = _model_and_property(tmp_path, name)
    exact = check_multi(model, b)
    assert exact.stopped == "finished" and math.isfinite(exact.optimum)
    monkeypatch.setattr(engine, "CLOCK_EVERY", 7)
    looks = model.n_states // 7 + 1
    uppers = []
    for n in sorted(
        {n for n in (0, 1, looks // 4, looks // 2, looks - 2) if 7 * n < model.n_states}
    ):
        got = check_multi(model, b, _Looks(n))
        assert got.stopped == "timeout" and got.expanded == 7 * n
        assert got.lower <= exact.optimum <= got.optimum, (n, got.lower, got.optimum)
        uppers.append(got.optimum)
        if got.path is None:
            continue
        steps = [int(model.step[model.dst[t]]) for t in got.path]
        assert steps == list(range(1, model.end + 1))
        cost = (
            float(sum(model.payoff[list(got.path)]))
            if name == "lose_payoff"
            else float(sum(1 for t in got.path if model.count[t] > 0))
        )
        assert cost == got.optimum
    assert uppers[0] == math.inf and any(math.isfinite(u) for u in uppers)


def test_an_unfolding_stopped_at_a_step_reports_the_states_made_before_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The unfolding looks at the clock before each step: stopped at the k-th look, it has
    made the states of steps 0..k-1 of the whole model; the check is then unknown."""
    scene, spec, _, _ = _small(tmp_path, "2..4")
    sc = api.load_scene(scene)
    sp = parse_spec(spec.read_text(), str(spec))
    (prop,) = [p for p in sp.properties if p.name == "hijack"]
    key = build_key(bind_multi(sp, prop, len(sc.frames) - 1))
    whole = build_for(sc, str(scene), key)
    for k in range(1, whole.end + 1):
        with pytest.raises(UnfoldStopped) as stop:
            build_for(sc, str(scene), key, None, _Looks(k - 1))
        assert (stop.value.step, stop.value.reason) == (k, "timeout")
        assert stop.value.states == int((whole.step < k).sum()), k
    monkeypatch.setattr(pipeline, "_search", lambda _budget: _Looks(2))
    (r,) = check_multi_design(sc, str(scene), (sp,), ("hijack",), None, False, Budget(600.0))
    assert r.verdict == "unknown" and r.stopped == "timeout" and r.counterexample is None
    assert r.states == int((whole.step < 3).sum()) and r.states_expanded == 0
    assert "before step 3" in r.notes[0]


# --------------------------------------------------------------------------- campaigns


def _group(scene: Path, spec: Path, timeout: float | None) -> tuple[Group, dict[str, Any]]:
    doc = json.loads(scene.read_text())
    x, y = doc["target"]["start"]
    units = tuple(Unit(f"k-{p}", (2, 3), "sort", p) for p in ("hijack", "lose"))
    group = Group(
        "small",
        "small-key",
        TargetSpec(x, y, 0),
        "sort",
        units,
        ((str(spec), spec.read_text()),),
        timeout,
        None,
        scene_file=str(scene),
    )
    return group, doc


def test_a_campaign_unit_past_its_timeout_is_an_unknown_row(tmp_path: Path) -> None:
    scene, spec, _, _ = _small(tmp_path)
    group, doc = _group(scene, spec, 1e-9)
    rows = run_group(group, doc)
    assert [r["property"] for r in rows] == ["hijack", "lose"]
    for row in rows:
        assert row["verdict"] == row["status"] == "unknown"
        assert row["optimum"] == "unknown" and row["bounds"] == ["-inf", "inf"]
        assert row["stats"]["stopped"] == "timeout" and row["stats"]["states_expanded"] == 0
        props = schema("campaign-row")["properties"]
        for key in ("optimum", "bounds", "stats", "status"):
            jsonschema.validate(row[key], props[key] | {"$defs": schema("campaign-row")["$defs"]})
    group, doc = _group(scene, spec, 600.0)
    want = {r.property: r for r in api.check(scene, spec)}
    for row in run_group(group, doc):
        r = want[row["property"]]
        assert row["stats"]["stopped"] == "finished" and row["verdict"] == r.verdict
        assert row["optimum"] == ("inf" if math.isinf(r.optimum) else r.optimum)
