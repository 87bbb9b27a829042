"""Each extension point's choices are declared once (round 21, "one registry per extension
point"): the check arguments a multi-target search does not read are one table
(lesmc/pipeline/multi.py), refused alike by ``lesmc.check`` and ``lesmc check``; the
designs table of docs/cli.md is generated from the design registry; the monitors and
tracker parts tables name what their registry and package hold; the schemas' attack
actions are the actions registry's."""

from __future__ import annotations

import ast
import itertools
import re
from pathlib import Path
from typing import Any

import pytest
from cli_run import ROOT, lesmc

import lesmc as api
from lesmc.common.errors import UsageError
from lesmc.pipeline import multi

pytest.importorskip("sort_tracker")

SCENE = ROOT / "examples" / "crossing.json"  # its tracker is sort
SPEC = ROOT / "examples" / "hijack.spec"

#: A value other than the default for each argument, as lesmc.check takes it and as
#: lesmc check spells it.
NOT_DEFAULT: dict[str, tuple[Any, list[str]]] = {
    "engine": ("bnb", ["--engine", "bnb"]),
    "timeout": (600.0, ["--timeout", "600"]),  # far beyond the run, loaded or not
    "payoffs": ("certified", ["--payoffs", "certified"]),
    "max_states": (1000, ["--max-states", "1000"]),
}


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The crossing scene's sort model for the hijack property, as lesmc build writes it."""
    out = tmp_path_factory.mktemp("multi") / "crossing.npz"
    api.save_model(api.build(SCENE, None, spec=SPEC), out)
    return out


def test_the_tables_name_check_arguments() -> None:
    """Every refused name is an argument of lesmc.check (so a CLI option of that name)."""
    import inspect

    arguments = set(inspect.signature(api.check).parameters)
    assert set(multi.MODEL_IGNORES) <= arguments
    assert set(multi.DESIGN_IGNORES) <= arguments
    assert set(multi.MODEL_IGNORES) | set(multi.DESIGN_IGNORES) <= set(NOT_DEFAULT)


@pytest.mark.parametrize("name", sorted(multi.MODEL_IGNORES))
def test_the_api_refuses_each_on_a_built_model(built: Path, name: str) -> None:
    with pytest.raises(UsageError) as err:
        api.check(built, SPEC, **{name: NOT_DEFAULT[name][0]})
    assert err.value.message.startswith(f"{name}: {multi.MODEL_IGNORES[name]}")


def test_the_api_checks_a_built_model_given_none_of_them(built: Path) -> None:
    results = api.check(built, SPEC)
    assert [r.property for r in results] == ["hijack"]


def test_the_command_line_refuses_the_same_on_a_built_model(built: Path) -> None:
    flags = [f for name in multi.MODEL_IGNORES for f in NOT_DEFAULT[name][1]]
    proc = lesmc("check", str(built), str(SPEC), *flags)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    named = {f"--{n.replace('_', '-')}" for n in multi.MODEL_IGNORES}
    assert all(flag in proc.stderr for flag in named), proc.stderr


@pytest.mark.parametrize("name", sorted(multi.DESIGN_IGNORES))
def test_the_api_refuses_each_on_a_multi_target_design(name: str) -> None:
    with pytest.raises(UsageError) as err:
        api.check(SCENE, SPEC, **{name: NOT_DEFAULT[name][0]})
    assert err.value.message.startswith(f"{name}: {multi.DESIGN_IGNORES[name]}")


def test_the_command_line_refuses_the_same_on_a_multi_target_design() -> None:
    flags = [f for name in multi.DESIGN_IGNORES for f in NOT_DEFAULT[name][1]]
    proc = lesmc("check", str(SCENE), str(SPEC), *flags)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    named = {f"--{n.replace('_', '-')}" for n in multi.DESIGN_IGNORES}
    assert all(flag in proc.stderr for flag in named), proc.stderr


# ------------------------------------------------------------- docs tables and schema enums


def _table(doc: str, header: str) -> list[str]:
    """The lines of the markdown table of docs/``doc`` whose header starts with ``header``."""
    lines = (ROOT / "docs" / doc).read_text().splitlines()
    at = next(i for i, line in enumerate(lines) if line.startswith(header))
    return list(itertools.takewhile(lambda line: line.startswith("|"), lines[at:]))


def test_the_designs_table_is_the_registry() -> None:
    """docs/cli.md's designs table is generated (it had drifted from the --help lines)."""
    from lesmc.designs import registry

    page = (ROOT / "docs" / "cli.md").read_text()
    marker = "<!-- generated: lesmc.designs.registry.docs_table() -->\n"
    assert marker in page
    assert page.split(marker, 1)[1].split("\n\n", 1)[0] == registry.docs_table()
    rows = _table("cli.md", "| design | label in tables |")[2:]
    assert [r.split("`")[1] for r in rows] == list(registry.names())
    for r in rows:  # each row's summary is its design's --help line
        name = r.split("`")[1]
        assert r.endswith(f" {registry.get(name).summary} |")


def test_the_monitors_table_is_the_registry() -> None:
    """docs/semantics.md's alarms table names the registered monitors, in order."""
    from lesmc.language import monitors

    rows = _table("semantics.md", "| kind | parameter (domain) | alarm at step j |")[2:]
    assert [r.split("`")[1] for r in rows] == list(monitors.names())


def test_the_parts_table_lists_the_parts_package() -> None:
    """docs/trackers.md's parts table names each module of lesmc/tracking/parts/."""
    text = "\n".join(_table("trackers.md", "| part | module | kinds | used by |"))
    named = set(re.findall(r"`(\w+\.py)`", text))
    files = {p.name for p in (ROOT / "lesmc" / "tracking" / "parts").glob("*.py")}
    assert named == files - {"__init__.py"}


@pytest.mark.parametrize("name", ["results", "replay"])
def test_the_attack_actions_enum_is_the_registry(name: str) -> None:
    from lesmc.language import actions
    from lesmc.schemas import schema

    assert schema(name)["$defs"]["attack_actions"] == {"enum": list(actions.names())}
    text = (ROOT / "lesmc" / "schemas" / f"{name}.json").read_text()
    assert '"hide"' not in text and '"inject"' not in text  # referred to, not spelled


def test_no_module_spells_the_actions_list() -> None:
    """The actions' names are lesmc/language/actions.py's: no other module types the list
    as a value (a type's ``Literal["hide", "inject"]`` below the language layer is no list)."""
    spelled = []
    for path in (ROOT / "lesmc").rglob("*.py"):
        text = path.read_text()
        if '"hide"' not in text or '"inject"' not in text:
            continue  # parse only the modules that spell both names
        tree = ast.parse(text)
        types = {id(n.slice) for n in ast.walk(tree) if isinstance(n, ast.Subscript)}
        for node in ast.walk(tree):
            if isinstance(node, ast.Tuple | ast.List | ast.Set) and id(node) not in types:
                words = [e.value for e in node.elts if isinstance(e, ast.Constant)]
                if {"hide", "inject"} <= set(words):
                    spelled.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert spelled == []


def test_the_alarms_monitor_help_is_the_registrys() -> None:
    """``lesmc alarms --help`` lists each registered monitor with its parameter (it was typed)."""
    from lesmc.language import monitors

    proc = lesmc("alarms", "--help")
    assert proc.returncode == 0 and "Traceback" not in proc.stderr
    text = re.sub(r"\s+", " ", proc.stdout)
    for kind in map(monitors.get, monitors.names()):
        assert f"{kind.name} {kind.parameter.upper()}" in text
