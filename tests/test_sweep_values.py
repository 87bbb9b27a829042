"""A sweep's values are data (issue 56, item 18) and every result names its design (issue 57):
``"sweep": {"eps": 10.782}`` and ``"design"`` in ``check --json``, in the results document
and in campaign rows, as the schemas say."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path
from types import SimpleNamespace

import jsonschema
from cli_run import lesmc

from lesmc.results.load import load_results
from lesmc.schemas import schema

ROOT = Path(__file__).resolve().parents[1]
SPECS = ("specs/robustness.spec", "specs/resilience.spec")


def test_check_json_names_each_variants_values_and_design() -> None:
    r = lesmc("check", "examples/merge.json", *SPECS,
              "--sweep", "eps=10.782,20", "--sweep", "p=1,inf", "--json")  # fmt: skip
    assert r.returncode in (0, 1) and "Traceback" not in r.stderr, r.stderr
    doc = json.loads(r.stdout)
    jsonschema.validate(doc, schema("check"))
    got = {(x["property"], json.dumps(x["sweep"], sort_keys=True)) for x in doc["results"]}
    want = {
        (f"{name}@eps={eps:g},p={p}", json.dumps({"eps": eps, "p": pj}, sort_keys=True))
        for name in ("robustness", "resilience")
        for eps, (p, pj) in itertools.product((10.782, 20.0), (("1", 1.0), ("inf", "inf")))
    }
    assert got == want
    scene = json.loads((ROOT / "examples" / "merge.json").read_text())
    assert {x["design"] for x in doc["results"]} == {scene["tracker"]["design"]}


def test_a_payoff_source_sweep_names_the_source() -> None:
    r = lesmc("check", "examples/merge.json", SPECS[0], "--sweep", "payoffs=attack", "--json")
    assert r.returncode in (0, 1), r.stderr
    (res,) = json.loads(r.stdout)["results"]
    assert res["sweep"] == {"payoffs": "attack"} and res["property"] == "robustness@payoffs=attack"


def test_without_a_sweep_there_is_no_sweep_field() -> None:
    tiny = ROOT / "tests" / "golden" / "tiny"
    r = lesmc("check", str(tiny / "model.lts"), str(tiny / "properties.spec"), "--json")
    assert r.returncode == 1, r.stderr
    results = json.loads(r.stdout)["results"]
    assert all("sweep" not in x for x in results)
    assert {x["design"] for x in results} == {"model"}  # a hand-made .lts names no design


def test_the_results_document_carries_sweep_and_design(tmp_path: Path) -> None:
    out = tmp_path / "rep"
    r = lesmc("check", "examples/merge.json", SPECS[0], "--sweep", "eps=10.782",
              "--report", str(out))  # fmt: skip
    assert r.returncode in (0, 1) and "Traceback" not in r.stderr, r.stderr
    doc = load_results(out / "results.json")  # validated against the shipped schema
    (run,) = doc["runs"]
    (res,) = run["results"]
    assert res["sweep"] == {"eps": 10.782} and res["design"] == run["design"]


def test_campaign_rows_carry_the_sweep() -> None:
    """A campaign row of a swept result (campaign/work.row) keeps its values."""
    import lesmc as api
    from lesmc.campaign.store import FORMAT, VERSION
    from lesmc.campaign.work import row
    from lesmc.language.sweep import parse_sweep, swept

    sweeps = (parse_sweep("eps=10.782"), parse_sweep("p=1,inf"))
    spec = swept(api.load_spec(ROOT / SPECS[0]), sweeps)
    results = api.check(ROOT / "examples" / "merge.json", spec, designs="improved")
    group = SimpleNamespace(video="v", target=SimpleNamespace(step=0, x=1.0, y=2.0))
    rows = [row(group, "k", (6, 8), r.design or "", r) for r in results]  # type: ignore[arg-type]
    for got in rows:
        jsonschema.validate({"format": FORMAT, "version": VERSION, **got}, schema("campaign-row"))
    assert [x["sweep"] for x in rows] == [{"eps": 10.782, "p": 1.0}, {"eps": 10.782, "p": "inf"}]
    assert {x["design"] for x in rows} == {"improved"}
    assert [r.sweep for r in results] == [{"eps": 10.782, "p": 1.0}, {"eps": 10.782, "p": math.inf}]
