"""MOTChallenge files in (``lesmc import mot``): a round trip through lesmc's own video,
located errors through the real CLI, and a loader that never crashes on mutated files."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest
from cli_run import lesmc
from hypothesis import given, settings
from hypothesis import strategies as st

from lesmc.common.errors import LesmcError
from lesmc.scene import load_scene
from lesmc.scene.mot import Payoffs, footage_from_boxes, read_boxes, write_det, write_gt

BOX = (12.0, 8.0)


@pytest.fixture(scope="module")
def perceived(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any], int]:
    """A synthetic video perceived into a scene tracking a true vehicle; the truth; its id."""
    d = tmp_path_factory.mktemp("mot")
    r = lesmc("synth", str(d / "v"), "--frames", "8", "--size", "512x512", "--density", "3")
    assert r.returncode == 0, r.stderr
    truth = json.loads((d / "v" / "truth.json").read_text())
    for v in truth["frames"][5]["vehicles"]:
        r = lesmc(
            "perceive", str(d / "v"), "--truth", str(d / "v" / "truth.json"),
            "--target", f"{v['x']!r},{v['y']!r}@5", "-o", str(d / "scene.json"),
            "--max-iter", "2",
        )  # fmt: skip
        if r.returncode == 0:
            return d, truth, int(v["id"])
    raise AssertionError("no vehicle of frame 5 lies in the tracker's gate")


def test_a_mot_round_trip_gives_perceives_scene(
    perceived: tuple[Path, dict[str, Any], int],
) -> None:
    """det.txt and gt.txt written from perceive's scene and the video's truth, imported:
    the same detections (ids, positions, payoffs, unattackable ones), the same target."""
    d, truth, vid = perceived
    scene = load_scene(d / "scene.json")
    write_det(scene, d / "det.txt", BOX)
    rows = [
        (int(v["id"]), int(f["step"]), float(v["x"]), float(v["y"]))
        for f in truth["frames"]
        if f["step"] >= 5
        for v in f["vehicles"]
    ]
    write_gt(rows, d / "gt.txt", BOX)
    out = d / "imported.json"
    fps = repr(1.0 / scene.dt)
    r = lesmc(
        "import", "mot", str(d / "det.txt"), "--gt", str(d / "gt.txt"), "--track", str(vid),
        "--payoff-column", "7", "--fps", fps, "-o", str(out), "--json",
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    got = load_scene(out)
    assert [f.step for f in got.frames] == [f.step for f in scene.frames]
    for g, w in zip(got.frames, scene.frames, strict=True):
        assert [x.id for x in g.detections] == [x.id for x in w.detections]
        for a, b in zip(g.detections, w.detections, strict=True):
            assert a.x == pytest.approx(b.x, abs=1e-9) and a.y == pytest.approx(b.y, abs=1e-9)
            assert a.payoff == b.payoff
    assert any(math.isinf(x.payoff) for f in got.frames for x in f.detections)
    assert got.target.step == scene.target.step == 5
    assert got.target.start == pytest.approx(scene.target.start, abs=1e-9)
    # MOT boxes carry no velocity: the import takes the difference to the next box
    p5 = next(v for v in truth["frames"][5]["vehicles"] if v["id"] == vid)
    p6 = next(v for v in truth["frames"][6]["vehicles"] if v["id"] == vid)
    want = ((p6["x"] - p5["x"]) / scene.dt, (p6["y"] - p5["y"]) / scene.dt)
    assert got.target.velocity == pytest.approx(want, rel=1e-9)
    doc = json.loads(r.stdout)
    assert doc["detections"] == sum(len(f.detections) for f in scene.frames)


def _write(tmp_path: Path, text: str, name: str = "det.txt") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def test_missing_frames_are_empty_and_the_payoff_is_constant(tmp_path: Path) -> None:
    det = _write(tmp_path, "2,-1,10,20,4,6,0.3\n2,-1,50,20,4,6,0.9\n5, -1, 11, 21, 4, 6, 0.1\n")
    out = tmp_path / "s.json"
    r = lesmc("import", "mot", str(det), "-o", str(out), "--point", "bottom", "--payoff", "2")
    assert r.returncode == 0, r.stderr
    doc = json.loads(out.read_text())
    assert [f["step"] for f in doc["frames"]] == [2, 3, 4, 5]
    assert [len(f["detections"]) for f in doc["frames"]] == [2, 0, 0, 1]
    first = doc["frames"][0]["detections"][0]
    assert (first["id"], first["x"], first["y"], first["payoff"]) == ("2:0", 12.0, 26.0, 2.0)
    assert "target" not in doc


BAD = [
    ("1,-1,10,20,4\n", "det.txt:1:1: expected 6 to 10", ""),
    ("1,-1,10,2x0,4,6\n", "det.txt:1:9: bb_top must be a number", ""),
    ("1,-1,10,20,4,6\n1,-1,10,20,4,nan\n", "det.txt:2:", "bb_height must be a finite number"),
    ("1,-1,10,20,0,6\n", "det.txt:1:12: bb_width must be > 0", ""),
    ("1.5,-1,10,20,4,6\n", "det.txt:1:1: frame must be an integer", ""),
    ("3,-1,10,20,4,6\n2,-1,10,20,4,6\n", "det.txt:2:1: frame 2 comes after frame 3", ""),
    ("1,0.5,10,20,4,6\n", "det.txt:1:3: id must be an integer", ""),
    ("\n\n", "no detections", ""),
    ("1,-1,10,20,4,6,-3\n", "det.txt:1:16: column 7 is the payoff", "got -3\n"),
]


@pytest.mark.parametrize(("text", "want", "also"), BAD)
def test_a_bad_det_file_is_located(tmp_path: Path, text: str, want: str, also: str) -> None:
    det = _write(tmp_path, text)
    out = tmp_path / "s.json"
    r = lesmc("import", "mot", "det.txt", "-o", str(out), "--payoff-column", "7", cwd=tmp_path)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert want in r.stderr and also in r.stderr, r.stderr
    assert det.exists() and not out.exists()


def test_gt_problems_are_usage_errors(tmp_path: Path) -> None:
    det = _write(tmp_path, "1,-1,10,20,4,6\n2,-1,12,20,4,6\n")
    gt = _write(tmp_path, "1,3,10,20,4,6,1,1,1\n", "gt.txt")
    out = tmp_path / "s.json"
    r = lesmc("import", "mot", str(det), "--gt", str(gt), "-o", str(out))
    assert r.returncode == 2 and "--gt and --track go together" in r.stderr
    r = lesmc("import", "mot", str(det), "--gt", str(gt), "--track", "4", "-o", str(out))
    assert (
        r.returncode == 2
        and "no such track within the detections' frames (its tracks there: 3)" in r.stderr
    )
    r = lesmc("import", "mot", str(det), "--payoff", "1", "--payoff-column", "7", "-o", str(out))
    assert r.returncode == 2 and "not both" in r.stderr
    assert not out.exists()


LINE = st.lists(
    st.one_of(
        st.integers(-5, 20).map(str),
        st.floats(allow_nan=True, allow_infinity=True).map(repr),
        st.text(alphabet="0123456789.-e ,inf", max_size=6),
    ),
    min_size=0,
    max_size=12,
).map(",".join)


@settings(max_examples=300, deadline=None)
@given(st.lists(LINE, max_size=6), st.sampled_from([None, 7, 8]))
def test_the_loader_never_crashes(lines: list[str], column: int | None) -> None:
    """Mutated files give a scene or a located LesmcError, nothing else."""
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "det.txt"
        p.write_text("\n".join(lines))
        try:
            footage_from_boxes(read_boxes(p, True), str(p), 0.1, "center", Payoffs(1.0, column))
        except LesmcError as exc:
            assert str(exc)


def test_perceive_writes_the_tracker_file_into_the_scene(
    perceived: tuple[Path, dict[str, Any], int], tmp_path: Path
) -> None:
    d, _, _ = perceived
    out = tmp_path / "s.json"
    tracker = "examples/trackers/ca6.json"
    r = lesmc("perceive", str(d / "v"), "-o", str(out), "--max-iter", "2", "--tracker", tracker)
    assert r.returncode == 0, r.stderr
    got = json.loads(out.read_text())["tracker"]
    want = json.loads(Path(tracker).read_text())
    assert got["model"]["state"] == want["model"]["state"]
    assert got["model"]["F"] == want["model"]["F"] and got["gate"] == want["gate"]
    r = lesmc("perceive", str(d / "v"), "--tracker", tracker)
    assert r.returncode == 2 and "--tracker is the tracker of the scene written" in r.stderr
