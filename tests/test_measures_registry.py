"""The measures' registry (lesmc/language/measures/; issue 58): one declared object per
measure, and no other layer deciding per measure.

The docs table is the registry's; every measure rule of the grammar belongs to a declared
measure; each spelling parses, prints back and binds as the table in this file (written
from docs/language.md, not from the code) says; the kernel folds each source as
hand-computed here; and a measure registered from outside (a toy) is folded, bound and
checked by the kernel, the binding and the multi-target engine without any of them
naming it (the old kernel folded any unknown source as a deviation).
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from lesmc.common.errors import SpecError
from lesmc.language import measures
from lesmc.language.measures.base import Bound, DeclaredMeasure, Parsed, Quantities, Step
from lesmc.language.parser import parse_spec
from lesmc.language.properties import Measure
from lesmc.language.semantics import BoundMeasure, bind
from lesmc.model import kernel

ROOT = Path(__file__).resolve().parents[1]

#: spelling -> (source, aggregate, lo, hi, weight) in attack window 2..5 of a model whose
#: path ends at step 8 (docs/language.md, "Measures": payoff and count over the window L..U,
#: payoff.mean weighted 1/(U-L+1), dist.at(k) a sum over k..k, dist.max a max, tau.rise a
#: max, the identity measures sums).
BINDINGS: dict[str, tuple[str, str, int, int, float]] = {
    "payoff": ("payoff", "sum", 2, 5, 1.0),
    "payoff.mean": ("payoff", "sum", 2, 5, 0.25),
    "count": ("count", "sum", 2, 5, 1.0),
    "count.frames": ("frames", "sum", 2, 5, 1.0),
    "dist.at(3)": ("dist", "sum", 3, 3, 1.0),
    "dist.nearest(end)": ("near", "sum", 8, 8, 1.0),
    "dist.sum(1..end)": ("dist", "sum", 1, 8, 1.0),
    "dist.max(0..4)": ("dist", "max", 0, 4, 1.0),
    "tau.rise(2..6)": ("tau", "max", 2, 6, 1.0),
    "switches(0..end)": ("switches", "sum", 0, 8, 1.0),
    "lost(3..7)": ("lost", "sum", 3, 7, 1.0),
}


def _spec(measure: str, window: str = "2..5") -> str:
    return (
        f"property p {{ attack window {window}\n  minimize {measure}\n"
        "  subject to dist.max(0..end) > 1 holds if optimum > 1 }\n"
    )


def _measure(text: str) -> Measure:
    return parse_spec(_spec(text), "m.spec").properties[0].objective


def test_the_docs_table_is_the_registry() -> None:
    page = (ROOT / "docs" / "language.md").read_text(encoding="utf-8")
    table = measures.docs_table()
    assert table in page
    # one row per spelling the page documents, in the registry's order
    rows = [line.split("|")[1].strip() for line in table.splitlines()[2:]]
    assert rows[0].startswith("`payoff`") and rows[-1] == "`lost(a..b)`"
    assert len(rows) == 11


def test_every_measure_rule_of_the_grammar_is_declared() -> None:
    grammar = (ROOT / "grammars" / "lesmc.lark").read_text(encoding="utf-8")
    block = re.search(r"^\?measure:(.*?)^\S", grammar, re.S | re.M)
    assert block is not None
    rules = re.findall(r"[a-z_]+", block.group(1))
    assert set(rules) == {r for n in measures.names() for r in measures.get(n).rules}
    words = re.search(r"^IDENTITY:(.*)$", grammar, re.M)
    assert words is not None
    identity = set(re.findall(r'"([a-z_]+)"', words.group(1)))
    shared = {n for n in measures.names() if "identity_range" in measures.get(n).rules}
    assert identity == shared == {"switches", "lost"}


@pytest.mark.parametrize("text", sorted(BINDINGS))
def test_each_spelling_parses_prints_back_and_binds(text: str) -> None:
    m = _measure(text)
    assert m.text() == text.replace("payoff.sum", "payoff")
    spec = parse_spec(_spec(text), "m.spec")
    prop = spec.properties[0]
    b = bind(spec, prop, 8, ("x", "y"), True, tracks=("x", "y"), multi=True)
    got = (b.objective.source, b.objective.aggregate, b.objective.lo, b.objective.hi)
    assert (*got, b.objective.weight) == BINDINGS[text]
    assert b.objective.text == m.text()


def test_sum_is_written_without_its_suffix() -> None:
    assert _measure("payoff.sum").text() == "payoff"
    assert _measure("payoff.sum") == _measure("payoff")


def test_ranges_follow_a_moved_window_for_deviations_and_tau_only() -> None:
    text = (
        "property p { attack window 2..4 minimize dist.max(2..4)\n"
        "  subject to tau.rise(2..4) > 1 holds if optimum > 1 }\n"
        "property q { attack window 2..4 minimize payoff\n"
        "  subject to switches(2..4) > 0 holds if optimum > 1 }\n"
        "property r { attack window 2..4 minimize payoff\n"
        "  subject to dist.at(2) > 0 holds if optimum > 1 }\n"
    )
    p, q, r = (x.with_window((5, 7)) for x in parse_spec(text, "m.spec").properties)
    assert (p.objective.lo, p.objective.hi) == (5, 7)
    assert (p.constraint.measure.lo, p.constraint.measure.hi) == (5, 7)
    assert (q.constraint.measure.lo, q.constraint.measure.hi) == (2, 4)
    assert (r.constraint.measure.lo, r.constraint.measure.hi) == (2, 2)


def test_measure_errors_are_located() -> None:
    with pytest.raises(SpecError) as e:
        parse_spec(_spec("tau.rise(0..3)"), "m.spec")
    assert str(e.value).startswith("m.spec:2:") and "tau.rise starts at step 1" in str(e.value)
    with pytest.raises(SpecError) as e:
        parse_spec(_spec("switches(4..2)"), "m.spec")
    assert str(e.value).startswith("m.spec:2:") and "empty step range 4..2" in str(e.value)
    spec = parse_spec(_spec("lost(0..end)"), "m.spec")
    with pytest.raises(SpecError) as e:
        bind(spec, spec.properties[0], 8, ("x", "y"), True)
    assert str(e.value).startswith("m.spec:2:12:") and "'lost'" in str(e.value)


def _bound(text: str) -> BoundMeasure:
    spec = parse_spec(_spec(text), "m.spec")
    return bind(
        spec, spec.properties[0], 8, ("x", "y"), True, tracks=("x", "y"), multi=True
    ).objective


def test_the_kernel_folds_each_source_as_computed_by_hand() -> None:
    k = np.array([1, 2, 3, 5, 6])
    combined = np.array([0.0, 1.5, 2.0, 4.0, 8.0])
    dist = np.array([0.1, 0.2, 0.3, 0.4, 0.5])
    counted = np.array([0.0, 1.0, math.inf, 3.0, 2.0])
    rise = np.array([9.0, 0.0, 0.7, 0.2, 0.1])
    near = np.array([0.05, 0.15, 0.25, 0.35, 0.45])
    ident = np.array([1.0, 0.0, 1.0, 1.0, 1.0])
    want = {  # window 2..5: k = 2, 3, 5 are inside
        "payoff": [0, 1.5, 2.0, 4.0, 0],
        "payoff.mean": [0, 1.5 / 4, 2.0 / 4, 4.0 / 4, 0],
        "count": [0, 1.0, math.inf, 3.0, 0],
        "count.frames": [0, 1.0, math.inf, 1.0, 0],
        "dist.at(3)": [0, 0, 0.3, 0, 0],
        "dist.nearest(end)": [0, 0, 0, 0, 0],
        "dist.sum(1..end)": [0.1, 0.2, 0.3, 0.4, 0.5],
        "dist.max(0..4)": [0.1, 0.2, 0.3, 0, 0],
        "tau.rise(2..6)": [0, 0.0, 0.7, 0.2, 0.1],
        "switches(0..end)": [1.0, 0, 1.0, 1.0, 1.0],
        "lost(3..7)": [0, 0, 1.0, 1.0, 1.0],
    }
    for text, expected in want.items():
        got = kernel.contributions(_bound(text), k, combined, dist, counted, rise, near, ident)
        assert got.tolist() == expected, text
    # step 0 counts for deviations alone, and a halt makes the rest of their range +inf
    assert kernel.initial_value(_bound("dist.max(0..4)"), 2.5, 1.5) == 2.5
    assert kernel.initial_value(_bound("switches(0..end)"), 2.5, 1.5) == 0.0
    halted = {t: kernel.tail(_bound(t), 3, 8) for t in want}
    assert {t for t, v in halted.items() if v == math.inf} == {
        "dist.nearest(end)",
        "dist.sum(1..end)",
        "dist.max(0..4)",
        "tau.rise(2..6)",
    }


class Hits(DeclaredMeasure):
    """A toy measure from outside lesmc: ``hits`` sums the identity indicator where the
    target's track exists, weighted 10."""

    name = "hits"
    rules = ()
    sources = ("hits",)
    quantity = "identity"
    multi_only = True
    multi_constraint = True
    docs = (("`hits(a..b)`", "a toy"),)

    def parse(self, rule: str, tokens: Sequence[str], steps: Sequence[Step]) -> Parsed:
        return Parsed(self.name, "sum", steps[0], steps[1])

    def text(self, aggregate: str, lo: Step, hi: Step) -> str:
        return f"hits({lo}..{'end' if hi is None else hi})"

    def bind(self, aggregate: str, l: int, u: int, lo: int, hi: int) -> Bound:
        return Bound("hits", "sum", lo, hi)

    def per_transition(self, source: str, weight: float, q: Quantities) -> np.ndarray:
        out: np.ndarray = 10.0 * q.need("identity")
        return out

    def indicator(
        self, last_src: np.ndarray, tid_dst: np.ndarray, ref_dst: np.ndarray
    ) -> np.ndarray:
        out: np.ndarray = (tid_dst >= 0).astype(float)
        return out


