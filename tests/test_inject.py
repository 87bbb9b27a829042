"""Attacks that inject as well as hide (issue 61) on SORT (``lesmc check --design sort``,
``attack window L..U allow hide, inject``), against a brute force: on random small scenes
with injection candidates every subset of every attacked frame's detections is hidden
and every subset of its candidates injected, the REFERENCE SORT (``sort-tracker-py``,
run unchanged) tracks what the attacker left (the detections in the frame's order, then
the injected candidates in theirs), and switches / lost are scored from its output.
Also: adding ``inject`` never raises an optimum, scene candidates and ``import mot
--inject-column`` are validated, and injection on the joint design is refused."""

from __future__ import annotations

import copy
import importlib
import itertools
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_run import lesmc
from inject_scale import cases

from lesmc.cli.multi_check import multi_results
from lesmc.common.errors import InputError
from lesmc.language.parser import parse_spec
from lesmc.scene import scene_from_dict
from lesmc.scene.io import scene_to_dict

sort_reference = pytest.importorskip("sort_reference")
pytest.importorskip("sort_tracker")
multi_attack = pytest.importorskip("test_multi_attack")  # its scenes and scoring

SCENES = cases(50, 200)  # LESMC_INJECT_FULL=1: the 200 (tests/inject_scale.py)


def _candidates(rng: np.random.Generator, boxes: np.ndarray) -> np.ndarray:
    """Up to two injection candidates: a detection's box shifted sideways (the hijacking
    attack's fake box) or a box anywhere."""
    out = []
    for _ in range(int(rng.integers(0, 3))):
        if len(boxes) and rng.random() < 0.7:
            b = boxes[int(rng.integers(0, len(boxes)))]
            shift = rng.uniform(3, 12, 2) * rng.choice([-1.0, 1.0], 2)
            out.append([b[0] + shift[0], b[1] + shift[1], b[2] + shift[0], b[3] + shift[1]])
        else:
            c, s = rng.uniform(20, 80, 2), rng.uniform(12, 30, 2)
            out.append([*(c - s / 2), *(c + s / 2)])
    return np.array(out, dtype=float).reshape(-1, 4)


def _det(did: str, b: np.ndarray, payoff: float) -> dict[str, Any]:
    return {
        "id": did,
        "x": float((b[0] + b[2]) / 2),
        "y": float((b[1] + b[3]) / 2),
        "w": float(b[2] - b[0]),
        "h": float(b[3] - b[1]),
        "payoff": float(payoff),
    }


def _doc(
    frames: list[np.ndarray], pay: list[np.ndarray], cands: list[np.ndarray], cpay: list[Any]
) -> dict[str, Any]:
    """A scene (format 3) of the boxes and candidates: ids FRAME:K, K counting the frame's
    detections and then its candidates."""
    out = []
    for k, (boxes, cs) in enumerate(zip(frames, cands, strict=True)):
        fr: dict[str, Any] = {
            "step": k,
            "detections": [_det(f"{k}:{j}", b, pay[k][j]) for j, b in enumerate(boxes)],
        }
        if len(cs):
            n = len(boxes)
            fr["candidates"] = [_det(f"{k}:{n + j}", c, cpay[k][j]) for j, c in enumerate(cs)]
        out.append(fr)
    b = frames[0][0]
    return {
        "format": "lesmc-scene",
        "version": 3,
        "frames": out,
        "tracker": {"design": "sort"},
        "target": {"step": 0, "start": [float((b[0] + b[2]) / 2), float((b[1] + b[3]) / 2)]},
    }


Leaf = tuple[float, int, int, list[dict[int, np.ndarray]]]


def _subsets(n: int) -> list[tuple[int, ...]]:
    return [s for r in range(n + 1) for s in itertools.combinations(range(n), r)]


