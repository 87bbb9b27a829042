"""Sensitivity sweeps (issue 30, item 2): each variant against the property checked on
its own (a spec edited as text, through the real CLI), and against the brute force."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from cli_run import lesmc
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from oracle import brute_force
from test_engines import _spec, cases

from lesmc.common.budget import Budget
from lesmc.engines.check import bind_all, check
from lesmc.language.parser import parse_spec
from lesmc.language.sweep import parse_sweep, swept
from lesmc.model import kernel
from lesmc.model.lts import to_arrays


def _rows(stdout: str) -> dict[str, tuple[str, object]]:
    return {r["property"]: (r["status"], r["optimum"]) for r in json.loads(stdout)["results"]}


def test_a_sweep_is_each_value_checked_alone(tmp_path: Path) -> None:
    """``--sweep eps=...`` and ``--sweep p=...``: every variant's verdict and optimum as
    the spec rewritten with that value and checked by itself."""
    r = lesmc("check", "examples/merge.json", "specs/robustness.spec", "specs/resilience.spec",
              "--sweep", "eps=0.5..160.5:40", "--sweep", "p=1,inf", "--json")  # fmt: skip
    assert r.returncode in (0, 1), r.stderr
    got = _rows(r.stdout)
    assert len(got) == 2 * 5 * 2
    for name, path in (
        ("robustness", "specs/robustness.spec"),
        ("resilience", "specs/resilience.spec"),
    ):
        text = Path(path).read_text()
        for eps in (0.5, 40.5, 80.5, 120.5, 160.5):
            for p, norm in (("1", "1"), ("inf", "inf")):
                lines = text.splitlines()
                lines = [_with_bound(ln, eps) for ln in lines]
                lines.insert(-1, f"    norm {norm}")
                edited = tmp_path / f"{name}.spec"
                edited.write_text("\n".join(lines) + "\n")
                one = lesmc("check", "examples/merge.json", str(edited), "--json")
                assert one.returncode in (0, 1), one.stderr
                assert got[f"{name}@eps={eps:g},p={p}"] == _rows(one.stdout)[name]
    assert {v[0] for v in got.values()} >= {"holds", "violated"}  # the verdict flips


def _with_bound(line: str, eps: float) -> str:
    if "subject to" not in line:
        return line
    head, _, _ = line.rpartition(" ")
    return f"{head} {eps!r}"


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cases(), st.lists(st.floats(-1, 50, allow_nan=False), min_size=1, max_size=4))
def test_every_variant_equals_the_brute_force(case: tuple, values: list[float]) -> None:
    model, params, _ = case
    spec = parse_spec(_spec(params, 0.0))
    sweep = parse_sweep("eps=" + ",".join(repr(v) for v in values))
    variants = swept(spec, (sweep,))
    cm = to_arrays(model)
    bound = bind_all(cm, [variants])
    assert [bp.bound for bp in bound] == values
    for bp, r in zip(bound, check(cm, [variants]), strict=True):
        truth = brute_force(model, bp).optimum
        assert r.optimum == math.inf if math.isinf(truth) else r.optimum == pytest.approx(truth)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    cases(),
    st.lists(st.floats(-1, 50, allow_nan=False), min_size=2, max_size=6),
    st.sampled_from(["levels", "bnb"]),
)
def test_a_sweep_too_large_to_walk_reuses_answers_exactly(
    case: tuple, values: list[float], engine: str
) -> None:
    """When the tree is too large to walk once (forced here), a sweep's variants are
    searched loosest first and a tighter one takes a looser one's answer when its
    counterexample qualifies (pipeline.payoffs._bound_families): every optimum,
    counterexample objective and θ* equals the brute force, and answers are reused."""
    from unittest.mock import patch

    from lesmc.pipeline.payoffs import check_all

    model, params, _ = case
    spec = parse_spec(_spec(params, 0.0))
    values = values + values[:1]  # a repeated value is always answered by reuse
    variants = swept(spec, (parse_sweep("eps=" + ",".join(repr(v) for v in values)),))
    cm = to_arrays(model)
    bound = bind_all(cm, [variants])
    with patch("lesmc.engines.enumerate.SMALL_TREE", 0):
        got = check_all(
            lambda _: cm,
            bound,
            "attack",
            engine,
            Budget(),
            lambda _: [],
            lambda _: None,  # type: ignore[arg-type]
        )
    for bp, r in zip(bound, got, strict=True):
        truth = brute_force(model, bp)
        assert r.stats.stopped == "finished"
        if math.isinf(truth.optimum):
            assert r.optimum == math.inf
        else:
            assert r.optimum == pytest.approx(truth.optimum, rel=1e-12, abs=1e-12)
            assert r.cheapest is not None
            assert r.cheapest.objective == pytest.approx(truth.optimum, rel=1e-12)
            assert kernel.compare(bp.op, r.cheapest.constraint, bp.bound)
        if truth.witness_value is None:
            assert r.witness is None
        else:
            assert r.witness_value == pytest.approx(truth.witness_value, rel=1e-12, abs=1e-12)
    assert any("answered_by" in r.stats.extra for r in got)


@pytest.mark.parametrize(
    ("sweep", "words"),
    [
        ("eps=10..5:1", "LO <= HI"),
        ("eps=1..2:0", "STEP > 0"),
        ("p=3", "1, 2 or inf"),
        ("gamma=1,2", "must look like"),
        ("eps=1,x", "numbers separated by commas"),
        ("eps=0..1e9:1", "at most 1000"),
    ],
)
def test_a_bad_sweep_is_refused(sweep: str, words: str) -> None:
    r = lesmc("check", "examples/merge.json", "specs/robustness.spec", "--sweep", sweep)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert words in r.stderr, r.stderr


def test_the_report_plots_each_swept_optimum_and_where_the_verdict_flips(tmp_path: Path) -> None:
    """``--sweep ... --report``: one figure per design whose curve holds each variant's
    optimum and verdict from results.json, with a flip between the values whose verdicts
    differ (lesmc.report.design_section.sweep_curves read against the document itself)."""
    from lesmc.report.design_section import sweep_curves as _sweep_curves
    from lesmc.results.read import results_of

    out = tmp_path / "rep"
    r = lesmc("check", "tests/scenes/rq1_platoon.json", "specs/robustness.spec",
              "--sweep", "eps=20..400:20", "--report", str(out), "--no-paths")  # fmt: skip
    assert r.returncode in (0, 1), r.stderr
    assert (out / "figures" / "single-sweep.png").stat().st_size > 1000
    assert "Sensitivity (single)" in (out / "report.html").read_text()
    doc = json.loads((out / "results.json").read_text())
    rows = {x["property"]: x for x in doc["runs"][0]["results"]}
    (curve,) = _sweep_curves(results_of(doc).runs[0])
    assert curve.parameter == "eps" and len(curve.values) == 20
    for eps, opt, verdict in zip(curve.values, curve.optima, curve.verdicts, strict=True):
        row = rows[f"robustness@eps={eps:g}"]
        want = math.inf if row["optimum"] == "inf" else float(row["optimum"])
        assert opt == want and verdict == row["status"]
    assert {"holds", "violated"} <= set(curve.verdicts)  # this scene's verdict flips
