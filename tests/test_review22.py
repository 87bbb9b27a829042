"""Round 22's review findings (task fixrep): a multi-target check stopped by its budget is
reported with the bounds and notes it proved, its path labelled the best attack found
(not a counterexample); verify's budget help says what a ``--design sort|gnn`` unfolding
past ``--timeout`` does; the detector file's per-frame loop of payoffs and bounds."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_run import lesmc
from markupsafe import escape

import lesmc as api
from lesmc.experiment.detector_verify import per_frame
from lesmc.language.parser import parse_spec

pytest.importorskip("sort_tracker")
from test_multi_timeout import LOSE, _big, _Looks, _small

from lesmc.engines import multi as engine
from lesmc.pipeline.multi import _result, bind_multi, build_for, build_key, multi_document
from lesmc.report.multi import render_multi

#: The verdict line's parenthesis of a stopped check: "... between LOWER and UPPER)".
BETWEEN = re.compile(r"the optimum lies between (\S+) and (\S+?)\)")


def _bounds_on(page: str) -> list[tuple[float, float]]:
    """Every (lower, upper) the page states, as numbers."""
    return [(float(lo), float(hi)) for lo, hi in BETWEEN.findall(page)]


def test_a_report_of_a_check_stopped_by_its_timeout_shows_its_bounds_and_notes(
    tmp_path: Path,
) -> None:
    """``lesmc check --design sort --timeout 1e-9 --json`` stops every property while
    unfolding (bounds -inf..inf); ``lesmc report`` on that document states the bounds and
    the notes, not only 'optimum unknown'."""
    scene, spec = _big(tmp_path)
    r = lesmc("check", str(scene), str(spec), "--design", "sort", "--timeout", "1e-9", "--json")
    assert "Traceback" not in r.stderr, r.stderr
    assert r.returncode == 3, r.stderr
    doc_path = tmp_path / "stopped.json"
    doc_path.write_text(r.stdout)
    doc = json.loads(r.stdout)
    out = tmp_path / "rep"
    rep = lesmc("report", str(doc_path), "--out", str(out))
    assert "Traceback" not in rep.stderr, rep.stderr
    assert rep.returncode == 0, rep.stderr
    page = (out / "report.html").read_text(encoding="utf-8")
    wanted = [(float(x["bounds"]["lower"]), float(x["bounds"]["upper"])) for x in doc["results"]]
    assert wanted == [(-math.inf, math.inf)] * 2
    # each property's line and its verdict-table cell
    assert sorted(_bounds_on(page)) == sorted(wanted * 2)
    for res in doc["results"]:
        assert res["notes"]
        for note in res["notes"]:
            assert str(escape(note)) in page, note
    assert "stopped by timeout" in page


def _stopped_with_a_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> dict[str, Any]:
    """A lesmc-multi-check document of a search stopped (at a chosen look at the clock,
    whatever the machine's speed) after it found an attack that decides nothing: lower
    bound <= the threshold 3 < the attack's cost, so the verdict is unknown."""
    scene, _, _, _ = _small(tmp_path, "2..4")
    sc = api.load_scene(scene)
    sp = parse_spec(LOSE.format(), "lose.spec")
    (prop,) = [p for p in sp.properties if p.name == "lose_payoff"]
    b = bind_multi(sp, prop, len(sc.frames) - 1)
    model = build_for(sc, str(scene), build_key(b))
    monkeypatch.setattr(engine, "CLOCK_EVERY", 7)
    for n in range(model.n_states // 7 + 1):
        res = _result(model, b, sc, str(scene), _Looks(n))
        if res.counterexample is not None and res.verdict == "unknown":
            return multi_document("sort", "unattacked", [res])
    raise AssertionError("no stopped search with an undecided attack on the small scene")


def test_a_stopped_checks_path_is_the_best_attack_found_not_a_counterexample(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    doc = _stopped_with_a_path(tmp_path, monkeypatch)
    (res,) = doc["results"]
    steps = res["counterexample"]
    # the path's cost, summed from its attacked detections, is the stated upper bound
    pay = {
        d["id"]: d["payoff"]
        for f in json.loads((tmp_path / "small.json").read_text())["frames"]
        for d in f["detections"]
    }
    cost = sum(pay[i] for s in steps for i in s["hidden"])
    assert cost == res["bounds"]["upper"] > 3 >= res["bounds"]["lower"]
    page, figs = render_multi(doc)
    assert figs  # the panels are drawn
    # the verdict line, the verdict table, and the panels' caption (and its alt text)
    assert _bounds_on(page) == [(res["bounds"]["lower"], cost)] * 4
    assert "every track of the attacked run of the best attack found" in page
    assert "The best attack found is not a counterexample" in page
    assert "counterexample&#39;s attacked run" not in page  # the old caption
    assert "attacked run of the counterexample" not in page


def test_verify_budget_help_says_a_multi_target_timeout_writes_unknown_results() -> None:
    r = lesmc("verify", "--help")
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    text = " ".join(r.stdout.split())
    assert "while perceiving or building a model, verify stops" not in text
    assert "--design sort|gnn unfolding past --timeout gives 'unknown' results" in text
    reference = (Path(__file__).parent.parent / "docs/cli-options.md").read_text()
    assert "--design sort\\|gnn unfolding past --timeout gives 'unknown'" in reference
    assert "while perceiving or building a model, verify stops" not in reference


def test_the_cli_page_says_box_detectors_are_priced_on_demand() -> None:
    text = " ".join((Path(__file__).parent.parent / "docs/cli.md").read_text().split())
    assert "a box-list detector or `--payoffs certified|interval`" not in text
    assert "a heatmap or box-list detector's payoffs priced when a checked model reads" in text


def test_per_frame_fills_the_wanted_detections_and_nan_elsewhere() -> None:
    positions = {0: np.zeros((3, 2)), 4: np.ones((5, 2))}
    wanted = {4: np.array([1, 3]), 0: np.array([2])}
    calls = []

    def value(k: int, pos: np.ndarray, idx: np.ndarray) -> np.ndarray:
        calls.append((k, len(pos), list(idx)))
        return 10.0 * k + idx

    out = per_frame(wanted, positions.__getitem__, value)
    assert calls == [(0, 3, [2]), (4, 5, [1, 3])]
    np.testing.assert_array_equal(out[0], [np.nan, np.nan, 2.0])
    np.testing.assert_array_equal(out[4], [np.nan, 41.0, np.nan, 43.0, np.nan])
