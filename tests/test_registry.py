"""A design added to the registry reaches every place that names designs.

The toy design is registered here, in the test suite, as a user's code would
(lesmc/designs/registry.py, docs/architecture.md "Adding a design"): a tracker
module of its own (a subclass of the single design) and one registry call each
for it and for it under the runtime monitor. It must then be offered by the
command line, accepted by a scene and by the JSON schemas, checked, and counted
in a campaign summary under its label; and it must answer what the design it
copies answers, computed independently through the single design.
"""

from __future__ import annotations

import sys
import types
from collections.abc import Iterator
from pathlib import Path

import pytest
from click.testing import CliRunner

from lesmc.api import check, load_scene
from lesmc.campaign.plan import Group, plan_units
from lesmc.campaign.store import FORMAT, VERSION
from lesmc.campaign.summary import summarise
from lesmc.campaign.work import run_group
from lesmc.cli.main import cli
from lesmc.common.errors import LesmcError
from lesmc.common.files import read_json
from lesmc.designs import registry
from lesmc.language.parser import load_spec
from lesmc.scene import scene_from_dict
from lesmc.schemas import schema, validate
from lesmc.tracking.single import SingleDesign
from lesmc.tracking.targets import TargetSpec

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "tests" / "scenes" / "rq4_merge.json"
SPEC = ROOT / "tests" / "scenes" / "rq4_merge.spec"


class ToyDesign(SingleDesign):
    """The user's tracker: here the single design under another name."""


@pytest.fixture
def toy() -> Iterator[None]:
    module = types.ModuleType("lesmc_toy_design")
    module.ToyDesign = ToyDesign  # type: ignore[attr-defined]
    sys.modules["lesmc_toy_design"] = module
    registry.tracker("toy", "lesmc_toy_design:ToyDesign", "toy tracker", "a test's tracker")
    registry.monitored("toy_mon", "toy", "toy + monitor", "the toy tracker, monitored")
    try:
        yield
    finally:
        registry.unregister("toy_mon")
        registry.unregister("toy")
        del sys.modules["lesmc_toy_design"]


def test_the_command_line_offers_it(toy: None) -> None:
    runner = CliRunner()
    for verb in ("verify", "check", "campaign", "build", "track"):
        out = runner.invoke(cli, [verb, "--help"]).output
        assert "toy" in out, verb
        # build and track take a tracker: the monitored design is no tracker of its own
        assert ("toy_mon" in out) == (verb not in ("build", "track")), verb


def test_the_schemas_and_a_scene_accept_it(toy: None) -> None:
    assert "toy" in schema("build")["$defs"]["trackers"]["enum"]
    assert "toy_mon" in schema("campaign-row")["$defs"]["designs"]["enum"]
    doc = read_json(SCENE)
    doc["tracker"]["design"] = "toy"
    assert scene_from_dict(doc, "scene").tracker.design == "toy"
    registry.unregister("toy_mon")
    registry.unregister("toy")
    with pytest.raises(LesmcError, match="toy"):
        scene_from_dict(doc, "scene")


def test_it_is_checked_and_answers_as_the_design_it_copies(toy: None) -> None:
    spec = load_spec(SPEC)
    scene = load_scene(SCENE)
    got = check(scene, spec, designs=("toy", "toy_mon"))
    single = check(scene.with_tracker(design="single"), spec)
    monitored = check(scene, spec, designs=("monitor",))
    assert [(r.property, r.verdict, r.optimum) for r in got] == [
        (r.property, r.verdict, r.optimum) for r in single + monitored
    ]


def test_a_campaign_summary_counts_it_under_its_label(toy: None) -> None:
    specs = [load_spec(SPEC)]
    doc = read_json(SCENE)
    target = TargetSpec(*doc["target"]["start"], doc["target"]["step"])
    units = plan_units("s", target, specs, [(6, 8)], ("toy", "toy_mon"))
    assert set(units) == {"toy"}  # both designs unfold with the toy tracker
    group = Group(
        "video", "s", target, "toy", tuple(units["toy"]),
        tuple((str(SPEC), SPEC.read_text()) for _ in specs), None, None,
    )  # fmt: skip
    rows = run_group(group, doc)
    for r in rows:
        validate({"format": FORMAT, "version": VERSION, **r}, "campaign-row")
    summary = summarise(rows, "scenes").to_dict()
    validate(summary, "campaign-summary")
    assert summary["designs"] == ["toy", "toy_mon"]
    assert sum(summary["cells"]["toy"][p]["rows"] for p in summary["properties"]) == 2
    assert registry.label("toy_mon") == "toy + monitor"