def _brute(
    frames: list[np.ndarray],
    pay: list[np.ndarray],
    cands: list[np.ndarray],
    cpay: list[np.ndarray],
    l: int,
    u: int,
    hide: bool = True,
    inject: bool = True,
) -> list[Leaf]:
    """(payoff, frames attacked, detections hidden + candidates injected, the reference
    SORT's output) of every way to hide and inject at steps l..u."""
    sort = importlib.import_module("sort_tracker.sort")
    end = len(frames) - 1
    sort.KalmanBoxTracker.count = 0
    results: list[Leaf] = []

    def run(tracker: Any, k: int, hist: list[Any], cost: float, n: int, h: int) -> None:
        if k > end:
            results.append((cost, n, h, hist))
            return
        attacked = l <= k <= u
        hides = _subsets(len(frames[k])) if attacked and hide else [()]
        adds = _subsets(len(cands[k])) if attacked and inject else [()]
        options = [(a, b) for a in hides for b in adds]
        for gone, added in options:
            t = copy.deepcopy(tracker) if len(options) > 1 else tracker
            seen = np.vstack([np.delete(frames[k], list(gone), axis=0), cands[k][list(added)]])
            dets = np.hstack([seen, np.ones((len(seen), 1))]) if len(seen) else np.empty((0, 5))
            with sort_reference._without_lap():
                res = t.update(dets)
            got = {int(r[-1]): np.asarray(r[:4], dtype=float) for r in res}
            c = cost + math.fsum([*pay[k][list(gone)], *cpay[k][list(added)]])
            m = len(gone) + len(added)
            run(t, k + 1, [*hist, got], c, n + bool(m), h + m)

    run(sort.Sort(max_age=1, min_hits=3, iou_threshold=0.3), 0, [], 0.0, 0, 0)
    return results


SPEC = """
property sw_payoff {{ attack window {l}..{u}{allow} minimize payoff
  subject to switches(0..end) > 0 holds if optimum > 1000 }}
property sw_frames {{ attack window {l}..{u}{allow} minimize count.frames
  subject to switches(0..end) > 0 holds if optimum > 1000 }}
property lost_payoff {{ attack window {l}..{u}{allow} minimize payoff
  subject to lost(0..end) > 0 holds if optimum > 1000 }}
property lost_count {{ attack window {l}..{u}{allow} minimize count
  subject to lost(0..end) > 0 holds if optimum > 1000 }}
"""

#: each property: the cost (0 payoff, 1 frames, 2 detections hidden + candidates
#: injected) and the measure (0 switches, 1 lost)
PROPS = {"sw_payoff": (0, 0), "sw_frames": (1, 0), "lost_payoff": (0, 1), "lost_count": (2, 1)}
ALLOW = {"hide": "", "inject": " allow inject", "both": " allow hide, inject"}


Case = tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray], list[np.ndarray], int, int]


def _case(seed: int) -> Case:
    """3-5 frames of <= 4 detections and <= 2 candidates; a window of 1-2 steps."""
    rng = np.random.default_rng(6100 + seed)
    n_frames = int(rng.integers(3, 6))
    frames = multi_attack._frames(rng, n_frames)
    cands = [np.empty((0, 4))] + [_candidates(rng, f) for f in frames[1:]]
    u = int(rng.integers(1, n_frames))
    l = max(1, u - int(rng.integers(0, 2)))
    pay = [rng.integers(1, 10, len(f)).astype(float) for f in frames]
    cpay = [rng.integers(1, 10, len(c)).astype(float) for c in cands]
    return frames, pay, cands, cpay, l, u


def _optima(case: Case, allow: str) -> dict[str, dict[str, Any]]:
    frames, pay, cands, cpay, l, u = case
    scene = scene_from_dict(_doc(frames, pay, cands, cpay))
    spec = parse_spec(SPEC.format(l=l, u=u, allow=ALLOW[allow]), "p.spec")
    return {r["property"]: r for r in multi_results(scene, "s.json", (spec,))}


def _opt(r: dict[str, Any]) -> float:
    return math.inf if r["optimum"] is None else float(r["optimum"])


def _attacked(case: Case, steps: list[dict[str, Any]]) -> list[np.ndarray]:
    """The frames the counterexample leaves: hidden detections out, injected ones in (ids
    FRAME:K, K >= the frame's detections naming candidate K - n)."""
    frames, _, cands, _, _, _ = case
    out = [f.copy() for f in frames]
    for s in steps:
        k, n = s["step"], len(frames[s["step"]])
        gone = [int(h.split(":")[1]) for h in s["hidden"]]
        added = [int(h.split(":")[1]) - n for h in s["injected"]]
        assert all(j < n for j in gone) and all(j >= 0 for j in added)
        out[k] = np.vstack([np.delete(frames[k], gone, axis=0), cands[k][added]])
    return out


