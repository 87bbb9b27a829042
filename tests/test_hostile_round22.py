"""The hostile-input run of round 22: errors round 21 left unlocated, and round 21's new
inputs edited by hand. Each case was mishandled before its fix:

- a scene's ``"unpriced"`` payoff that a check reads, and a target's velocity that the
  tracker's state cannot take, were reported as ``FILE: frame N, detection 'id'`` (or
  ``FILE: target``), without the line;
- a ``joint`` injection counterexample whose path takes a candidate the scene does not
  have, and results whose ``meta.scene`` names another scene, were replayed (the path
  left the design, the attack was derived up to there: "confirmed (repaired)" or
  "diverged"); a counterexample step whose ``obs`` disagrees with its listed path was not
  noticed at all (the table shows one attack, the replay replays the other).

Every case goes through the real entry point and must exit 2 at the offending field's
``FILE:LINE:COL`` (its line found here by a regex over the written file), with no
traceback, and leave the input files as they were."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_run import lesmc
from test_hostile_round21 import INJECT_SPEC, _joint_scene

from lesmc.video.synth import SynthConfig
from lesmc.video.write import write_video

SPEC = """property p {
    attack window 2..4
    minimize payoff
    subject to dist.sum(0..end) > 20
    holds if optimum > 100
}
"""


def _line_of(text: str, pattern: str, nth: int = 0) -> int:
    """The 1-based line of the ``nth`` match of ``pattern`` in ``text``."""
    m = list(re.finditer(pattern, text))[nth]
    return text.count("\n", 0, m.start()) + 1


def _refused(r: Any, path: str, line: int, *said: str) -> None:
    """Exit 2, no traceback, the first line at ``path:line:COL`` and saying ``said``."""
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr, r.stderr
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    first = next(x for x in r.stderr.splitlines() if x.startswith(path))
    assert re.match(rf"{re.escape(path)}:{line}:\d+: ", first), (line, r.stderr)
    for s in said:
        assert s in first, (s, r.stderr)


def _point_scene(tmp_path: Path, name: str, edit: Any) -> tuple[str, str]:
    """tests/test_hostile_round21.py's joint scene without its candidates, edited by
    ``edit``, written as ``name`` (indented: one field a line); its name and text."""
    doc = _joint_scene()
    for f in doc["frames"]:
        del f["candidates"]
    doc["version"] = 1
    edit(doc)
    text = json.dumps(doc, indent=1)
    (tmp_path / name).write_text(text)
    (tmp_path / "p.spec").write_text(SPEC)
    return name, text


@pytest.mark.parametrize("verb", ["check", "build"])
def test_an_unpriced_payoff_read_is_refused_at_its_line(tmp_path: Path, verb: str) -> None:
    """The target's detection at step 3 (in the attack window: the check reads its
    payoff) unpriced; the far one of step 6 too, which no model reads."""

    def unprice(doc: dict[str, Any]) -> None:
        doc["frames"][3]["detections"][0]["payoff"] = "unpriced"
        doc["frames"][6]["detections"][1]["payoff"] = "unpriced"

    name, text = _point_scene(tmp_path, "s.json", unprice)
    more = ["p.spec"] if verb == "check" else ["--window", "2..4", "-o", "m.lts"]
    r = lesmc(verb, name, *more, cwd=tmp_path)
    _refused(r, name, _line_of(text, r'"payoff": "unpriced"'), "detection '3:0'", "--price-all")
    assert (tmp_path / name).read_text() == text and not (tmp_path / "m.lts").exists()


GOOD_MODEL = {
    "F": [[1, 0, 1, 0], [0, 1, 0, 1], [0, 0, 1, 0], [0, 0, 0, 1]],
    "H": [[1, 0, 0, 0], [0, 1, 0, 0]],
    "Q": np.eye(4).tolist(),
    "R": (np.eye(2) * 25).tolist(),
    "P0": (np.eye(4) * 100).tolist(),
}


@pytest.mark.parametrize("verb", ["check", "track"])
def test_a_velocity_the_state_cannot_take_is_refused_at_its_line(tmp_path: Path, verb: str) -> None:
    """A declared model whose state names no vx, vy, and a target with a velocity."""

    def declare(doc: dict[str, Any]) -> None:
        doc["tracker"] = {"model": {"state": ["x", "y", "u", "v"], **GOOD_MODEL}}

    name, text = _point_scene(tmp_path, "s.json", declare)
    r = lesmc(verb, name, *(["p.spec"] if verb == "check" else []), cwd=tmp_path)
    _refused(r, name, _line_of(text, r'"velocity": \['), "target: velocity [10, 0]", "vx and vy")


@pytest.fixture(scope="module")
def joint(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``lesmc check scene.json inj.spec --design joint --report r``: a joint injection
    counterexample (tests/test_hostile_round21.py's scene), and a 6-frame video ``v``."""
    base = tmp_path_factory.mktemp("hostile22")
    (base / "scene.json").write_text(json.dumps(_joint_scene(), indent=1))
    (base / "inj.spec").write_text(INJECT_SPEC)
    r = lesmc("check", "scene.json", "inj.spec", "--design", "joint", "--report", "r", cwd=base)
    assert r.returncode == 1, r.stderr
    write_video(SynthConfig(frames=6, width=64, height=64, seed=1, density=1.0), base / "v")
    return base


