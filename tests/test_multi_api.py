"""Multi-target designs through the Python API (issue 58): ``lesmc.check(..., designs="sort")``
returns typed results equal to ``lesmc check --design sort --json`` on the same inputs, whose
optima agree with a brute force over the reference SORT (tests/test_multi_attack.py's)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_run import lesmc

import lesmc as api
from lesmc.common.errors import LesmcError, UsageError
from lesmc.pipeline.multi import AttackStep, MultiCheckResult

pytest.importorskip("sort_tracker")
from test_multi_attack import _brute, _doc, _frames, _reference_boxes, _score

SPEC = """property hijack {{
  attack window {l}..{u}
  minimize payoff
  subject to switches(0..end) > 0
  holds if optimum > 3
}}
property lose {{
  attack window {l}..{u}
  minimize count.frames
  subject to lost(0..end) > 0
  holds if optimum > 1
}}
"""


def _files(tmp_path: Path, design: str) -> tuple[Path, Path, list[np.ndarray], list[Any]]:
    rng = np.random.default_rng(11)
    frames = _frames(rng, 5)
    pay = [rng.integers(1, 6, len(f)).astype(float) for f in frames]
    doc = _doc(frames, pay)
    doc["tracker"]["design"] = design
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps(doc))
    spec = tmp_path / "p.spec"
    spec.write_text(SPEC.format(l=2, u=4))
    return scene, spec, frames, pay


@pytest.mark.parametrize("design", ["sort", "gnn"])
def test_api_equals_cli_json(tmp_path: Path, design: str) -> None:
    scene, spec, _, _ = _files(tmp_path, design)
    r = lesmc("check", str(scene), str(spec), "--json")
    assert "Traceback" not in r.stderr, r.stderr
    doc = json.loads(r.stdout)
    got = api.check(str(scene), str(spec))
    assert all(isinstance(x, MultiCheckResult) for x in got)
    assert [x.to_dict() for x in got] == doc["results"]
    assert {x.design for x in got} == {doc["design"]} == {design}
    assert {x.reference for x in got} == {doc["reference"]}
    assert r.returncode == (0 if all(x.status == "holds" for x in got) else 1)


def test_designs_argument_overrides_the_scene_design(tmp_path: Path) -> None:
    """A scene made for ``single``, checked with ``designs="sort"`` (the API's spelling of
    ``--design sort``), as a Scene object and as a path."""
    scene, spec, _, _ = _files(tmp_path, "single")
    r = lesmc("check", str(scene), str(spec), "--design", "sort", "--json")
    assert "Traceback" not in r.stderr, r.stderr
    want = json.loads(r.stdout)["results"]
    by_path = api.check(scene, api.load_spec(spec), designs="sort")
    by_scene = api.check(api.load_scene(scene), spec, designs=["sort"], only="hijack")
    assert [x.to_dict() for x in by_path] == want
    assert [x.to_dict() for x in by_scene] == want[:1]


def test_typed_results_agree_with_brute_force_on_reference_sort(tmp_path: Path) -> None:
    """The optimum of each property is the least cost among every subset of the window's
    detections hidden and the rest run through the reference SORT; the counterexample's
    steps are typed, with the hidden ids inside the window."""
    scene, spec, frames, pay = _files(tmp_path, "sort")
    got = {x.property: x for x in api.check(scene, spec)}
    runs = _brute(frames, pay, 2, 4)
    refs = _reference_boxes(frames)
    end = len(frames) - 1
    for name, cost_of, which in (("hijack", 0, 0), ("lose", 1, 1)):
        want = min(
            (x[cost_of] for x in runs if _score(x[3], refs, 0, end)[which] > 0),
            default=math.inf,
        )
        res = got[name]
        assert res.optimum == want, (name, res.optimum, want)
        assert (res.verdict == "holds") == (want > (3 if name == "hijack" else 1))
        if res.counterexample is None:
            assert want == math.inf
            continue
        steps = res.counterexample
        assert [s.step for s in steps] == list(range(end + 1))
        assert all(isinstance(s, AttackStep) and isinstance(s.hidden, tuple) for s in steps)
        hidden = [(s.step, int(h.split(":")[1])) for s in steps for h in s.hidden]
        assert all(2 <= k <= 4 for k, _ in hidden)
        cost = sum(pay[k][j] for k, j in hidden) if cost_of == 0 else len({k for k, _ in hidden})
        assert cost == want
        assert all(s.injected == () for s in steps)
        assert all(s.target_id is None or s.target_id >= 1 for s in steps)


@pytest.mark.parametrize(
    ("kwargs", "word"),
    [
        ({"engine": "bnb"}, "engine"),
        ({"payoffs": "interval"}, "payoffs"),
        ({"designs": ["sort", "single"]}, "designs"),
        ({"designs": ["sort", "gnn"]}, "designs"),
        ({"only": "nope"}, "nope"),
    ],
)
def test_arguments_a_multi_target_check_does_not_read_are_refused(
    tmp_path: Path, kwargs: dict[str, Any], word: str
) -> None:
    scene, spec, _, _ = _files(tmp_path, "sort")
    with pytest.raises(UsageError) as err:
        api.check(scene, spec, **kwargs)
    assert word in err.value.message


def test_an_unsupported_property_is_a_located_error_not_an_exit(tmp_path: Path) -> None:
    scene, _, _, _ = _files(tmp_path, "sort")
    spec = tmp_path / "bad.spec"
    spec.write_text(
        "property p {\n  attack window 1..2\n  minimize tau.rise(0..end)\n"
        "  subject to switches(0..end) > 0\n  holds if optimum > 1\n}\n"
    )
    with pytest.raises(LesmcError) as err:
        api.check(scene, spec)
    assert err.value.location is not None and err.value.location.line == 3


def test_the_api_page_example_holds_against_the_reference_sort() -> None:
    """docs/api.md's multi-target example (run there as a doctest): its scene, re-read as
    boxes, has the optimum that the brute force over the reference SORT finds."""
    from cli_run import ROOT

    text = (ROOT / "docs" / "api.md").read_text()
    assert 'lesmc.check("examples/crossing.json", "examples/hijack.spec")' in text
    doc = json.loads((ROOT / "examples" / "crossing.json").read_text())
    frames = [
        np.array(
            [
                [d["x"] - d["w"] / 2, d["y"] - d["h"] / 2, d["x"] + d["w"] / 2, d["y"] + d["h"] / 2]
                for d in f["detections"]
            ],
            dtype=float,
        ).reshape(-1, 4)
        for f in doc["frames"]
    ]
    pay = [np.ones(len(f)) for f in frames]
    runs = _brute(frames, pay, 2, 4)
    refs = _reference_boxes(frames)
    end = len(frames) - 1
    want = min((x[1] for x in runs if _score(x[3], refs, 0, end)[0] > 0), default=math.inf)
    (got,) = api.check(ROOT / "examples" / "crossing.json", ROOT / "examples" / "hijack.spec")
    assert got.optimum == want
