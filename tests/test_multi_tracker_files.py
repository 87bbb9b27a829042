"""A tracker file names a multi-target composition by its design (``design = "sort"`` plus
parameters); an unknown design, a part chosen by key or a bad parameter is an error at the
key's FILE:LINE:COL, exit status 2 (issue 58, "Bad input")."""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np
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


def _fewest_hidden_to_lose(
    frames: list[np.ndarray], window: range, lost: int, min_hits: int, max_age: int
) -> int | None:
    """Brute force with the reference SORT (tests/sort_reference.py) run with ``min_hits``
    and ``max_age``: the fewest detections hidden in ``window`` (one a frame) after which
    the target (the track SORT outputs at step 0) is lost at ``lost`` or more steps: its
    unattacked box exists and no output box overlaps it by IoU ≥ 0.5."""
    from sort_reference import reference_sort

    def run(hide: tuple[int, ...]) -> list[dict[int, np.ndarray]]:
        shown = [np.zeros((0, 4)) if k in hide else f for k, f in enumerate(frames)]
        return reference_sort(shown, max_age=max_age, min_hits=min_hits, iou_threshold=0.2)

    plain = run(())
    me = next(iter(plain[0]))
    refs = [out.get(me) for out in plain]
    best = None
    for n in range(len(window) + 1):
        for hide in itertools.combinations(window, n):
            out = run(hide)
            miss = sum(
                r is not None and not any(_iou(b, r) >= 0.5 for b in o.values())
                for o, r in zip(out, refs, strict=True)
            )
            if miss >= lost and best is None:
                best = n
    return best


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    w = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    h = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = w * h
    return float(inter / ((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter))


def test_a_tracker_file_declares_the_sort_composition(tmp_path: Path) -> None:
    """``design = "sort"`` with its parameters in a tracker file: the check runs the sort
    design with them, through the CLI and the API alike. The optimum (the fewest detections
    hidden to lose the target at 3 steps or more) equals a brute force over the reference
    SORT run with the file's ``min_hits`` 1 and ``max_age`` 0, and differs from SORT's with
    its defaults (3 and 1), so ignoring the file's values fails."""
    pytest.importorskip("sort_tracker")
    scene = tmp_path / "s.json"
    boxes = [np.array([[30.0 + 8 * k, 35.0, 50.0 + 8 * k, 65.0]]) for k in range(7)]
    frames = [
        [{"id": f"{k}:0", "x": 40.0 + 8 * k, "y": 50.0, "w": 20.0, "h": 30.0, "payoff": 1.0}]
        for k in range(7)
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
        "property hijack { attack window 2..5 minimize count\n"
        "  subject to lost(0..end) >= 3 holds if optimum > 3 }\n"
    )
    expect = _fewest_hidden_to_lose(boxes, range(2, 6), 3, min_hits=1, max_age=0)
    defaults = _fewest_hidden_to_lose(boxes, range(2, 6), 3, min_hits=3, max_age=1)
    assert expect is not None and expect != defaults  # the file's values decide
    r = lesmc("check", str(scene), str(spec), "--tracker", str(tracker), "--json")
    assert "Traceback" not in r.stderr, r.stderr
    out = json.loads(r.stdout)
    assert out["design"] == "sort"
    res = out["results"][0]
    assert res["optimum"] == expect and r.returncode == 1
    got = api.check(api.load_scene(scene, tracker=tracker), spec)
    assert [x.to_dict() for x in got] == out["results"]
