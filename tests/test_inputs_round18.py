"""Issue 56, items 5-8 and 21, through the real entry point: the track table's columns and
precision, trackers that do not follow their target (warned) or cannot take its velocity
(refused at import), the ground truth kept by ``import mot --gt``, duplicate gt boxes in
any frame, and the tracker-file messages."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path
from typing import Any

import pytest
from cli_run import ROOT, lesmc

MOT = ROOT / "examples" / "mot"
CA2D = ROOT / "examples" / "trackers" / "ca2d.toml"
FPS = "1.25"
#: A gt track of examples/mot that the shipped trackers follow from frame 4 to the end.
FOLLOWED = 10


def _ok(r: Any) -> None:
    """Exit 0, no traceback."""
    assert r.returncode == 0, (r.returncode, r.stderr)
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr


def _failed(r: Any, *wanted: str) -> None:
    """Exit 2, no traceback, every ``wanted`` text in stderr."""
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr
    for w in wanted:
        assert w in r.stderr, r.stderr


def _gt_rows(path: Path) -> list[list[float]]:
    """The gt file's lines as numbers, read here independently of lesmc."""
    return [[float(v) for v in line.split(",")] for line in path.read_text().splitlines() if line]


def _centre(row: list[float]) -> tuple[float, float]:
    return (row[2] + row[4] / 2, row[3] + row[5] / 2)


def _import(tmp_path: Path, track: int, *extra: str) -> Any:
    return lesmc(
        "import", "mot", str(MOT / "det.txt"), "--gt", str(MOT / "gt.txt"),
        "--track", str(track), "--fps", FPS, "-o", str(tmp_path / "scene.json"), *extra,
    )  # fmt: skip


def _model(**change: Any) -> dict[str, Any]:
    """A constant-velocity model declared by its matrices (x, y measured), with changes."""
    model: dict[str, Any] = {
        "state": ["x", "y", "vx", "vy"],
        "F": [[1, 0, 0.8, 0], [0, 1, 0, 0.8], [0, 0, 1, 0], [0, 0, 0, 1]],
        "H": [[1, 0, 0, 0], [0, 1, 0, 0]],
        "Q": [[4, 0, 0, 0], [0, 4, 0, 0], [0, 0, 9, 0], [0, 0, 0, 9]],
        "R": [[25, 0], [0, 25]],
        "P0": [[900, 0, 0, 0], [0, 900, 0, 0], [0, 0, 400, 0], [0, 0, 0, 400]],
    }
    model.update(change)
    return model


def _tracker(tmp_path: Path, name: str, doc: Any) -> Path:
    p = tmp_path / name
    p.write_text(json.dumps(doc))
    return p


# ------------------------------------------------------------------ item 5


def test_the_track_table_names_every_state_component_and_keeps_pixel_precision(
    tmp_path: Path,
) -> None:
    _ok(_import(tmp_path, FOLLOWED))
    scene = str(tmp_path / "scene.json")
    r = lesmc("track", scene, "--tracker", str(CA2D))
    _ok(r)
    lines = r.stdout.splitlines()
    head = next(line for line in lines if "step" in line and "frame" in line)
    cols = [c.strip() for c in re.split(r"[┃│]", head) if c.strip()]
    assert cols == ["step", "frame", "obs", "x", "y", "vx", "vy", "ax", "ay", "τ", "NIS", "alarm"]
    rows = [
        [c.strip() for c in line.split("│")[1:-1]]
        for line in lines
        if line.startswith("│") and line.split("│")[1].strip().isdigit()
    ]
    assert all(len(row) == len(cols) for row in rows), rows
    assert not any("e+" in c for row in rows for c in row[3:9]), rows
    # step 0 is the target's start: the centre of track 10's box in frame 4 of gt.txt
    first = next(g for g in _gt_rows(MOT / "gt.txt") if g[1] == FOLLOWED and g[0] == 4)
    x, y = _centre(first)
    assert rows[0][3] == f"{x:.2f}" and rows[0][4] == f"{y:.2f}", (rows[0], x, y)
    # every cell holds the JSON's full-precision value to 1/100 of a pixel
    doc = json.loads(lesmc("track", scene, "--tracker", str(CA2D), "--json").stdout)
    assert doc["state"] == ["x", "y", "vx", "vy", "ax", "ay"]
    for row, point in zip(rows, doc["track"], strict=True):
        for cell, v in zip(row[3:9], point["s"], strict=True):
            assert abs(float(cell) - v) <= 0.005 + 1e-9, (cell, v)


# ------------------------------------------------------------------ item 6


