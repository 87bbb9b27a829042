"""Round 21's review of multi-target verify, replay and campaign (docs/trackers.md,
docs/campaign.md): ``lesmc replay`` of ``lesmc verify --scene S --target X,Y@K --design
sort`` (S without a target) places the recorded target and confirms; hand-edited
``meta.window`` and ``meta.properties`` are located errors (exit 2); a campaign refuses a
heatmap detector file without a box for sort before any video is perceived; a
multi-target campaign group locates its scene's errors at the scene file; a unit's key
holds ``within R``, ``allow ...`` and ``inject grid`` (and the keys of properties without
them stay those of earlier versions); verify and campaign refuse certified payoffs for a
multi-target design in one message; the engine name of a multi-target row comes from
lesmc/engines/registry.py; ``expand_designs`` names a multi-target design only with
``multi=True``.

A small scene: a 12-frame 448 x 448 video (seed 5) perceived without a target, as
tests/test_multi_replay.py's."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from cli_run import lesmc
from multi_video import SPEC, write_small_video

#: tests/test_multi_replay.py's target: a hijack and a loss, both confirmed by the replay
X, Y, STEP = 119.0, 71.5, 4


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The video, its scene without a target (``lesmc perceive -o``), the spec and
    ``lesmc verify --scene SCENE --target X,Y@STEP --design sort`` into OUT (no frames:
    verify does not replay)."""
    base = tmp_path_factory.mktemp("review21")
    video, scene, spec, out = base / "video", base / "scene.json", base / "id.spec", base / "out"
    write_small_video(video)
    spec.write_text(SPEC)
    r = lesmc("perceive", str(video), "-o", str(scene))
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    assert "target" not in json.loads(scene.read_text())
    r = lesmc("verify", "--scene", str(scene), "--target", f"{X},{Y}@{STEP}", "--design",
              "sort", "--spec", str(spec), "--out", str(out))  # fmt: skip
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
    return {"video": video, "scene": scene, "spec": spec, "out": out}


def test_replay_places_the_target_verify_placed(made: dict[str, Path]) -> None:
    """The results record the target as the scene format has it, and ``lesmc replay``
    (which before refused: ``scene.json:1:1: target: is missing``) confirms both
    counterexamples; results without the record, on a scene without a target, are an
    error naming meta.scene_target (exit 2)."""
    results = made["out"] / "results.json"
    doc = json.loads(results.read_text())
    placed = doc["meta"]["scene_target"]
    assert placed["step"] == STEP and placed["start"] == pytest.approx([X, Y])
    r = lesmc("replay", str(results), "--frames", str(made["video"]), "--json")
    assert "Traceback" not in r.stderr, r.stderr
    assert r.returncode == 1, r.stderr  # violations confirmed
    rows = json.loads(r.stdout)["replays"]
    assert [(x["property"], x["replay"]["status"]) for x in rows] == [
        ("hijack", "confirmed"),
        ("lose", "confirmed"),
    ]
    del doc["meta"]["scene_target"]
    old = made["out"].parent / "old.json"
    old.write_text(json.dumps(doc))
    r = lesmc("replay", str(old), "--frames", str(made["video"]))
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert "meta.scene_target" in r.stderr


def _meta_line(text: str, key: str) -> int:
    """The 1-based line of ``meta``'s ``key`` in a document written with indent 1 (meta's
    fields are the only ones indented by two spaces and named so)."""
    lines = text.splitlines()
    return next(i for i, s in enumerate(lines, 1) if s.startswith(f'  "{key}":'))


@pytest.mark.parametrize(
    ("key", "value", "what"),
    [
        ("window", [7], "meta.window: must have at least 2 items"),
        ("window", "x", "meta.window: expected array or null, got str"),
        ("properties", "identity.spec", "meta.properties: expected array, got str"),
        ("scene_target", {"step": 4}, "meta.scene_target: missing 'start'"),
    ],
)
def test_bad_meta_is_a_located_error(
    made: dict[str, Path], tmp_path: Path, key: str, value: Any, what: str
) -> None:
    """Hand-edited meta fields (before: IndexError or ValueError, exit 4; a string of
    properties read one character a file) are refused at FILE:LINE:COL, exit 2."""
    doc = json.loads((made["out"] / "results.json").read_text())
    doc["meta"][key] = value
    bad = tmp_path / "bad.json"
    text = json.dumps(doc, indent=1)
    bad.write_text(text)
    r = lesmc("replay", str(bad), "--frames", str(made["video"]))
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert f"{bad}:{_meta_line(text, key)}:3: {what}" in r.stderr


def test_campaign_refuses_a_boxless_heatmap_file_for_sort_up_front(
    made: dict[str, Path], tmp_path: Path
) -> None:
    """``campaign --design sort --detector points.toml`` (a heatmap file without ``box``):
    exit 2 naming ``box = [w, h]`` before anything is perceived (the network file is
    not even read: an empty one will do), nothing written."""
    (tmp_path / "net.onnx").write_bytes(b"")
    toml = tmp_path / "points.toml"
    toml.write_text(
        'kind = "heatmap"\nnetwork = "net.onnx"\nchannels = "gray"\nscale = [0.0, 1.0]\n'
        'stride = 4\nthreshold = 0.5\nscore = "sigmoid"\nnms_radius = 2\noutput = "heatmap"\n'
    )
    out = tmp_path / "c"
    r = lesmc("campaign", str(made["video"]), "--design", "sort", "--detector", str(toml),
              "--out", str(out), "--workers", "0")  # fmt: skip
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert "box = [w, h]" in r.stderr and "perceiving" not in r.stderr
    assert not out.exists()


