"""The command line as a user runs it: exit statuses, JSON, clean errors."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from cli_run import lesmc

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "tests" / "golden" / "tiny"


def test_check_json_contract() -> None:
    r = lesmc("check", str(TINY / "model.lts"), str(TINY / "properties.spec"), "--json")
    assert r.returncode == 1, r.stderr  # some properties are violated
    doc = json.loads(r.stdout)
    first = doc["results"][0]
    assert set(first) >= {
        "property",
        "verdict",
        "optimum",
        "threshold",
        "counterexample",
        "witness",
        "witness_value",
        "stats",
    }
    assert set(first["counterexample"]) >= {"states", "objective", "constraint"}
    assert set(first["witness"]) >= {"states", "objective"}
    assert set(first["stats"]) >= {"engine", "states_expanded", "seconds"}
    nothing = next(x for x in doc["results"] if x["property"] == "nothing_breaks")
    assert nothing["optimum"] == "inf" and nothing["verdict"] == "holds"


@pytest.mark.parametrize(("props", "status"), [(["robustness_mean"], 0), (["robustness"], 1)])
def test_exit_status_follows_verdicts(props: list[str], status: int) -> None:
    args = [a for p in props for a in ("--property", p)]
    r = lesmc("check", str(TINY / "model.lts"), str(TINY / "properties.spec"), *args)
    assert r.returncode == status, r.stdout + r.stderr
    assert "counterexample" in r.stdout


def test_unknown_exits_3(tmp_path: Path) -> None:
    from lesmc.model.lts_format import save_lts
    from lesmc.model.random_models import RandomModelConfig, random_lts

    tmp = tmp_path
    save_lts(
        random_lts(RandomModelConfig(steps=8, width=8, branching=(3, 4), tree=True), 3),
        tmp / "m.lts",
    )
    (tmp / "p.spec").write_text(
        "property p { attack window 1..8 minimize payoff "
        "subject to dist.max(0..end) > 60 holds if optimum > 1 }"
    )
    r = lesmc("check", str(tmp / "m.lts"), str(tmp / "p.spec"), "--max-states", "3")
    assert r.returncode == 3, r.stdout + r.stderr
    assert "unknown" in r.stdout


def test_spec_error_exit_2_without_traceback(tmp_path: Path) -> None:
    bad = tmp_path / "bad.spec"
    bad.write_text("property p {\n  attack window 6..8\n  minimize payof\n}\n")
    r = lesmc("check", str(TINY / "model.lts"), str(bad))
    assert r.returncode == 2
    assert r.stderr.startswith(f"{bad}:3:12: unexpected 'payof'")
    assert "Traceback" not in r.stderr and r.stdout == ""


def test_model_error_exit_2(tmp_path: Path) -> None:
    bad = tmp_path / "bad.lts"
    bad.write_text('{"format": "lesmc-lts", "version": 1}')
    r = lesmc("check", str(bad), str(TINY / "properties.spec"))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert f"{bad}: states: must be a non-empty list" in r.stderr


def test_semantic_error_names_the_spec_line(tmp_path: Path) -> None:
    r = lesmc("check", str(TINY / "model.lts"), str(ROOT / "specs" / "robustness.spec"))
    assert r.returncode == 2
    assert "robustness.spec:5:5: attack window 6..8 must satisfy" in r.stderr


def test_missing_file_and_bad_option() -> None:
    r = lesmc("check", "nope.lts", str(TINY / "properties.spec"))
    assert r.returncode == 2 and "nope.lts: cannot read file" in r.stderr
    r = lesmc("check", str(TINY / "model.lts"), str(TINY / "properties.spec"), "--engine", "magic")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    r = lesmc("check", str(TINY / "model.lts"), str(TINY / "properties.spec"), "--property", "zzz")
    assert r.returncode == 2 and "no property named zzz" in r.stderr


def test_reduce_knapsack_then_check(tmp_path: Path) -> None:
    items = tmp_path / "items.csv"
    items.write_text("cost,capacity\n3,4\n5,7\n2,2\n8,9\n")
    r = lesmc(
        "reduce",
        "knapsack",
        str(items),
        "--demand",
        "10",
        "--budget",
        "6",
        "-o",
        str(tmp_path / "k.lts"),
    )
    assert r.returncode == 0, r.stderr
    r = lesmc("check", str(tmp_path / "k.lts"), str(tmp_path / "k.spec"), "--json")
    assert r.returncode == 0
    # cheapest selection with capacity > 10: items 1 and 2 (cost 8) -> 8 > 6 holds
    assert json.loads(r.stdout)["results"][0]["optimum"] == 8.0


def test_reduce_bad_items_writes_nothing(tmp_path: Path) -> None:
    items = tmp_path / "items.csv"
    items.write_text("cost,capacity\n3,oops\n")
    r = lesmc("reduce", "knapsack", str(items), "--demand", "1", "-o", str(tmp_path / "k.lts"))
    assert r.returncode == 2 and f"{items}:2:3: 'oops' is not a number" in r.stderr
    assert not (tmp_path / "k.lts").exists()


def test_json_outputs_validate_against_their_shipped_schemas(tmp_path: Path) -> None:
    """check, track and report print documents with format and version, valid per schema."""
    import jsonschema

    from lesmc.schemas import SCHEMAS, schema

    scenes = ROOT / "tests" / "scenes"
    docs = []
    r = lesmc("check", str(TINY / "model.lts"), str(TINY / "properties.spec"), "--json")
    docs.append(json.loads(r.stdout))
    r = lesmc("track", str(scenes / "rq4_merge.json"), "--json", "--design", "joint")
    assert r.returncode == 0, r.stderr
    docs.append(json.loads(r.stdout))
    scene, spec = str(scenes / "rq4_merge.json"), str(scenes / "rq4_merge.spec")
    r = lesmc("check", scene, spec, "--report", str(tmp_path / "a"), "--json")
    assert r.returncode in (0, 1), r.stderr
    docs.append(json.loads(r.stdout))
    results = json.loads((tmp_path / "a" / "results.json").read_text())
    docs.append(results)
    r = lesmc(
        "report", str(tmp_path / "a" / "results.json"), "--out", str(tmp_path / "b"), "--json"
    )
    assert r.returncode == 0, r.stderr
    docs.append(json.loads(r.stdout))
    for doc in docs:
        assert isinstance(doc["version"], int)
        jsonschema.validate(doc, schema(SCHEMAS[doc["format"]]))
    assert [d["format"] for d in docs] == [
        "lesmc-check",
        "lesmc-track",
        "lesmc-check",
        "lesmc-results",
        "lesmc-report",
    ]


def test_frames_without_report_is_an_error() -> None:
    r = lesmc(
        "check", str(TINY / "model.lts"), str(TINY / "properties.spec"), "--frames", str(TINY)
    )
    assert r.returncode == 2 and "--frames" in r.stderr and "Traceback" not in r.stderr


def test_swapped_arguments_get_a_hint() -> None:
    r = lesmc("check", str(TINY / "properties.spec"), str(TINY / "model.lts"))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "the order is lesmc check MODEL|SCENE SPEC" in r.stderr


def test_json_errors_are_documents_on_stdout(tmp_path: Path) -> None:
    """With --json an error is also a lesmc-error document on stdout (exit 2), located."""
    import jsonschema

    from lesmc.schemas import schema

    bad = tmp_path / "bad.lts"
    bad.write_text('{"format": "lesmc-lts", "version": 1,\n  "states": [}')
    r = lesmc("check", str(bad), str(TINY / "properties.spec"), "--json")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    doc = json.loads(r.stdout)
    jsonschema.validate(doc, schema("error"))
    assert doc["exit"] == 2 and doc["error"]["file"] == str(bad)
    assert doc["error"]["line"] == 2  # where the JSON breaks
    r = lesmc("check", str(TINY / "model.lts"), str(TINY / "properties.spec"), "--json", "-x")
    assert r.returncode == 2 and json.loads(r.stdout)["error"]["file"] is None


def test_the_options_reference_is_what_the_command_line_declares() -> None:
    """docs/cli-options.md lists every verb's options as click declares them (regenerate
    with `python -m lesmc.cli.reference > docs/cli-options.md`)."""
    import click

    from lesmc.cli.main import cli
    from lesmc.cli.reference import options_markdown

    text = (ROOT / "docs" / "cli-options.md").read_text()
    assert text == options_markdown()
    ctx = click.Context(cli)
    for name in cli.list_commands(ctx):  # every option of every verb is in the page
        cmd = cli.get_command(ctx, name)
        for p in cmd.params if cmd is not None else ():
            for opt in getattr(p, "opts", []):
                if opt.startswith("--") and opt != "--help":
                    assert f"`{opt}`" in text, (name, opt)


def test_every_verb_has_a_whole_line_in_the_help() -> None:
    r = lesmc("--help")
    lines = r.stdout.split("Commands:")[1].splitlines()
    verbs = [line.split()[0] for line in lines if line.strip()]
    assert len(verbs) >= 12 and all(not line.rstrip().endswith("...") for line in lines)
