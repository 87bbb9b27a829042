"""The property language: shipped specs, syntax errors with positions, semantic checks."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from lesmc.common.errors import SpecError
from lesmc.language.parser import load_spec, parse_spec
from lesmc.language.properties import Measure
from lesmc.language.semantics import bind

ROOT = Path(__file__).resolve().parents[1]


def test_robustness_spec_means_eq6() -> None:
    (p,) = load_spec(ROOT / "specs" / "robustness.spec").properties
    assert p.name == "robustness"
    assert p.window == (6, 8)
    assert p.objective == Measure("payoff", "sum")
    assert p.constraint.measure == Measure("dist", "sum", 0, None)
    assert (p.constraint.op, p.constraint.threshold) == (">", 120.0)
    assert (p.holds_op, p.threshold, p.norm, p.components, p.monitor, p.end) == (
        ">",
        3.0,
        2.0,
        ("x", "y"),  # deviation of the position, in pixels
        None,
        None,
    )


def test_resilience_spec_means_eq7() -> None:
    (p,) = load_spec(ROOT / "specs" / "resilience.spec").properties
    assert p.window == (6, 8)
    assert p.objective == Measure("dist", "max", 6, 8)
    assert p.constraint.measure == Measure("dist", "at", None, None)
    assert (p.constraint.op, p.constraint.threshold, p.threshold) == (">", 1.0, 30.0)


def test_end_binds_to_last_original_step() -> None:
    spec = load_spec(ROOT / "specs" / "resilience.spec")
    bp = bind(spec, spec.properties[0], 19, ("x", "y", "vx", "vy"), False)
    assert (bp.l, bp.u, bp.end) == (6, 8, 19)
    assert (bp.constraint.lo, bp.constraint.hi, bp.constraint.aggregate) == (19, 19, "sum")
    assert bp.components == (0, 1)  # on x, y


def test_all_optional_clauses() -> None:
    text = """
    # two properties, every clause
    property a {
        attack window 2..end   # window up to the end
        end 9
        minimize payoff.mean
        subject to dist.max(0..end) >= 5.5e1
        holds if optimum >= 0.25
        norm inf
        on x, y
        monitor uncertainty on x tolerance 1e-6
    }
    property b { attack window 1..1 minimize dist.at(3) subject to payoff < 2
                 holds if optimum > 0 norm 1 }
    """
    a, b = parse_spec(text).properties
    assert a.window == (2, None) and a.end == 9 and a.norm == math.inf
    assert a.objective == Measure("payoff", "mean")
    assert (a.constraint.op, a.constraint.threshold) == (">=", 55.0)
    assert a.components == ("x", "y")
    assert a.monitor is not None and a.monitor.components == ("x",) and a.monitor.tolerance == 1e-6
    bp = bind(parse_spec(text), a, 12, ("x", "y", "vx", "vy"), True)
    assert (bp.l, bp.u, bp.end, bp.objective.weight) == (2, 9, 9, 1 / 8)
    assert b.norm == 1.0 and b.constraint.measure == Measure("payoff", "sum")


GOOD = (
    "property p {\n    attack window 6..8\n    minimize payoff\n"
    "    subject to dist.sum(0..end) > 120\n    holds if optimum > 3.0\n}\n"
)

SYNTAX = [
    (GOOD.replace("minimize payoff", "minimise payoff"), "3:5", "unexpected 'minimise'"),
    (GOOD.replace("> 120", "> abc"), "4:35", "expected a number"),
    (GOOD.replace("6..8", "6...8"), "2:22", "unexpected '.8'"),
    (GOOD.replace("dist.sum", "dist.avg"), "4:21", "'sum' or 'max'"),
    (GOOD.replace("}\n", ""), "5:24", "unexpected end of file"),
    (GOOD.replace("optimum > 3.0", "optimum < 3.0"), "5:22", "'>' or '>='"),
    (GOOD + "property p2 { attack window 1..2 norm 3 }", "7:39", "1, 2 or inf"),
    (GOOD.replace("property p", "property 9p"), "1:10", "a name"),
    ("", "1:1", "defines no property"),
]


@pytest.mark.parametrize(("text", "where", "message"), SYNTAX, ids=[s[2] for s in SYNTAX])
def test_syntax_errors_have_position_caret_and_expectation(
    text: str, where: str, message: str
) -> None:
    with pytest.raises(SpecError) as exc:
        parse_spec(text, "f.spec")
    rendered = exc.value.render()
    assert rendered.startswith(f"f.spec:{where}"), rendered
    assert message in rendered, rendered
    if text:
        assert rendered.splitlines()[-1].strip() == "^"


MEANING = [
    (GOOD.replace("    holds if optimum > 3.0\n", ""), "1:1", "lacks 'holds if optimum > NUMBER'"),
    (
        GOOD.replace("minimize payoff", "minimize payoff\n    minimize payoff"),
        "4:5",
        "repeats its objective",
    ),
    (GOOD + GOOD, "7:1", "duplicate property name 'p'"),
    (GOOD.replace("> 120", "> 1e400"), "4:35", "must be finite"),
    (GOOD.replace("0..end", "5..2"), "4:16", "empty step range 5..2"),
    (GOOD.replace("    holds", "    on x, x\n    holds"), "5:11", "named twice"),
]


@pytest.mark.parametrize(("text", "where", "message"), MEANING, ids=[m[2] for m in MEANING])
def test_meaning_errors_in_the_file(text: str, where: str, message: str) -> None:
    with pytest.raises(SpecError) as exc:
        parse_spec(text, "f.spec")
    assert exc.value.render().startswith(f"f.spec:{where}: ")
    assert message in exc.value.render()


BIND = [
    (GOOD, 7, "window 6..8 must satisfy"),
    (GOOD.replace("6..8", "0..3"), 19, "must start at step 1"),
    (GOOD.replace("6..8", "6..8\n    end 30"), 19, "end 30 is beyond"),
    (GOOD.replace("0..end", "0..25"), 19, "step 25 is beyond end = 19"),
    (GOOD.replace("    holds", "    on x, z\n    holds"), 19, "unknown component 'z'"),
    (GOOD.replace("    holds", "    monitor uncertainty\n    holds"), 19, "needs the covariance"),
]


@pytest.mark.parametrize(("text", "e", "message"), BIND, ids=[b[2] for b in BIND])
def test_semantic_errors_against_a_model(text: str, e: int, message: str) -> None:
    spec = parse_spec(text, "f.spec")
    with pytest.raises(SpecError) as exc:
        bind(spec, spec.properties[0], e, ("x", "y", "vx", "vy"), False)
    assert exc.value.render().startswith("f.spec:")
    assert message in exc.value.render()
