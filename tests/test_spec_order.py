"""A spec mixing properties of several attack windows and attackers (hide only, hide +
inject, an inject grid): one model per attacker is checked, and the results still come
back in the spec's order, through the API and the command line (issue 61)."""

from __future__ import annotations

import json
from pathlib import Path

from cli_run import lesmc
from test_inject_single import _cases

from lesmc import api
from lesmc.scene import scene_from_dict

#: (name, window, attacker): the attackers interleaved, so that grouping them reorders
PROPS = [
    ("a", "1..1", ""),
    ("b", "1..2", " allow hide, inject"),
    ("c", "2..2", ""),
    ("d", "1..1", " allow hide, inject inject grid 4 within 4 payoff 1"),
    ("e", "1..1", " allow inject"),
    ("f", "2..2", " allow hide, inject"),
    ("g", "1..2", ""),
]


def _spec(end: int) -> str:
    return "".join(
        f"property {n} {{ attack window {w}{a} end {end} minimize payoff subject to "
        "dist.max(0..end) > 3 holds if optimum > 10 }\n"
        for n, w, a in PROPS
    )


def test_api_results_come_in_the_spec_order() -> None:
    case = _cases(1, 1)[0]
    spec = api.parse_spec(_spec(case["end"]))
    got = api.check(scene_from_dict(case["doc"]), spec)
    assert [r.property for r in got] == [n for n, _, _ in PROPS]
    # and each is the result of its own attacker: checked alone, the same optimum
    for r, (n, w, a) in zip(got, PROPS, strict=True):
        alone = api.parse_spec(_spec(case["end"]).splitlines()[PROPS.index((n, w, a))] + "\n")
        assert api.check(scene_from_dict(case["doc"]), alone)[0].optimum == r.optimum, n


def test_cli_results_come_in_the_spec_order(tmp_path: Path) -> None:
    case = _cases(1, 1)[0]
    scene, spec = tmp_path / "s.json", tmp_path / "p.spec"
    scene.write_text(json.dumps(case["doc"]))
    spec.write_text(_spec(case["end"]))
    r = lesmc("check", str(scene), str(spec), "--json")
    assert r.returncode in (0, 1) and "Traceback" not in r.stderr, r.stderr
    names = [x["property"] for x in json.loads(r.stdout)["results"]]
    assert names == [n for n, _, _ in PROPS]