def test_a_multi_group_locates_scene_errors_at_the_scene_file(
    made: dict[str, Path], tmp_path: Path
) -> None:
    """A campaign group of sort on a scene whose detections are points: the error names
    the scene file (OUT/scenes/VIDEO.json in a campaign), not a made-up name."""
    from lesmc.campaign.multi_rows import run_multi_group
    from lesmc.campaign.plan import Group, plan_units
    from lesmc.common.errors import InputError
    from lesmc.language.parser import parse_spec
    from lesmc.scene import footage_from_dict
    from lesmc.tracking.targets import TargetSpec

    data = json.loads(made["scene"].read_text())
    for f in data["frames"]:
        for d in f["detections"]:
            d.pop("w", None), d.pop("h", None)
    points = tmp_path / "points.json"
    points.write_text(json.dumps(data))
    footage, _ = footage_from_dict(data, str(points))
    target = TargetSpec(X, Y, STEP)
    specs = [parse_spec(SPEC, str(made["spec"]))]
    (units,) = plan_units("k", target, specs, [(2, 4)], ("sort",)).values()
    group = Group("video", "k", target, "sort", tuple(units), ((str(made["spec"]), SPEC),),
                  None, None, scene_file=str(points))  # fmt: skip
    with pytest.raises(InputError) as err:
        run_multi_group(group, footage)
    assert str(err.value).startswith(str(points)), str(err.value)
    assert "has no box" in str(err.value)


KEYED = """property p {
    attack window 2..4%s
    minimize payoff
    subject to lost(0..end) > 1
    holds if optimum > 3.0
}
"""


def _key(clause: str, design: str = "sort") -> str:
    from lesmc.campaign.plan import unit_key
    from lesmc.language.parser import parse_spec
    from lesmc.tracking.targets import TargetSpec

    (p,) = parse_spec(KEYED % clause, "x.spec").properties
    return unit_key("abc", TargetSpec(X, Y, STEP), design, p)


def test_unit_keys_hold_the_attackers_clauses() -> None:
    """``within R``, ``allow ...`` and ``inject grid`` change a unit's key (a rerun into
    the same OUT with another radius redoes its rows); the key of a property without
    them is the one lesmc computed before this change (recorded from the merged code
    of round 21: existing OUT directories keep their rows)."""
    plain = _key("")
    assert plain == "45bc44f684ce0b56b612"
    assert _key("", "single") == "e7ab24e40f172d842667"
    keys = [
        plain,
        _key(" within 30"),
        _key(" within 40"),
        _key(" within 30 allow hide, inject"),
        _key(" allow hide, inject", "single"),
        _key(" allow hide, inject\n    inject grid 5 within 10 payoff 0.5", "single"),
        _key(" allow hide, inject\n    inject grid 5 within 10 payoff 0.25", "single"),
    ]
    assert len(set(keys)) == len(keys)
    assert _key(" allow hide") == plain  # the default attacker, spelled out


def test_verify_and_campaign_refuse_certified_payoffs_in_one_message(
    made: dict[str, Path], tmp_path: Path
) -> None:
    """The same refusal from both verbs (one function), naming the option given."""
    v = lesmc("verify", "--scene", str(made["scene"]), "--target", f"{X},{Y}@{STEP}", "--design",
              "sort", "--payoffs", "certified", "--out", str(tmp_path / "v"))  # fmt: skip
    c = lesmc("campaign", "--design", "sort", "--payoffs", "certified", "--out",
              str(tmp_path / "c"))  # fmt: skip
    want = (
        "--design sort: --payoffs certified applies to the point designs; a multi-target "
        "design is checked on attack payoffs"
    )
    for r in (v, c):
        assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
        assert want in r.stderr


def test_the_multi_engine_name_in_the_row_schema_is_the_registrys(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """campaign-row's ``stats.engine`` accepts the multi-target engine's name as
    lesmc/engines/registry.py spells it (renamed here: the schema follows)."""
    from lesmc.engines import registry as engines
    from lesmc.schemas import errors, schema

    monkeypatch.setattr(engines, "MULTI", "exact-multi")
    sch = schema("campaign-row")
    stats = sch["properties"]["stats"]
    row = {"engine": "exact-multi", "states_expanded": 1, "seconds": 0.1, "stopped": "finished"}
    assert not errors(row, stats, sch, "stats")
    assert errors(row | {"engine": "multi"}, stats, sch, "stats")


def test_expand_designs_names_a_multi_target_design_with_multi_only() -> None:
    import lesmc
    from lesmc.common.errors import UsageError

    assert lesmc.expand_designs("sort", multi=True) == ("sort",)
    with pytest.raises(UsageError) as err:
        lesmc.expand_designs("sort")
    assert "multi=True" in err.value.message
    assert "campaign is not supported" not in err.value.message
