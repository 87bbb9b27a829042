"""The readers of the results documents read typed objects (lesmc.results.read), not string
keys into the JSON (issue 57, item 5)."""

from __future__ import annotations

import ast
from pathlib import Path
from typing import Any

import pytest

from lesmc.campaign.summary import command, summarise
from lesmc.results.campaign_row import read_row

ROOT = Path(__file__).resolve().parents[1]

#: The readers migrated to the typed objects.
READERS = (
    "lesmc/campaign/summary.py",
    "lesmc/replay/case.py",
    "lesmc/replay/run.py",
    "lesmc/report/html.py",
    "lesmc/report/run_view.py",
    "lesmc/report/document_tables.py",
    "lesmc/report/design_section.py",
    "lesmc/report/attack_images.py",
)


def string_key_reads(source: str) -> list[int]:
    """The lines of ``source`` that read ``x["key"]`` (a subscript by a string literal, not an
    assignment to one). A module's own constant tables (``COLOURS["window"]``: an upper-case
    name) are no document."""
    return [
        node.lineno
        for node in ast.walk(ast.parse(source))
        if isinstance(node, ast.Subscript)
        and isinstance(node.ctx, ast.Load)
        and isinstance(node.slice, ast.Constant)
        and isinstance(node.slice.value, str)
        and not (isinstance(node.value, ast.Name) and node.value.id.isupper())
    ]


@pytest.mark.parametrize("module", READERS)
def test_the_reader_reads_no_string_key(module: str) -> None:
    assert string_key_reads((ROOT / module).read_text()) == []


def test_the_count_finds_string_key_reads() -> None:
    src = (
        "def f(doc):\n"
        "    out = {}\n"
        '    out["a"] = COLOURS["window"]\n'
        "    return doc[\"runs\"][0]['results'], [1][0]\n"
    )
    assert string_key_reads(src) == [4, 4]


def _row(key: str, design: str, verdict: str, optimum: Any, window: list[int]) -> dict[str, Any]:
    return {
        "format": "lesmc-campaign-row",
        "version": 2,
        "key": key,
        "video": "v",
        "target": {"step": 3, "x": 1.5, "y": 2.25},
        "window": window,
        "design": design,
        "property": "robustness",
        "verdict": verdict,
        "status": verdict,
        "vacuous": False,
        "optimum": optimum,
        "witness_value": None,
        "bounds": [None, None],
        "holds_if": "optimum > 1",
        "stats": {"engine": "bnb", "states_expanded": 1, "seconds": 0.0, "stopped": "finished"},
        "spec": None,
        "holds_op": ">",
        "threshold": 1.0,
    }


def test_the_summary_of_hand_made_rows() -> None:
    rows = [
        _row("a", "single", "violated", 0.5, [2, 4]),
        _row("b", "single", "holds", "inf", [2, 3]),
        _row("c", "single", "violated", 0.25, [2, 3]),
        _row("d", "joint", "holds", 3, [2, 4]),
    ]
    typed = read_row(rows[0])
    assert (typed.target.x, typed.target.y, typed.target.step) == (1.5, 2.25, 3)
    assert typed.window == (2, 4) and typed.payoffs is None
    s = summarise(rows, "sc")
    assert s.designs == ("single", "joint")
    single = s.cell("single", "robustness")
    assert (single.rows, single.holds, single.violated) == (3, 1, 2)
    assert single.by_length[2].fraction == 0.5 and single.by_length[3].fraction == 1.0
    assert [w.row.key for w in single.worst] == ["c", "a"]
    assert single.worst[0].command == (
        "lesmc verify --scene sc/v.json --target 1.50,2.25@3 --window 2..3 --design single"
    )
    joint = s.improvements["robustness"].designs["joint"]
    assert (joint.compared, joint.removed, joint.added) == (1, 1, 0)
    doc = s.to_dict()
    assert doc["cells"]["single"]["robustness"]["optima"] == [0.25, 0.5, "inf"]
    assert doc["cells"]["single"]["robustness"]["worst"][0]["target"] == rows[2]["target"]
    assert command(read_row(rows[0]), "sc").endswith("--window 2..4 --design single")


def test_the_typed_document_holds_what_the_json_holds(tmp_path: Path) -> None:
    """lesmc.results.read against the JSON module's reading of a results.json with two
    designs, a monitor and component failures."""
    import json

    from cli_run import lesmc

    from lesmc.results.read import read_results

    out = tmp_path / "rep"
    r = lesmc(
        "check", "tests/scenes/rq1_platoon.json", "tests/scenes/rq1_platoon.spec",
        "--faults", "examples/faults.spec", "--design", "single", "--design", "monitor",
        "--report", str(out),
    )  # fmt: skip
    assert r.returncode in (0, 1), r.stderr
    raw = json.loads((out / "results.json").read_text())
    doc = read_results(out / "results.json")
    assert [run.design for run in doc.runs] == [run["design"] for run in raw["runs"]]
    assert doc.provenance.specs[0].text == raw["provenance"]["specs"][0]["text"]
    for run, want in zip(doc.runs, raw["runs"], strict=True):
        assert [(x.property, x.verdict, x.optimum) for x in run.results] == [
            (x["property"], x["verdict"], x["optimum"]) for x in want["results"]
        ]
        assert [p.no for p in run.paths] == [p["no"] for p in want["paths"]]
        assert run.counterexamples == tuple(want["roles"]["counterexample"])
        assert [m.monitor is not None for m in run.properties] == [
            p["monitor"] is not None for p in want["properties"]
        ]
        assert [x.property for _, x in run.faults] == [
            f["result"]["property"] for f in want["faults"]
        ]
        q, s = next(iter(want["states"].items()))
        assert run.states[q].s == tuple(s["s"])
    assert any(run.faults for run in doc.runs)
    assert any(p.monitor is not None for run in doc.runs for p in run.properties)
