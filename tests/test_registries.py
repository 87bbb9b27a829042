"""The engines and payoff modes are declared once each (lesmc/engines/registry.py,
lesmc/engines/payoff_modes.py): the docs tables, ``--help``, the CLI's choices and the
JSON schemas' enums are the registries' (issue 57, item 4)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from cli_run import lesmc as run_lesmc

from lesmc.engines import payoff_modes
from lesmc.engines import registry as engines
from lesmc.schemas import schema

ROOT = Path(__file__).resolve().parents[1]


def _table(doc: str, header: str) -> list[list[str]]:
    """The rows of the markdown table of ``doc`` whose header line starts with ``header``."""
    lines = (ROOT / "docs" / doc).read_text().splitlines()
    at = next(i for i, line in enumerate(lines) if line.startswith(header))
    rows = []
    for line in lines[at + 2 :]:
        if not line.startswith("|"):
            break
        rows.append([c.strip() for c in line.strip("|").split("|")])
    return rows


def test_the_engines_table_is_the_registry() -> None:
    want = [
        [f"`{e.name}`", e.summary, "yes" if e.exhaustive else "no"]
        for e in map(engines.get, engines.names())
    ]
    assert _table("engines.md", "| engine | what it does |") == want
    assert len(want) == 4


def test_the_payoff_modes_table_is_the_registry() -> None:
    want = [
        [f"`{m.name}`", ", ".join(m.sets), m.summary]
        for m in map(payoff_modes.get, payoff_modes.names())
    ]
    assert _table("semantics.md", "| mode | payoff sets checked |") == want
    assert len(want) == 3


def _help(*verb: str) -> str:
    r = run_lesmc(*verb, "--help")
    assert r.returncode == 0 and "Traceback" not in r.stderr
    return re.sub(r"\s+", " ", r.stdout)


@pytest.mark.parametrize("verb", ["check", "verify", "campaign"])
def test_payoffs_help_and_choices_are_the_registrys(verb: str) -> None:
    text = _help(verb)
    assert "[" + "|".join(payoff_modes.names()) + "]" in text
    for m in map(payoff_modes.get, payoff_modes.names()):
        assert f"{m.name}: {m.summary}" in text


def test_engine_help_and_choices_are_the_registrys() -> None:
    text = _help("check")
    assert "--engine [" + "|".join(engines.names()) + "]" in text
    for e in map(engines.get, engines.names()):
        assert f"{e.name}: {e.summary}" in text


@pytest.mark.parametrize("name", ["check", "results", "campaign-row", "campaign-summary"])
def test_the_schemas_enums_are_the_registries(name: str) -> None:
    sch = schema(name)
    assert sch["$defs"]["payoff_modes"] == {"enum": list(payoff_modes.names())}
    assert sch["$defs"]["engines"] == {"enum": list(engines.names())}
    text = (ROOT / "lesmc" / "schemas" / f"{name}.json").read_text()
    # the files refer to the enums, they do not spell the names
    assert '"interval"' not in text and '"bnb"' not in text


def test_a_registered_engine_is_offered_and_searches() -> None:
    """A new engine is one register() call: the API accepts it and checks with it."""
    import lesmc

    tiny = ROOT / "tests" / "golden" / "tiny"
    base = engines.get("bnb")
    engines.register(engines.Engine("toy", "bnb under another name", base.load))
    try:
        assert "toy" in schema("check")["$defs"]["engines"]["enum"]
        got = lesmc.check(tiny / "model.lts", tiny / "properties.spec", engine="toy")
        want = lesmc.check(tiny / "model.lts", tiny / "properties.spec", engine="bnb")
        assert [(r.property, r.optimum) for r in got] == [(r.property, r.optimum) for r in want]
    finally:
        engines._ENGINES.pop("toy")