@pytest.fixture
def hits() -> Iterator[DeclaredMeasure]:
    toy = Hits()
    measures.register(toy)
    try:
        yield toy
    finally:
        measures.unregister(toy.name)


def test_a_new_measure_is_one_object_and_one_registration(hits: DeclaredMeasure) -> None:
    from lesmc.engines.multi import supported
    from lesmc.model.identity import indicators

    assert "hits" in measures.names() and "`hits(a..b)`" in measures.docs_table()
    spec = parse_spec(_spec("payoff"), "m.spec")
    prop = spec.properties[0]
    toy = Measure("hits", "sum", 1, None)
    assert toy.text() == "hits(1..end)"
    prop = replace(prop, constraint=replace(prop.constraint, measure=toy))
    with pytest.raises(SpecError, match="'hits' measures a multi-target"):
        bind(spec, prop, 8, ("x", "y"), True)
    b = bind(spec, prop, 8, ("x", "y"), True, multi=True).constraint
    assert (b.source, b.aggregate, b.lo, b.hi) == ("hits", "sum", 1, 8)
    tid = np.array([-1, 3, 4, -1])
    ident = indicators("hits", np.full(4, -1), tid, np.ones(4, dtype=bool))
    assert ident.tolist() == [0.0, 1.0, 1.0, 0.0]
    k = np.array([0, 1, 8, 9])
    got = kernel.contributions(b, k, np.zeros(4), np.full(4, 7.0), identity=ident)
    assert got.tolist() == [0.0, 10.0, 10.0, 0.0]  # the old kernel gave the deviation, 7
    assert kernel.initial_value(b, 7.0) == 0.0 and kernel.tail(b, 2, 8) == 0.0
    supported(spec, prop)  # the multi-target engine takes it as a constraint