@pytest.mark.parametrize("seed", range(SCENES))
def test_optima_equal_brute_force_over_hide_and_inject(seed: int) -> None:
    case = _case(seed)
    frames, pay, cands, cpay, l, u = case
    end = len(frames) - 1
    runs = _brute(frames, pay, cands, cpay, l, u)
    refs = multi_attack._reference_boxes(frames)
    got = _optima(case, "both")
    for name, (cost_of, which) in PROPS.items():
        want = min(
            (r[cost_of] for r in runs if multi_attack._score(r[3], refs, 0, end)[which] >= 1),
            default=math.inf,
        )
        res = got[name]
        assert _opt(res) == want, (seed, name, _opt(res), want)
        if res["counterexample"] is None:
            continue
        steps = res["counterexample"]
        assert all(l <= s["step"] <= u for s in steps if s["hidden"] or s["injected"])
        named = [(s["step"], h) for s in steps for h in (*s["hidden"], *s["injected"])]
        price = {f"{k}:{j}": p for k, ps in enumerate(pay) for j, p in enumerate(ps)}
        for k, (f, ps) in enumerate(zip(frames, cpay, strict=True)):
            price.update({f"{k}:{len(f) + j}": p for j, p in enumerate(ps)})
        costs = (
            sum(price[h] for _, h in named),
            sum(bool(s["hidden"] or s["injected"]) for s in steps),
            len(named),
        )
        assert costs[cost_of] == want, (seed, name)
        out = sort_reference.reference_sort(_attacked(case, steps))
        assert multi_attack._score(out, refs, 0, end)[which] >= 1, (seed, name)


def never_raises(hide_only: dict[str, Any], more: dict[str, Any]) -> list[str]:
    """The properties whose optimum the larger threat model raised (should be none)."""
    return [n for n in hide_only if _opt(more[n]) > _opt(hide_only[n])]


def test_inject_never_raises_an_optimum() -> None:
    """On every random case, the hide-only optimum >= the hide + inject optimum; and the
    brute force agrees that injection alone answers as the engine says."""
    strict = 0
    for seed in range(SCENES):
        case = _case(seed)
        hide, both = _optima(case, "hide"), _optima(case, "both")
        assert never_raises(hide, both) == [], seed
        strict += sum(_opt(both[n]) < _opt(hide[n]) for n in PROPS)
    assert strict > 0  # injection made some attack cheaper: the comparison is not vacuous


def _hijack_case() -> Case:
    """One pedestrian (20 x 20 px) moving 9 px a frame, two frames; at step 1 a candidate
    3 px beyond its detection. SORT predicts frame 0's box at step 1 (zero initial
    velocity): the true detection overlaps it by IoU 11/29 >= 0.3, the candidate by
    8/32 < 0.3. Hiding the detection and injecting the candidate at step 1 starts a
    second track there, output at once (frame count <= min_hits) and overlapping the
    reference by IoU >= 0.5: a switch. Hiding alone can only lose the pedestrian."""
    box = np.array([[40.0, 40.0, 60.0, 60.0]])
    frames = [box, box + np.array([9.0, 0.0, 9.0, 0.0])]
    cands = [np.empty((0, 4)), box + np.array([12.0, 0.0, 12.0, 0.0])]
    pay = [np.array([5.0])] * 2
    cpay = [np.empty(0), np.array([2.0])]
    return frames, pay, cands, cpay, 1, 1


def test_a_constructed_case_where_injection_is_strictly_cheaper() -> None:
    case = _hijack_case()
    frames, pay, cands, cpay, l, u = case
    hide, both = _optima(case, "hide"), _optima(case, "both")
    assert _opt(hide["sw_payoff"]) == math.inf  # hiding alone cannot switch it
    assert _opt(both["sw_payoff"]) == 7.0  # hide 1:0 (5) + inject 1:1 (2)
    step = both["sw_payoff"]["counterexample"][1]
    assert step["hidden"] == ["1:0"] and step["injected"] == ["1:1"]
    # the brute force over the reference SORT agrees, both ways
    refs = multi_attack._reference_boxes(frames)
    for h, want in ((False, math.inf), (True, 7.0)):
        runs = _brute(frames, pay, cands, cpay, l, u, inject=h)
        sw = [r[0] for r in runs if multi_attack._score(r[3], refs, 0, 1)[0] >= 1]
        assert min(sw, default=math.inf) == want


def test_the_never_raises_check_can_fail() -> None:
    """The check flags a threat model that raises an optimum: an attacker who may only
    inject (``allow inject``, no hide) cannot lose the pedestrian of the constructed case,
    which hiding loses at 5."""
    case = _hijack_case()
    hide, inject_only = _optima(case, "hide"), _optima(case, "inject")
    assert _opt(hide["lost_payoff"]) == 5.0
    assert _opt(inject_only["lost_payoff"]) == math.inf
    assert "lost_payoff" in never_raises(hide, inject_only)