def test_a_tracker_that_measures_the_velocity_is_warned_about_everywhere(
    tmp_path: Path,
) -> None:
    """H measures vx, vy: the unattacked track ends far from the target's truth; import,
    track, check (table, JSON, report) all say so. The shipped tracker is not warned."""
    hv = _tracker(tmp_path, "hv.json", {"model": _model(H=[[0, 0, 1, 0], [0, 0, 0, 1]])})
    r = _import(tmp_path, FOLLOWED, "--tracker", str(hv))
    _ok(r)
    assert "warning: the unattacked track ends" in r.stdout + r.stderr
    assert "from the target's truth (track '10')" in r.stdout + r.stderr
    scene = str(tmp_path / "scene.json")
    spec = str(ROOT / "specs" / "robustness.spec")
    track = json.loads(lesmc("track", scene, "--json").stdout)
    assert any("may not follow the target" in w for w in track["warnings"])
    table = lesmc("check", scene, spec, "--no-paths")
    assert table.returncode in (0, 1), table.stderr
    assert "warning: the unattacked track ends" in table.stdout
    doc = json.loads(lesmc("check", scene, spec, "--json").stdout)
    assert any("may not follow the target" in w for w in doc["warnings"])
    rep = tmp_path / "rep"
    r = lesmc("check", scene, spec, "--report", str(rep))
    assert r.returncode in (0, 1), r.stderr
    results = json.loads((rep / "results.json").read_text())
    assert "may not follow the target" in results["meta"]["warning"]
    assert "may not follow the target" in (rep / "report.html").read_text()
    # the same scene with a tracker that measures x, y: no warning
    good = _tracker(tmp_path, "good.json", {"model": _model()})
    doc = json.loads(lesmc("check", scene, spec, "--json", "--tracker", str(good)).stdout)
    assert doc["warnings"] == []
    shipped = json.loads(lesmc("track", scene, "--tracker", str(CA2D), "--json").stdout)
    assert shipped["warnings"] == []


def test_a_tracker_whose_gate_takes_nothing_is_warned_about(tmp_path: Path) -> None:
    """A gate no detection passes: the track takes none in its first 3 steps."""
    _ok(_import(tmp_path, FOLLOWED))
    shut = tmp_path / "shut.toml"
    shut.write_text("gate = 1e-9\n")
    doc = json.loads(
        lesmc("track", str(tmp_path / "scene.json"), "--tracker", str(shut), "--json").stdout
    )
    assert all(p["obs"] is None for p in doc["track"][1:4])  # the premise, in the JSON
    assert any("takes no detection in its first 3 steps" in w for w in doc["warnings"])


def test_a_state_without_vx_vy_is_refused_at_import_where_the_tracker_is_named(
    tmp_path: Path,
) -> None:
    """px, py, vpx, vpy cannot take the gt track's velocity: refused by import mot, naming
    the tracker file and the velocity as gt.txt gives it (17.975, not 17.974999999999994)."""
    names = {"state": ["px", "py", "vpx", "vpy"]}
    pv = _tracker(tmp_path, "pv.json", {"model": _model(**names)})
    r = _import(tmp_path, 7, "--tracker", str(pv))
    gt = [g for g in _gt_rows(MOT / "gt.txt") if g[1] == 7 and g[0] in (4, 5)]
    (x4, y4), (x5, y5) = (_centre(g) for g in sorted(gt))
    vx, vy = (x5 - x4) * 1.25, (y5 - y4) * 1.25
    assert round(vx, 9) == 17.975 and round(vy, 9) == 0.67  # the velocity gt.txt gives
    # located at "state" of the one-line JSON file: line 1, column 12 ({"model": {"state")
    _failed(r, f"{pv}:1:12: model.state: the target's velocity [17.975, 0.67] needs state")
    assert "17.97499" not in r.stderr
    assert not (tmp_path / "scene.json").exists()
    # a scene made with the default tracker, checked with that tracker: the same numbers
    _ok(_import(tmp_path, 7))
    spec = str(ROOT / "specs" / "robustness.spec")
    r = lesmc("check", str(tmp_path / "scene.json"), spec, "--tracker", str(pv))
    _failed(r, "target: velocity [17.975, 0.67] needs state components named vx and vy")


# ------------------------------------------------------------------ item 7


def test_import_mot_keeps_the_ground_truth_and_recovery_checks_against_it(
    tmp_path: Path,
) -> None:
    r = _import(tmp_path, FOLLOWED, "--json")
    _ok(r)
    assert json.loads(r.stdout)["truth_tracks"] > 1
    scene = json.loads((tmp_path / "scene.json").read_text())
    assert scene["version"] == 2  # import mot keeps the boxes (scene format version 2)
    first, last = scene["frames"][0]["step"], scene["frames"][-1]["step"]
    want: dict[str, list[list[float]]] = {}
    for g in sorted(_gt_rows(MOT / "gt.txt"), key=lambda g: (g[1], g[0])):
        if first <= g[0] <= last:
            want.setdefault(str(int(g[1])), []).append([int(g[0]), *_centre(g), g[4], g[5]])
    got = {t["id"]: t["positions"] for t in scene["truth"]}
    assert got.keys() == want.keys()
    for tid, rows in want.items():
        assert len(got[tid]) == len(rows)
        # at the box centres each position keeps its box: [frame, x, y, w, h] (issue 58)
        for (k, x, y, w, h), (gk, gx, gy, gw, gh) in zip(rows, got[tid], strict=True):
            assert gk == k and abs(gx - x) < 1e-9 and abs(gy - y) < 1e-9
            assert (gw, gh) == (w, h)
    spec = str(ROOT / "examples" / "recovery.spec")
    r = lesmc("check", str(tmp_path / "scene.json"), spec, "--json")
    assert r.returncode in (0, 1), r.stderr
    names = [x["property"] for x in json.loads(r.stdout)["results"]]
    assert names == ["recovers_any", "settles"]


