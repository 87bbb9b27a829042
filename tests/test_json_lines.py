"""Hand-edited JSON documents are refused at the line of the offending field (brief item
1: "FILE:LINE:COL: what is wrong (for JSON: the line and the offending id or field),
exit 2, no traceback"). Before, a results file, a multi-check document and a scene file
named only the field (``FILE: runs[0]...``, ``FILE: frame 5, detection '5:c'``) and a
tracker file in JSON the line of its top-level key (``model``), not the element's.

The expected line and column are found here independently: each edit writes a sentinel
value, and the test looks for the line of the text that holds it."""

from __future__ import annotations

import copy
import json
import random
from pathlib import Path
from typing import Any

import pytest
from cli_run import ROOT, lesmc, sort_hijack_document
from pipeline_run import design_runs

from lesmc.common.locations import item_keys, json_offset
from lesmc.language.parser import load_spec
from lesmc.report.publish import publish
from lesmc.results.document import provenance
from lesmc.scene import load_scene

SCENES = Path(__file__).parent / "scenes"
EXAMPLES = ROOT / "examples"


def _place(text: str, needle: str, nth: int = 0) -> tuple[int, int]:
    """Line and column (1-based) of the ``nth`` occurrence of ``needle`` in ``text``."""
    pos = -1
    for _ in range(nth + 1):
        pos = text.index(needle, pos + 1)
    line = text.count("\n", 0, pos) + 1
    return line, pos - (text.rfind("\n", 0, pos) + 1) + 1


def _refused_at(r: Any, path: Path, line: int, col: int, *wanted: str) -> None:
    """Exit 2, no traceback, stderr's first line ``PATH:LINE:COL: ...`` holding ``wanted``."""
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr, r.stderr
    errors = [ln for ln in r.stderr.splitlines() if ln.startswith(str(path))]
    assert errors, r.stderr
    assert errors[0].startswith(f"{path}:{line}:{col}: "), r.stderr
    for w in wanted:
        assert w in errors[0], r.stderr


# ------------------------------------------------------------------ the position reader


def _dump(value: Any, at: tuple[str | int, ...], out: list[str], where: dict[Any, int]) -> None:
    """JSON text of ``value`` appended to ``out``, recording where each member is named
    (an independent writer: the oracle of :func:`json_offset`)."""
    if isinstance(value, dict):
        out.append("{ ")
        for i, (k, v) in enumerate(value.items()):
            if i:
                out.append(" ,\n  ")
            where[(*at, k)] = sum(map(len, out))
            out.append(json.dumps(k) + " :\t")
            _dump(v, (*at, k), out, where)
        out.append("}")
    elif isinstance(value, list):
        out.append("[")
        for i, v in enumerate(value):
            if i:
                out.append(",  ")
            where[(*at, i)] = sum(map(len, out))
            _dump(v, (*at, i), out, where)
        out.append("\n]")
    else:
        out.append(json.dumps(value))


def _random_value(rng: random.Random, depth: int) -> Any:
    kind = rng.randrange(6 if depth < 4 else 3)
    if kind == 0:
        return rng.choice([0, -1.5e300, 12345678901234, True, None])
    if kind == 1:
        return rng.choice(['a"b', "[{,:}]", "é\\n", ""])
    if kind == 2:
        return rng.random()
    if kind in (3, 4):
        keys = rng.sample(["k", "a.b", '"q"', "x y", "é", "[0]", "long" * 5], rng.randrange(4))
        return {k: _random_value(rng, depth + 1) for k in keys}
    return [_random_value(rng, depth + 1) for _ in range(rng.randrange(4))]


def test_json_offset_finds_every_member_an_independent_writer_placed() -> None:
    rng = random.Random(7)
    checked = 0
    for _ in range(200):
        value = {"top": _random_value(rng, 0), "other": [_random_value(rng, 1)]}
        out: list[str] = ["  "]
        where: dict[Any, int] = {}
        _dump(value, (), out, where)
        text = "".join(out)
        assert json.loads(text) == value
        for keys, pos in where.items():
            assert json_offset(text, list(keys)) == (pos, len(keys)), (text, keys)
            checked += 1
        assert json_offset(text, ["top", "no such key"]) == (where[("top",)], 1)
    assert checked > 1000


