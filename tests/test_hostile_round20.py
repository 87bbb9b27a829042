"""The hostile-input run on round 20's inputs: ``allow`` edge cases around ``inject grid``,
``lesmc build -o`` paths, and ``lesmc report`` on a hand-edited ``lesmc-multi-check``
version 2 document. Each case was mishandled before its fix (a misleading parse error
at the wrong token, exit 4 from an OSError or a ValueError, a report drawn from an
impossible counterexample); every case runs the real entry point."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import pytest
from cli_run import ROOT, lesmc

CROSSING = ROOT / "examples" / "crossing.json"

SPEC = """property p {{
  attack window 1..3 {allow}
  minimize payoff
  subject to dist.max(0..end) > 50
  holds if optimum > 3
  on x, y
}}
"""


def _refused(r: Any, *wanted: str) -> None:
    """Exit 2, no traceback, no internal error, every ``wanted`` text on stderr."""
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr, r.stderr
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    for w in wanted:
        assert w in r.stderr, r.stderr


def _single_scene(tmp_path: Path) -> Path:
    """examples/crossing.json tracked by the single design."""
    doc = json.loads(CROSSING.read_text())
    doc["tracker"] = {"design": "single"}
    path = tmp_path / "single.json"
    path.write_text(json.dumps(doc))
    return path


@pytest.mark.parametrize("allow", ["allow hide,", "allow hide, inject,"])
def test_allow_ending_in_a_comma_before_a_keyword_names_the_keyword(
    tmp_path: Path, allow: str
) -> None:
    """``allow hide,`` at the end of a line, ``minimize payoff`` on the next: 'minimize' was
    read as an action and the parser stopped at 'payoff' (3:12) with "expected ','"."""
    spec = tmp_path / "p.spec"
    spec.write_text(SPEC.format(allow=allow))
    assert f"{allow}\n  minimize payoff\n" in spec.read_text()
    r = lesmc("check", str(_single_scene(tmp_path)), str(spec))
    _refused(r, f"{spec}:3:3: allow needs an action", "'minimize' is a keyword")
    assert r.stdout == ""


def test_allow_ending_in_a_comma_before_a_brace_says_no_action_follows(tmp_path: Path) -> None:
    spec = tmp_path / "p.spec"
    spec.write_text("property p {\n  attack window 1..3 allow hide, }\n")
    r = lesmc("check", str(_single_scene(tmp_path)), str(spec))
    _refused(r, f"{spec}:2:34: allow needs an action", "no action follows")


def test_a_wide_grid_with_few_points_is_not_refused_as_too_big(tmp_path: Path) -> None:
    """``inject grid 1e308 within 1e308``: 5 points (the prediction and 4 neighbours), but
    2 * R overflowed to inf and the clause was refused as having more than 1000 points."""
    spec = tmp_path / "p.spec"
    spec.write_text(
        SPEC.format(allow="allow hide, inject\n  inject grid 1e308 within 1e308 payoff 1")
    )
    r = lesmc("check", str(_single_scene(tmp_path)), str(spec), "--json")
    assert "more than 1000 points" not in r.stderr, r.stderr
    assert r.returncode in (0, 1), (r.returncode, r.stderr)
    note = json.loads(r.stdout)["results"][0]["notes"]
    assert any("at 5 grid points" in n for n in note), note


@pytest.mark.parametrize("design", ["single", "sort"])
def test_build_output_under_a_file_is_a_usage_error(tmp_path: Path, design: str) -> None:
    """``-o FILE/x.npz``: mkdir raised FileExistsError, exit 4."""
    blocker = tmp_path / "m.npz"
    blocker.write_bytes(b"not a directory")
    out = blocker / "sub" / "x.npz"
    r = lesmc("build", str(CROSSING), "--design", design, "--window", "1..3", "-o", str(out))
    _refused(r, f"{out}: cannot write the file: a directory on its path is a file")
    assert blocker.read_bytes() == b"not a directory"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.npz"]


@pytest.fixture(scope="module")
def multi_doc(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """A lesmc-multi-check document of examples/crossing.json on sort, its counterexample
    steps given the drawing keys of version 2 (as lesmc verify --design sort writes)."""
    tmp = tmp_path_factory.mktemp("multi")
    spec = tmp / "id.spec"
    spec.write_text(
        "property hijack {\n  attack window 1..3 within 40\n  minimize payoff\n"
        "  subject to switches(0..end) > 0\n  holds if optimum > 3.0\n}\n"
    )
    r = lesmc("check", str(CROSSING), str(spec), "--design", "sort", "--json")
    assert r.returncode == 1, r.stderr
    doc: dict[str, Any] = json.loads(r.stdout)
    assert doc["format"] == "lesmc-multi-check" and doc["version"] == 2
    for s in doc["results"][0]["counterexample"]:
        s["switch"] = False
        s["reference"] = [10.0, 20.0, 30.0, 40.0]
        s["tracks"] = [{"id": 1, "status": "confirmed", "box": [10.0, 20.0, 30.0, 40.0]}]
        s["attacked"] = []
    return doc


def _report(tmp_path: Path, doc: dict[str, Any]) -> Any:
    path = tmp_path / "results.json"
    path.write_text(json.dumps(doc, indent=1))
    return lesmc("report", str(path), "--out", str(tmp_path / "out"), timeout=300)


def test_the_unedited_multi_document_is_drawn(tmp_path: Path, multi_doc: dict[str, Any]) -> None:
    r = _report(tmp_path, multi_doc)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "out" / "report.html").is_file()


def _edit(doc: dict[str, Any], where: str, value: Any) -> None:
    """Set the field at ``where`` (``step`` / ``frame`` / ``reference`` / ``tracks``) of the
    last counterexample step (a non-first one), or drop a track's box (``nobox``)."""
    steps = doc["results"][0]["counterexample"]
    s = steps[-1]
    if where == "nobox":
        del s["tracks"][0]["box"]
    elif where == "box":
        s["tracks"][0]["box"] = value
    elif where == "attacked":
        s["attacked"] = [{"id": "5:0", "action": "hidden", "position": value}]
    else:
        s[where] = value