def _write(tmp_path: Path, doc: dict[str, Any], spec_text: str) -> tuple[Path, Path]:
    scene, spec = tmp_path / "scene.json", tmp_path / "p.spec"
    scene.write_text(json.dumps(doc))
    spec.write_text(spec_text)
    return scene, spec


HIJACK_SPEC = (
    "property hijack {\n  attack window 1..1 allow hide, inject minimize payoff\n"
    "  subject to switches(0..end) > 0 holds if optimum > 1 }\n"
)


def test_cli_lists_injected_detections(tmp_path: Path) -> None:
    frames, pay, cands, cpay, _, _ = _hijack_case()
    scene, spec = _write(tmp_path, _doc(frames, pay, cands, cpay), HIJACK_SPEC)
    r = lesmc("check", str(scene), str(spec), "--json")
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr  # 7 > 1: holds
    res = json.loads(r.stdout)["results"][0]
    assert res["optimum"] == 7.0
    assert [s["injected"] for s in res["counterexample"]] == [[], ["1:1"]]
    r = lesmc("check", str(scene), str(spec))
    assert "hidden 1:0; injected 1:1" in r.stdout, r.stdout


def test_unknown_action_is_a_located_error(tmp_path: Path) -> None:
    frames, pay, cands, cpay, _, _ = _hijack_case()
    text = HIJACK_SPEC.replace("allow hide, inject", "allow hide, fabricate")
    scene, spec = _write(tmp_path, _doc(frames, pay, cands, cpay), text)
    r = lesmc("check", str(scene), str(spec))
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert f"{spec}:2:" in r.stderr and "unknown attack action 'fabricate'" in r.stderr


def test_scene_candidates_round_trip_and_versions() -> None:
    frames, pay, cands, cpay, _, _ = _hijack_case()
    doc = _doc(frames, pay, cands, cpay)
    sc = scene_from_dict(doc)
    assert [len(f.candidates) for f in sc.frames] == [0, 1]
    assert sc.frames[1].candidates[0].id == "1:1"
    out = scene_to_dict(sc)
    assert out["version"] == 3 and out["frames"][1]["candidates"] == doc["frames"][1]["candidates"]
    assert scene_from_dict(out) == sc
    del doc["frames"][1]["candidates"]  # without candidates: written as format 2, as before
    assert scene_to_dict(scene_from_dict(doc))["version"] == 2


@pytest.mark.parametrize(
    ("change", "want"),
    [
        (lambda d: d.update(version=2), "candidates (injection candidates) need scene format"),
        (lambda d: d["frames"][1]["candidates"][0].update(payoff=-1), "payoff (the price"),
        (lambda d: d["frames"][1]["candidates"][0].update(payoff="unattackable"), "in [0,"),
        (lambda d: d["frames"][1]["candidates"][0].update(id="1:0"), "duplicate id"),
        (lambda d: d["frames"][1]["candidates"][0].update(payoff_lower=1), "unknown key"),
        (lambda d: d["frames"][1].update(candidates={}), "candidates must be a list"),
    ],
)
def test_a_bad_candidate_is_located(change: Any, want: str) -> None:
    frames, pay, cands, cpay, _, _ = _hijack_case()
    doc = _doc(frames, pay, cands, cpay)
    change(doc)
    with pytest.raises(InputError) as info:
        scene_from_dict(doc, "s.json")
    assert want in str(info.value) and "s.json: frame 1" in str(info.value), str(info.value)


#: frame 1: a detection (conf 0.9), a low-score line (conf 0.2, price 3 in column 8) and a
#: detection; frame 2: one of each
MOT = """1,-1,10,20,30,40,0.9,-1,-1,-1
1,-1,50,20,30,40,0.2,3,-1,-1
1,-1,90,20,30,40,0.8,-1,-1,-1
2,-1,12,20,30,40,0.1,1.5,-1,-1
2,-1,52,20,30,40,0.7,-1,-1,-1
"""


def test_import_mot_turns_low_score_lines_into_candidates(tmp_path: Path) -> None:
    det = tmp_path / "det.txt"
    det.write_text(MOT)
    out = tmp_path / "s.json"
    args = ["--inject-column", "8", "--threshold", "0.5", "--json"]
    r = lesmc("import", "mot", str(det), "-o", str(out), *args)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    assert json.loads(r.stdout)["candidates"] == 2
    doc = json.loads(out.read_text())
    assert doc["version"] == 3
    f1, f2 = doc["frames"]
    assert [d["id"] for d in f1["detections"]] == ["1:0", "1:2"]
    assert [(c["id"], c["payoff"], c["x"], c["w"]) for c in f1["candidates"]] == [
        ("1:1", 3.0, 65.0, 30.0)
    ]
    assert [d["id"] for d in f2["detections"]] == ["2:1"]
    assert [(c["id"], c["payoff"]) for c in f2["candidates"]] == [("2:0", 1.5)]
    # without the options, the same file is a format-2 scene of five detections
    r = lesmc("import", "mot", str(det), "-o", str(out))
    assert r.returncode == 0 and json.loads(out.read_text())["version"] == 2