@pytest.mark.parametrize("name", ["results", "check", "campaign-row"])
def test_the_schemas_measure_sources_are_the_registrys(name: str) -> None:
    from lesmc.schemas import errors, schema

    root = schema(name)
    want = ["payoff", "count", "frames", "dist", "near", "tau", "switches", "lost"]
    assert root["$defs"]["measure_sources"]["enum"] == want
    text = (ROOT / "lesmc" / "schemas" / f"{name}.json").read_text(encoding="utf-8")
    assert '"$ref": "#/$defs/measure_sources"' in text and '"dist"\n' not in text
    # a results file's property may minimise tau.rise or dist.nearest (the old enum of
    # results.json's property refused both), never an unknown source
    prop = root["$defs"].get("property", {}).get("properties", {}).get("objective_source")
    if prop is not None:
        assert errors("tau", prop, root) == [] and errors("near", prop, root) == []
        assert errors("speed", prop, root) != []


def test_a_registered_measures_sources_reach_the_schemas(hits: DeclaredMeasure) -> None:
    from lesmc.schemas import schema

    assert "hits" in schema("results")["$defs"]["measure_sources"]["enum"]


def test_a_tau_rise_results_file_is_read_back_by_lesmc_report(tmp_path: Path) -> None:
    """``lesmc check --report`` on a ``tau.rise`` constraint wrote a results.json whose
    ``constraint_source`` "tau" the schema's hand-written enum refused, so ``lesmc report``
    exited 2 on it; the enum is the registry's now."""
    from cli_run import lesmc as run_lesmc

    spec = tmp_path / "settles.spec"
    spec.write_text(
        "property settles { attack window 6..8 minimize payoff\n"
        "  subject to tau.rise(10..end) > 1 holds if optimum > 3 }\n"
    )
    out = tmp_path / "check"
    r = run_lesmc("check", str(ROOT / "examples" / "merge.json"), str(spec), "--report", str(out))
    assert r.returncode in (0, 1) and "Traceback" not in r.stderr, r.stderr
    doc = (out / "results.json").read_text(encoding="utf-8")
    assert '"constraint_source": "tau"' in doc
    r = run_lesmc("report", str(out / "results.json"), "--out", str(tmp_path / "report"))
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    assert (tmp_path / "report" / "report.html").is_file()