@pytest.mark.parametrize(
    ("where", "value", "item", "message"),
    [
        # matplotlib: "Axis limits cannot be NaN or Inf", exit 4
        ("box", [1e308, -1e308, 1e308, 1e308], "tracks[0].box", "must be finite"),
        ("reference", [1e308, 1e308, -1e308, 1e308], "reference", "must be finite"),
        # numpy: a 3-number box cannot be a box's corners, exit 4
        ("box", [30.0, 40.0, 10.0], "tracks[0].box", "must hold 4 numbers, got 3"),
        ("attacked", [1.0, 2.0, 3.0], "attacked[0].position", "must hold 2 numbers, got 3"),
        # KeyError: 'position', exit 4
        ("nobox", None, "tracks[0]", "needs a box [x1, y1, x2, y2] or a position [x, y]"),
        # drawn before, with the steps' panels out of order
        ("step", 0, "step", "must exceed the step before"),
        ("frame", -3, "frame", "must be at least 0, got -3"),
    ],
)
def test_a_hand_edited_multi_document_is_refused_at_its_field(
    tmp_path: Path, multi_doc: dict[str, Any], where: str, value: Any, item: str, message: str
) -> None:
    doc = copy.deepcopy(multi_doc)
    _edit(doc, where, value)
    last = len(doc["results"][0]["counterexample"]) - 1
    r = _report(tmp_path, doc)
    _refused(r, f"results[0].counterexample[{last}].{item}: ", message)
    assert str(tmp_path / "results.json") in r.stderr, r.stderr
    assert not (tmp_path / "out").exists()