# ------------------------------------------------------------------ item 8


@pytest.mark.parametrize("second", ["1,5,10,10,12,8,1,1,1", "1,5,30,12,12,8,1,1,1"])
def test_duplicate_gt_boxes_outside_the_detections_frames_are_refused(
    tmp_path: Path, second: str
) -> None:
    """Track 5 twice in frame 1 (the detections start at frame 4), identical or not."""
    shutil.copy(MOT / "det.txt", tmp_path / "det.txt")
    lines = ["4,10,100,100,12,8,1,1,1", "1,5,10,10,12,8,1,1,1", "5,10,110,100,12,8,1,1,1", second]
    (tmp_path / "gt.txt").write_text("\n".join(lines) + "\n")
    r = lesmc("import", "mot", "det.txt", "--gt", "gt.txt", "--track", "10", "-o", "s.json",
              cwd=tmp_path)  # fmt: skip
    _failed(r, "gt.txt:4:1: track 5 has two boxes in frame 1 (lines 2 and 4)")
    assert not (tmp_path / "s.json").exists()


# ------------------------------------------------------------------ item 21


@pytest.mark.parametrize(
    ("doc", "wanted"),
    [
        ({"model": _model(F=[[1, 0, 0.8, 0], [0, 1, 0, 0.8], [0, 0, 1], [0, 0, 0, 1]])},
         "model.F row 2 must have 4 entries, got 3"),
        ({"model": _model(F=[[1, 0, 0.8, 0], 7, [0, 0, 1, 0], [0, 0, 0, 1]])},
         "model.F row 1 must have 4 entries, got 7, not a list"),
        ({"model": {k: v for k, v in _model().items() if k != "F"}}, "model.F is missing"),
        ({"model": {k: v for k, v in _model().items() if k != "state"}},
         "model.state is missing"),
        ([{"model": "cv2d"}], "a tracker file must be an object of the keys design, sigma_q"),
        ({"comment": 5, "model": "cv2d"}, "comment: must be a string"),
        ({"comment": ["a"], "model": "cv2d"}, "comment: must be a string"),
    ],
)  # fmt: skip
def test_tracker_file_messages_name_what_is_wrong(tmp_path: Path, doc: Any, wanted: str) -> None:
    _ok(_import(tmp_path, FOLLOWED))
    p = _tracker(tmp_path, "t.json", doc)
    r = lesmc("track", str(tmp_path / "scene.json"), "--tracker", str(p))
    _failed(r, wanted)  # at the key's line (round 19), or the file's name when none
    assert re.search(rf"{re.escape(str(p))}(:\d+:\d+)?: {re.escape(wanted)}", r.stderr), r.stderr
    assert "must be an object\n" not in r.stderr and "unknown key 'comment'" not in r.stderr


@pytest.mark.parametrize(
    ("doc", "wanted"),
    [
        ({"model": _model(R=[[1e-300, 0], [0, 1e-300]],
                          P0=[[1e-300 if i == j else 0 for j in range(4)] for i in range(4)])},
         "model.R is numerically singular"),
        ({"model": _model(R=[[1e-160, 0], [0, 1e-160]])}, "model.R is numerically singular"),
        ({"sigma_r": 1e-160}, "sigma_r = 1e-160 makes R = sigma_r² I, which is numerically"),
    ],
)  # fmt: skip
def test_a_numerically_singular_innovation_is_refused_with_its_matrix(
    tmp_path: Path, doc: Any, wanted: str
) -> None:
    """1e-300·I is positive definite, but S = H P Hᵀ + R has a determinant that underflows:
    every gate test would divide by zero (numpy warnings, every detection rejected)."""
    _ok(_import(tmp_path, FOLLOWED))
    p = _tracker(tmp_path, "t.json", doc)
    for verb in ("track", "check"):
        args = [str(ROOT / "specs" / "robustness.spec")] if verb == "check" else []
        r = lesmc(verb, str(tmp_path / "scene.json"), *args, "--tracker", str(p))
        _failed(r, wanted)  # at the key's line (round 19)
        assert re.search(rf"{re.escape(str(p))}(:\d+:\d+)?: {re.escape(wanted)}", r.stderr)
        assert "RuntimeWarning" not in r.stderr
    # small but representable: accepted, and the track runs without a numpy warning
    ok = _tracker(tmp_path, "ok.json", {"model": _model(R=[[1e-150, 0], [0, 1e-150]])})
    r = lesmc("track", str(tmp_path / "scene.json"), "--tracker", str(ok))
    _ok(r)
    assert "Warning" not in r.stderr