@pytest.mark.parametrize(
    ("text", "args", "want"),
    [
        (MOT, ["--inject-column", "8"], "--inject-column and --threshold go together"),
        (MOT, ["--inject-column", "11", "--threshold", "0.5"], "--inject-column"),
        (
            MOT.replace(",3,-1,-1\n", "\n"),
            ["--inject-column", "8", "--threshold", "0.5"],
            "{det}:2:21: --inject-column 8: the line has only 7 columns",
        ),
        (
            MOT.replace(",1.5,", ",-2,"),
            ["--inject-column", "8", "--threshold", "0.5"],
            "{det}:4:22: column 8 is the price of injecting this line",
        ),
        (
            MOT.replace("2,-1,52,20,30,40,0.7,-1,-1,-1", "2,-1,52,20,30,40"),
            ["--inject-column", "8", "--threshold", "0.5"],
            "{det}:5:17: --threshold compares conf (column 7)",
        ),
    ],
)
def test_import_mot_inject_errors_are_located(
    tmp_path: Path, text: str, args: list[str], want: str
) -> None:
    det = tmp_path / "det.txt"
    det.write_text(text)
    out = tmp_path / "s.json"
    r = lesmc("import", "mot", str(det), "-o", str(out), *args)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert want.format(det=det) in r.stderr, r.stderr
    assert not out.exists()


def test_the_language_page_has_the_registry_table() -> None:
    from lesmc.language import actions

    page = (Path(__file__).resolve().parents[1] / "docs" / "language.md").read_text()
    assert actions.docs_table() in page


def test_allow_parses_into_the_property_and_hide_alone_is_the_default() -> None:
    from lesmc.language.semantics import bind

    text = (
        "property a {{ attack window 1..2{} minimize payoff\n"
        "  subject to dist.max(0..end) > 5 holds if optimum > 1 }}\n"
    )
    default = parse_spec(text.format(""), "p.spec").properties[0]
    hide = parse_spec(text.format(" allow hide"), "p.spec").properties[0]
    both = parse_spec(text.format(" allow inject, hide"), "p.spec").properties[0]
    assert default.actions == hide.actions == ("hide",) and both.actions == ("inject", "hide")
    spec = parse_spec(text.format(" allow hide"), "p.spec")
    assert bind(spec, spec.properties[0], 5, ("x", "y"), False).l == 1  # single: hide is fine


@pytest.mark.parametrize("seed", range(0, SCENES, 5))
def test_inject_alone_equals_brute_force(seed: int) -> None:
    """``allow inject`` without hide: the brute force injects, never hides."""
    case = _case(seed)
    frames, pay, cands, cpay, l, u = case
    end = len(frames) - 1
    runs = _brute(frames, pay, cands, cpay, l, u, hide=False)
    refs = multi_attack._reference_boxes(frames)
    got = _optima(case, "inject")
    for name, (cost_of, which) in PROPS.items():
        want = min(
            (r[cost_of] for r in runs if multi_attack._score(r[3], refs, 0, end)[which] >= 1),
            default=math.inf,
        )
        assert _opt(got[name]) == want, (seed, name)
        for s in got[name]["counterexample"] or []:
            assert s["hidden"] == []


def test_max_states_counts_the_injection_options(tmp_path: Path) -> None:
    """Step 1 of the constructed case has 2 options hiding only and 4 hiding and injecting:
    --max-states 4 (1 state so far) lets the first through and stops the second, exit 3."""
    frames, pay, cands, cpay, _, _ = _hijack_case()
    scene, spec = _write(tmp_path, _doc(frames, pay, cands, cpay), HIJACK_SPEC)
    r = lesmc("check", str(scene), str(spec), "--max-states", "4")
    assert r.returncode == 3 and "--max-states 4: step 1 would compute 4" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr
    spec.write_text(HIJACK_SPEC.replace(" allow hide, inject", ""))
    r = lesmc("check", str(scene), str(spec), "--max-states", "4")
    assert r.returncode == 0 and "optimum inf" in r.stdout, r.stderr