def test_an_output_ending_in_a_slash_is_not_written_as_a_file(tmp_path: Path) -> None:
    """``-o OUT/`` (a directory's name): the slash was dropped and a file OUT written,
    or an existing file OUT replaced."""
    existing = tmp_path / "m.npz"
    existing.write_bytes(b"kept")
    for out in (f"{existing}/", f"{tmp_path / 'new'}/"):
        r = lesmc("build", str(CROSSING), "--design", "sort", "--window", "1..3", "-o", out)
        _refused(r, f"{out}: not a regular file")
    assert existing.read_bytes() == b"kept"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.npz"]


@pytest.mark.parametrize("design", ["single", "sort"])
def test_verify_refuses_inject_within_with_a_detector_file_before_perceiving(
    tmp_path: Path, design: str
) -> None:
    """``verify`` perceived the whole video first (and then ignored ``--inject-within``,
    or stopped on something else); it does not perceive candidates through a detector
    file yet (``perceive --detector det.toml -o S --inject-within PX`` writes them)."""
    frames = tmp_path / "frames"
    made = lesmc("synth", str(frames), "--frames", "6", "--size", "128x128", "--seed", "3")
    assert made.returncode == 0, made.stderr
    out = tmp_path / "out"
    detector = ROOT / "examples" / "detectors" / "heatmap.toml"
    r = lesmc(
        "verify", str(frames), "--detector", str(detector), "--inject-within", "5",
        "--target", "10,10", "--design", design, "--out", str(out), timeout=300,
    )  # fmt: skip
    _refused(r, "--inject-within: lesmc verify does not perceive injection candidates", "yet")
    assert "detector file:" not in r.stderr, r.stderr  # nothing was perceived
    assert not out.exists()


def test_verify_sort_with_a_heatmap_detector_file_is_refused_before_perceiving(
    tmp_path: Path,
) -> None:
    """A heatmap detector's detections are points; SORT's IoU needs boxes: verify used to
    perceive and price the whole video first, then stop at OUT/scene.json's first box."""
    frames = tmp_path / "frames"
    made = lesmc("synth", str(frames), "--frames", "6", "--size", "128x128", "--seed", "3")
    assert made.returncode == 0, made.stderr
    out = tmp_path / "out"
    detector = ROOT / "examples" / "detectors" / "heatmap.toml"
    r = lesmc(
        "verify", str(frames), "--detector", str(detector), "--target", "10,10",
        "--design", "sort", "--out", str(out), timeout=300,
    )  # fmt: skip
    _refused(r, "--design sort reads a box on every detection", "heatmap detector file")
    assert "detector file:" not in r.stderr, r.stderr  # nothing was perceived
    assert not out.exists()


@pytest.mark.parametrize("verb", ["import", "perceive"])
def test_an_output_that_would_be_a_frame_is_refused(tmp_path: Path, verb: str) -> None:
    """``import mot DET --frames DIR --detector det.toml -o DIR/frame_00001.png`` wrote the
    scene over an input frame (exit 0); so did ``perceive DIR --detector det.toml``."""
    frames = tmp_path / "frames"
    made = lesmc("synth", str(frames), "--frames", "6", "--size", "128x128", "--seed", "3")
    assert made.returncode == 0, made.stderr
    before = {p.name: p.read_bytes() for p in frames.iterdir()}
    detector = str(ROOT / "examples" / "detectors" / "heatmap.toml")
    det = tmp_path / "det.txt"
    det.write_text("1,-1,60,60,12,8,0.9,-1,-1,-1\n")
    for out in (frames / "frame_00001.png", frames / "extra.png"):
        args = {
            "import": ["import", "mot", str(det), "--frames", str(frames)],
            "perceive": ["perceive", str(frames)],
        }[verb]
        r = lesmc(*args, "--detector", detector, "-o", str(out), timeout=300)
        _refused(r, f"-o/--output {out} would be a frame of {frames}")
    assert {p.name: p.read_bytes() for p in frames.iterdir()} == before
