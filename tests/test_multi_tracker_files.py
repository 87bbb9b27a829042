"""A tracker file names a multi-target composition by its design (``design = "sort"`` plus
parameters); an unknown design, a part chosen by key or a bad parameter is an error at the
key's FILE:LINE:COL, exit status 2 (issue 58, "Bad input")."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from cli_run import ROOT, lesmc

import lesmc as api

SCENE = str(ROOT / "examples" / "merge.json")


def _where(text: str, key: str) -> tuple[int, int]:
    """The line and column of the first line of ``text`` that starts ``key`` (after
    blanks, a quote or a bracket): counted here, independently of lesmc."""
    for i, line in enumerate(text.split("\n"), 1):
        body = line.lstrip(" \t")
        if body.lstrip('["').startswith(key):
            return i, len(line) - len(body) + 1
    raise AssertionError(key)


CASES = [
    ("t.toml", '# a tracker\ndesign = "sortt"\nmin_hits = 2\n', "design", "design must be"),
    ("t.toml", 'design = "sort"\nmin_hits = 0\n', "min_hits", "min_hits must be an integer"),
    ("t.toml", 'design = "sort"\niou_threshold = 1.5\n', "iou_threshold", "(0, 1]"),
    ("t.toml", 'design = "sort"\n\n[parts]\nhypothesiser = "iou"\n', "parts", "does not choose"),
    (
        "t.json",
        '{\n  "design": "sort",\n  "min_hits": 2,\n  "associator": "global"\n}\n',
        "associator",
        "does not choose parts",
    ),
    ("t.json", '{\n  "design": "gnn",\n  "deleterr": 1\n}\n', "deleterr", "unknown key"),
    (
        "t.toml",
        'design = "gnn"\nconfirm_window = 3\nmin_hits = 4\n',
        "min_hits",
        "at most confirm_window",
    ),
]


@pytest.mark.parametrize(("name", "text", "key", "words"), CASES)
def test_a_bad_tracker_file_is_an_error_at_its_key(
    tmp_path: Path, name: str, text: str, key: str, words: str
) -> None:
    path = tmp_path / name
    path.write_text(text)
    line, col = _where(text, key)
    r = lesmc("track", SCENE, "--tracker", str(path))
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr
    first = r.stderr.strip().splitlines()[0]
    assert first.startswith(f"{path}:{line}:{col}: "), first
    assert words in first
    with pytest.raises(api.InputError) as err:
        api.load_scene(SCENE, tracker=path)
    loc = err.value.location
    assert loc is not None and (loc.path, loc.line, loc.column) == (str(path), line, col)


def test_every_problem_of_a_tracker_file_is_listed_at_its_line(tmp_path: Path) -> None:
    text = 'design = "sort"\nmin_hits = 0\nmax_age = -1\ndeleter = "max_age"\n'
    path = tmp_path / "t.toml"
    path.write_text(text)
    r = lesmc("track", SCENE, "--tracker", str(path))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert [x.split(": ")[0] for x in lines] == [f"{path}:{k}:1" for k in (2, 3, 4)]


def test_a_tracker_file_declares_the_sort_composition(tmp_path: Path) -> None:
    """``design = "sort"`` with its parameters in a tracker file: the check runs the sort
    design with them (min_hits 1 outputs a track at its first frame: the target has a
    track id at step 0, as SORT's output rule says), through the CLI and the API alike."""
    scene = tmp_path / "s.json"
    frames = [
        [{"id": f"{k}:0", "x": 40.0 + 8 * k, "y": 50.0, "w": 20.0, "h": 30.0, "payoff": 1.0}]
        for k in range(5)
    ]
    doc = {
        "format": "lesmc-scene",
        "version": 2,
        "frames": [{"step": k, "detections": d} for k, d in enumerate(frames)],
        "tracker": {"design": "single"},
        "target": {"step": 0, "start": [40.0, 50.0]},
    }
    scene.write_text(json.dumps(doc))
    tracker = tmp_path / "sort.toml"
    tracker.write_text('design = "sort"\nmin_hits = 1\nmax_age = 0\niou_threshold = 0.2\n')
    spec = tmp_path / "p.spec"
    spec.write_text(
        "property hijack { attack window 1..3 minimize count\n"
        "  subject to lost(0..end) > 0 holds if optimum > 1 }\n"
    )
    r = lesmc("check", str(scene), str(spec), "--tracker", str(tracker), "--json")
    assert "Traceback" not in r.stderr, r.stderr
    out = json.loads(r.stdout)
    assert out["design"] == "sort"
    res = out["results"][0]
    # one object, one detection a frame: hiding it once loses the target (max_age 0)
    assert res["optimum"] == 1 and r.returncode == 1
    got = api.check(api.load_scene(scene, tracker=tracker), spec)
    assert [x.to_dict() for x in got] == out["results"]