def _cex(doc: dict[str, Any]) -> tuple[list[Any], list[dict[str, Any]]]:
    """The counterexample's listed path's ``obs`` and its result's ``steps``."""
    run = doc["runs"][0]
    no = run["roles"]["counterexample"][0]
    return run["paths"][no - 1]["obs"], run["results"][0]["counterexample"]["steps"]


def _replay(base: Path, doc: dict[str, Any]) -> tuple[Any, str]:
    text = json.dumps(doc, indent=1)
    (base / "edited.json").write_text(text)
    r = lesmc("replay", "edited.json", "--frames", "v", cwd=base)
    assert (base / "edited.json").read_text() == text
    return r, text


def test_a_path_taking_a_candidate_the_scene_lacks_is_refused(joint: Path) -> None:
    """The path and its step both take '2:c9' (the frame's one candidate is '2:c0')."""
    doc = json.loads((joint / "r" / "results.json").read_text())
    obs, steps = _cex(doc)
    k = obs.index("2:c0")  # the injection: step k + 1
    obs[k] = steps[k + 1]["obs"] = "2:c9"
    r, text = _replay(joint, doc)
    _refused(r, "edited.json", _path_obs_line(text), "paths[", f".obs[{k}]", "'2:c9'", "scene.json")


def _path_obs_line(text: str) -> int:
    """The line of '2:c9' in the listed path's ``obs`` array (a bare string on its line,
    not the step's ``"obs": "2:c9"``)."""
    return _line_of(text, r'(?m)^\s*"2:c9",?$')


@pytest.mark.parametrize("where", ["step", "path"])
def test_a_step_disagreeing_with_its_path_is_refused(joint: Path, where: str) -> None:
    """One of the two edited: the step's ``obs`` is at fault either way (the file says two
    things); refused by every reader of the results (replay and report)."""
    doc = json.loads((joint / "r" / "results.json").read_text())
    obs, steps = _cex(doc)
    k = obs.index("2:c0")
    if where == "step":
        steps[k + 1]["obs"] = "2:c9"
    else:
        obs[k] = "2:c9"
    r, text = _replay(joint, doc)
    line = _line_of(text, r'"obs": "2:c[09]"')
    _refused(r, "edited.json", line, f"counterexample.steps[{k + 1}].obs", "path")
    r = lesmc("report", "edited.json", "--out", "rep", cwd=joint)
    _refused(r, "edited.json", line, f"counterexample.steps[{k + 1}].obs")