def test_item_keys_reads_the_validators_item_names() -> None:
    assert item_keys("runs[0].paths[12].states") == ["runs", 0, "paths", 12, "states"]
    assert item_keys("model.Q[3][2]") == ["model", "Q", 3, 2]
    assert item_keys("frame 5, detection '5:c'") is None
    assert item_keys("(document)") is None


# ------------------------------------------------------------------ results files


@pytest.fixture(scope="module")
def results_doc(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    out = tmp_path_factory.mktemp("results")
    specs = [load_spec(str(SCENES / "rq4_merge.spec"))]
    runs = design_runs(load_scene(SCENES / "rq4_merge.json"), specs, ["single"])
    publish(runs, out, {}, provenance(specs, ["test"]))
    doc: dict[str, Any] = json.loads((out / "results.json").read_text())
    return doc


def test_a_results_field_that_breaks_the_schema_is_refused_at_its_line(
    tmp_path: Path, results_doc: dict[str, Any]
) -> None:
    doc = copy.deepcopy(results_doc)
    doc["runs"][0]["results"][0]["status"] = "fine-by-me"
    path = tmp_path / "results.json"
    text = json.dumps(doc, indent=1)
    path.write_text(text)
    line, col = _place(text, '"status": "fine-by-me"')
    r = lesmc("report", str(path), "--out", str(tmp_path / "rep"))
    _refused_at(r, path, line, col, "runs[0].results[0].status: must be one of")
    assert not (tmp_path / "rep").exists()


def test_a_broken_reference_of_a_results_file_is_refused_at_its_element(
    tmp_path: Path, results_doc: dict[str, Any]
) -> None:
    doc = copy.deepcopy(results_doc)
    doc["runs"][0]["paths"][0]["states"][2] = "zzz-nowhere"
    path = tmp_path / "results.json"
    text = json.dumps(doc, indent=1)
    path.write_text(text)
    # the item is the list of state ids; its line is where "states" is named
    states_at = text.index('"zzz-nowhere"')
    line, col = _place(text[:states_at], '"states"', text[:states_at].count('"states"') - 1)
    r = lesmc("replay", str(path), "--frames", str(tmp_path))
    _refused_at(r, path, line, col, "runs[0].paths[0].states: state 'zzz-nowhere'")


# ------------------------------------------------------------------ multi-check documents


@pytest.fixture(scope="module")
def multi_doc(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    doc = sort_hijack_document()
    assert doc["results"][0]["counterexample"]
    return doc


@pytest.mark.parametrize(
    ("edit", "needle", "wanted"),
    [
        # issue of the brief, item 3: a single-target design's name was drawn (exit 0)
        (lambda d: d.update(design="joint"), '"design": "joint"', "design: must be one of"),
        (
            lambda d: d["results"][0]["counterexample"][-1].update(frame=-7),
            '"frame": -7',
            "].frame: must be at least 0, got -7",
        ),
    ],
    ids=["joint", "frame"],
)
def test_a_hand_edited_multi_check_document_is_refused_at_its_line(
    tmp_path: Path, multi_doc: dict[str, Any], edit: Any, needle: str, wanted: str
) -> None:
    doc = copy.deepcopy(multi_doc)
    edit(doc)
    path = tmp_path / "multi.json"
    text = json.dumps(doc, indent=2)
    path.write_text(text)
    r = lesmc("report", str(path), "--out", str(tmp_path / "rep"))
    _refused_at(r, path, *_place(text, needle), wanted)
    assert not (tmp_path / "rep").exists()


# ------------------------------------------------------------------ scene files


def test_a_scene_detection_is_refused_at_its_field_and_a_duplicate_id_at_the_second(
    tmp_path: Path,
) -> None:
    doc = json.loads((EXAMPLES / "merge.json").read_text())
    doc["frames"][5]["detections"][1]["payoff"] = "cheap"
    doc["frames"][9]["detections"][2]["id"] = "9:t"
    path = tmp_path / "scene.json"
    text = json.dumps(doc, indent=2)
    path.write_text(text)
    r = lesmc("check", str(path), str(EXAMPLES / "merge.spec"))
    line, col = _place(text, '"payoff": "cheap"')
    _refused_at(r, path, line, col, "frame 5, detection '5:c': payoff must be")
    dup = _place(text, '"id": "9:t"', 1)
    assert f"{path}:{dup[0]}:{dup[1]}: frame 9, detection '9:t': duplicate" in r.stderr


# ------------------------------------------------------------------ tracker and detector files


def test_a_tracker_file_in_json_is_refused_at_the_matrix_entry(tmp_path: Path) -> None:
    doc = json.loads((EXAMPLES / "trackers" / "ca6.json").read_text())
    doc["model"]["Q"][3][2] = "wide"
    path = tmp_path / "ca6.json"
    text = json.dumps(doc, indent=2)
    path.write_text(text)
    r = lesmc("track", str(EXAMPLES / "merge.json"), "--tracker", str(path))
    _refused_at(r, path, *_place(text, '"wide"'), "model.Q[3][2] must be a finite number")


def test_a_detector_file_in_json_is_refused_at_its_key(tmp_path: Path) -> None:
    import cv2
    import numpy as np

    frames = tmp_path / "frames"
    frames.mkdir()
    for i in range(2):
        cv2.imwrite(str(frames / f"frame_{i:05d}.png"), np.zeros((64, 64), np.uint8))
    text = (
        '{\n  "comment": "hand-made: \\"stride\\": was 4",\n  "kind": "heatmap",\n'
        '  "network": "heatmap.onnx",\n  "channels": "gray",\n  "scale": [0.0, 1.0],\n'
        '  "stride": -4,\n  "threshold": 0.5\n}\n'
    )
    path = tmp_path / "det.json"
    path.write_text(text)
    (tmp_path / "heatmap.onnx").write_bytes((EXAMPLES / "detectors" / "heatmap.onnx").read_bytes())
    r = lesmc(
        "import", "mot", str(EXAMPLES / "mot" / "det.txt"), "--frames", str(frames),
        "--detector", str(path), "-o", str(tmp_path / "s.json"),
    )  # fmt: skip
    _refused_at(r, path, *_place(text, '"stride": -4'), "stride: must be an integer")
    assert not (tmp_path / "s.json").exists()


def test_a_detection_without_a_box_for_sort_is_refused_at_its_line(tmp_path: Path) -> None:
    doc = json.loads((EXAMPLES / "crossing.json").read_text())
    det = doc["frames"][2]["detections"][1]
    del det["w"], det["h"]
    path = tmp_path / "scene.json"
    text = json.dumps(doc, indent=1)
    path.write_text(text)
    line = _place(text, f'"id": "{det["id"]}"')[0] - 1  # the object's brace: the line before
    col = text.split("\n")[line - 1].index("{") + 1
    r = lesmc("track", str(path), "--design", "sort")
    _refused_at(r, path, line, col, f"detection '{det['id']}': has no box (w, h)")


def test_export_refuses_a_results_file_at_the_states_it_cannot_mark(
    tmp_path: Path, results_doc: dict[str, Any]
) -> None:
    r = lesmc(
        "build", str(EXAMPLES / "merge.json"), "--window", "6..8", "-o", "m.lts", cwd=tmp_path
    )
    assert r.returncode == 0, r.stderr
    doc = copy.deepcopy(results_doc)
    doc["runs"][0]["results"][0]["witness"]["states"] = ["q-sentinel", 7]
    path = tmp_path / "r.json"
    text = json.dumps(doc, indent=1)
    path.write_text(text)
    before = text[: text.index('"q-sentinel"')]
    line, col = _place(before, '"states"', before.count('"states"') - 1)
    r = lesmc(
        "export", "m.lts", "--format", "dot", "-o", "m.dot", "--results", str(path), cwd=tmp_path
    )
    _refused_at(r, path, line, col, "runs[0].results[0].witness.states: must be a list")
    assert not (tmp_path / "m.dot").exists()