@pytest.mark.parametrize("change", ["moved", "renamed"])
def test_results_pointed_at_another_scene_are_refused(joint: Path, change: str) -> None:
    """``meta.scene`` names a scene whose detections are 3 px to the right, or renamed."""
    other = _joint_scene()
    for f in other["frames"]:
        for d in f["detections"]:
            if change == "moved":
                d["x"] += 3.0
            else:
                d["id"] = "x" + d["id"]
    (joint / "other.json").write_text(json.dumps(other))
    doc = json.loads((joint / "r" / "results.json").read_text())
    doc["meta"]["scene"] = "other.json"
    r, text = _replay(joint, doc)
    m = re.search(r'"scene": \{[^{}]*?"detections": \[\s*\[\s*\[', text)  # runs[0].scene
    assert m is not None
    line = text.count("\n", 0, m.end()) + 1  # its detections[0][0]: the third '['
    said = "is at (100, 50) in the results, at (103, 50)" if change == "moved" else "is not in"
    _refused(r, "edited.json", line, "runs[0].scene.detections[0][0]", said, "other.json")


def _heatmap_file(d: Path) -> Path:
    """A heatmap network written with onnx.helper (no torch export): one 4x4 convolution
    of stride 4 averaging the grey input, minus 0.3 (raw scores); its detector file."""
    onnx = pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    from onnx import TensorProto, helper, numpy_helper
    from test_campaign_detector import H, W

    w = numpy_helper.from_array(np.full((1, 1, 4, 4), 1 / 16, np.float32), "w")
    b = numpy_helper.from_array(np.array([-0.3], np.float32), "b")
    conv = helper.make_node("Conv", ["x", "w", "b"], ["y"], strides=[4, 4], kernel_shape=[4, 4])
    io = [
        helper.make_tensor_value_info(n, TensorProto.FLOAT, ["B", 1, h, w_])
        for n, h, w_ in (("x", H, W), ("y", H // 4, W // 4))
    ]
    graph = helper.make_graph([conv], "spot", [io[0]], [io[1]], [w, b])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.save(model, str(d / "spot.onnx"))
    toml = d / "spot.toml"
    toml.write_text(
        'kind = "heatmap"\nnetwork = "spot.onnx"\nstride = 4\nthreshold = 0.0\n'
        'score = "raw"\nnms_radius = 2\n'
    )
    return toml


def test_a_box_too_thin_for_a_scene_is_refused_at_its_line(tmp_path: Path) -> None:
    """``box = [1e-300, 4]``: each a number > 0, but at x = 100 both corners of the box are
    100: perceive wrote a scene its own loader refused ("too small for its position")."""
    toml = _heatmap_file(tmp_path)
    toml.write_text(toml.read_text() + "box = [1e-300, 4]\n")
    (tmp_path / "frames").mkdir()
    r = lesmc("perceive", "frames", "--detector", "spot.toml", "-o", "s.json", cwd=tmp_path)
    _refused(r, "spot.toml", 7, "box: must be [w, h]")
    assert not (tmp_path / "s.json").exists()


def test_a_campaigns_kept_scene_of_other_files_is_refused_at_its_field(tmp_path: Path) -> None:
    """``campaign --detector`` run again after the detector file changed, or its network:
    refused (as before) at the kept scene's field that records the file's sha256."""
    from test_campaign_detector import SPEC as DET_SPEC
    from test_campaign_detector import _frames

    _frames(tmp_path, 0)
    toml = _heatmap_file(tmp_path)
    (tmp_path / "p.spec").write_text(DET_SPEC)
    (tmp_path / "targets.txt").write_text("video0 10,30@0\n")

    def campaign(det: str) -> Any:
        return lesmc("campaign", "video0", "--detector", det, "--out", "out", "--workers", "0",
                     "--spec", "p.spec", "--windows", "5..5:2..2", "--targets", "targets.txt",
                     "--design", "single", cwd=tmp_path)  # fmt: skip

    r = campaign("spot.toml")
    assert "Traceback" not in r.stderr and r.returncode in (0, 1), r.stderr
    kept = tmp_path / "out" / "scenes" / "video0.json"
    rows = (tmp_path / "out" / "results.jsonl").read_text()
    text = kept.read_text()
    other = tmp_path / "other.toml"
    other.write_text(toml.read_text().replace("threshold = 0.0", "threshold = 0.1"))
    r = campaign("other.toml")
    _refused(
        r, "out/scenes/video0.json", _line_of(text, r'"sha256": "'), "meta.detector_file.sha256"
    )
    net = tmp_path / "spot.onnx"
    net.write_bytes(net.read_bytes() + b"\0")  # another network file (refused unread)
    r = campaign("spot.toml")
    _refused(r, "out/scenes/video0.json", _line_of(text, r'"network_sha256": "'), "network")
    assert kept.read_text() == text and (tmp_path / "out" / "results.jsonl").read_text() == rows


def test_frames_the_front_end_cannot_register_are_refused_at_the_frame(joint: Path) -> None:
    """The results replayed on a 64 x 64 video with no corner features: the front end's
    RegistrationError escaped (internal error, exit 4); now an input error at the frame's
    file, as ``lesmc perceive`` says it."""
    r = lesmc("replay", "r/results.json", "--frames", "v", cwd=joint)
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr, r.stderr
    assert r.returncode == 2, r.stderr
    first = sorted((joint / "v").glob("*.png"))[1]  # the second frame meets the first
    assert f"v/{first.name}: cannot register with the previous frame" in r.stderr, r.stderr


def test_a_multi_check_whose_scene_is_gone_is_refused_at_meta_scene(tmp_path: Path) -> None:
    """A ``lesmc-multi-check`` document (``check --design sort --json``) whose
    ``meta.scene`` names no file, and no scene.json beside it: refused naming the file
    only (``FILE: the scene ... is not found``); now at ``meta.scene``'s line."""

    def boxes(doc: dict[str, Any]) -> None:
        doc["version"] = 2
        for f in doc["frames"]:
            for d in f["detections"]:
                d["w"] = d["h"] = 8.0

    name, _ = _point_scene(tmp_path, "s.json", boxes)
    r = lesmc("check", name, "p.spec", "--design", "sort", "--json", cwd=tmp_path)
    assert r.returncode in (0, 1), r.stderr
    doc = json.loads(r.stdout)
    assert doc["format"] == "lesmc-multi-check"
    doc["meta"] = {"scene": "gone.json"}
    (tmp_path / "m").mkdir()
    (tmp_path / "v").mkdir()  # frames never read
    text = json.dumps(doc, indent=1)
    (tmp_path / "m" / "mc.json").write_text(text)
    r = lesmc("replay", "m/mc.json", "--frames", "v", cwd=tmp_path)
    _refused(r, "m/mc.json", _line_of(text, r'"scene": "gone.json"'), "meta.scene", "not found")


def _unref(doc: dict[str, Any]) -> str:
    """The third state of the counterexample's path without its ``ref``; its id."""
    run = doc["runs"][0]
    q = run["paths"][run["roles"]["counterexample"][0] - 1]["states"][3]
    del run["states"][q]["ref"]
    return str(q)


def _unlabel(doc: dict[str, Any]) -> str:
    """The counterexample's path with one label fewer than its states."""
    run = doc["runs"][0]
    run["paths"][run["roles"]["counterexample"][0] - 1]["labels"].pop(3)
    return "labels"


@pytest.mark.parametrize("edit", [_unref, _unlabel], ids=["a state's ref", "a label"])
def test_a_path_the_report_cannot_draw_is_refused(joint: Path, edit: Any) -> None:
    """A state of a listed path without a position in the reference frame while the others
    have one (ValueError), a path with fewer labels than states (IndexError): internal
    errors of ``lesmc report``; now refused at the path."""
    doc = json.loads((joint / "r" / "results.json").read_text())
    no = doc["runs"][0]["roles"]["counterexample"][0]
    said = edit(doc)
    text = json.dumps(doc, indent=1)
    (joint / "drawn.json").write_text(text)
    r = lesmc("report", "drawn.json", "--out", "drawn", cwd=joint)
    starts = [m.start() for m in re.finditer(r'\{\s*"no": ', text)]
    path_at = text[starts[no - 1] :]  # the listed path's text (the paths are in order)
    key = '"labels": \\[' if said == "labels" else '"states": \\[\\s*(?:"[^"]*",\\s*){3}'
    m = re.search(key, path_at)
    assert m is not None
    line = text.count("\n", 0, starts[no - 1] + (m.start() if said == "labels" else m.end())) + 1
    _refused(r, "drawn.json", line, f"runs[0].paths[{no - 1}]", said)
    assert not (joint / "drawn").exists()
