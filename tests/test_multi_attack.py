"""The exact cheapest identity attack on SORT (``lesmc check --design sort``) against a
brute force: on random small scenes (3 objects crossing, <= 4 detections a frame, attack
windows of 1-3 steps) every subset of every attacked frame's detections is hidden, the
REFERENCE SORT (``sort-tracker-py``, run unchanged) tracks the rest, and switches / lost
are scored from its output. The optima of payoff and count.frames must agree, and each
counterexample's hidden detections, run through the reference SORT, must do as claimed."""

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

from lesmc.cli.multi_check import multi_results
from lesmc.language.parser import parse_spec
from lesmc.scene import scene_from_dict

sort_reference = pytest.importorskip("sort_reference")
pytest.importorskip("sort_tracker")

SCENES = 50


def _frames(rng: np.random.Generator, n: int) -> list[np.ndarray]:
    """Three objects crossing, each missed at random (not in frame 0), sometimes clutter."""
    pos = np.array([[20.0, 50.0], [80.0, 52.0], [50.0, 20.0]]) + rng.normal(0, 3, (3, 2))
    vel = np.array([[10.0, 0.5], [-10.0, 0.0], [0.0, 9.0]]) + rng.normal(0, 2, (3, 2))
    size = rng.uniform(18, 30, (3, 2))
    out = []
    for k in range(n):
        p = pos + k * vel + rng.normal(0, 1, (3, 2))
        keep = [k == 0 or rng.random() < 0.85 for _ in range(3)]
        boxes = [[*(q - s / 2), *(q + s / 2)] for q, s, y in zip(p, size, keep, strict=True) if y]
        if len(boxes) < 4 and rng.random() < 0.15:
            c, s = rng.uniform(20, 80, 2), rng.uniform(10, 30, 2)
            boxes.append([*(c - s / 2), *(c + s / 2)])
        out.append(np.array(boxes, dtype=float).reshape(-1, 4))
    return out


def _doc(frames: list[np.ndarray], pay: list[np.ndarray]) -> dict[str, Any]:
    dets = [
        {
            "step": k,
            "detections": [
                {
                    "id": f"{k}:{j}",
                    "x": float((b[0] + b[2]) / 2),
                    "y": float((b[1] + b[3]) / 2),
                    "w": float(b[2] - b[0]),
                    "h": float(b[3] - b[1]),
                    "payoff": float(pay[k][j]),
                }
                for j, b in enumerate(boxes)
            ],
        }
        for k, boxes in enumerate(frames)
    ]
    b = frames[0][0]
    start = [float((b[0] + b[2]) / 2), float((b[1] + b[3]) / 2)]
    return {
        "format": "lesmc-scene",
        "version": 2,
        "frames": dets,
        "tracker": {"design": "sort"},
        "target": {"step": 0, "start": start},
    }


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    w = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    h = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = w * h
    return inter / ((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter)


def _reference_boxes(frames: list[np.ndarray]) -> list[np.ndarray | None]:
    """The target's reference: the reference SORT's unattacked track born on detection 0 of
    frame 0, at the frames where it is output."""
    out = sort_reference.reference_sort(frames)
    rid = max(out[0], key=lambda i: _iou(out[0][i], frames[0][0]))
    return [o.get(rid) for o in out]


def _score(out: list[dict[int, np.ndarray]], refs: list[Any], lo: int, hi: int) -> tuple[int, int]:
    """switches(lo..hi) and lost(lo..hi) of one run of the reference SORT."""
    switches = lost = 0
    last = None
    for k, (tracks, rb) in enumerate(zip(out, refs, strict=True)):
        if rb is None:
            continue
        best, top = None, -1.0
        for i in sorted(tracks):
            v = _iou(tracks[i], rb)
            if v >= 0.5 and v > top:
                best, top = i, v
        if best is None:
            lost += lo <= k <= hi
            continue
        if last is not None and best != last and lo <= k <= hi:
            switches += 1
        last = best
    return switches, lost


Leaf = tuple[float, int, int, list[dict[int, np.ndarray]]]


def _brute(frames: list[np.ndarray], pay: list[np.ndarray], l: int, u: int) -> list[Leaf]:
    """(payoff, frames attacked, detections hidden, the reference SORT's output) of every
    way to hide subsets of the detections of steps l..u, the reference SORT run on what
    is left (prefixes shared by copying its tracker)."""
    sort = importlib.import_module("sort_tracker.sort")
    end = len(frames) - 1
    sort.KalmanBoxTracker.count = 0
    results: list[Leaf] = []

    def run(tracker: Any, k: int, hist: list[Any], cost: float, n: int, h: int) -> None:
        if k > end:
            results.append((cost, n, h, hist))
            return
        boxes = frames[k]
        subsets: list[tuple[int, ...]] = [()]
        if l <= k <= u:
            idx = range(len(boxes))
            subsets = [s for r in range(len(boxes) + 1) for s in itertools.combinations(idx, r)]
        for sub in subsets:
            t = copy.deepcopy(tracker) if len(subsets) > 1 else tracker
            kept = np.delete(boxes, list(sub), axis=0)
            dets = np.hstack([kept, np.ones((len(kept), 1))]) if len(kept) else np.empty((0, 5))
            with sort_reference._without_lap():
                res = t.update(dets)
            got = {int(r[-1]): np.asarray(r[:4], dtype=float) for r in res}
            c = cost + math.fsum(pay[k][list(sub)]) if sub else cost
            run(t, k + 1, [*hist, got], c, n + bool(sub), h + len(sub))

    run(sort.Sort(max_age=1, min_hits=3, iou_threshold=0.3), 0, [], 0.0, 0, 0)
    return results


SPEC = """
property sw_payoff {{ attack window {l}..{u} minimize payoff
  subject to switches(0..end) > 0 holds if optimum > 1000 }}
property sw_frames {{ attack window {l}..{u} minimize count.frames
  subject to switches(0..end) > 0 holds if optimum > 1000 }}
property lost_payoff {{ attack window {l}..{u} minimize payoff
  subject to lost(0..end) > 0 holds if optimum > 1000 }}
property lost_frames {{ attack window {l}..{u} minimize count.frames
  subject to lost(0..end) > 0 holds if optimum > 1000 }}
property sw_count {{ attack window {l}..{u} minimize count
  subject to switches({a}..end) >= {c} holds if optimum > 1000 }}
property lost_range {{ attack window {l}..{u} minimize payoff
  subject to lost({a}..{b}) >= {c} holds if optimum > 1000 }}
"""

#: each property: the cost (0 payoff, 1 frames, 2 detections hidden), the measure (0
#: switches, 1 lost), its range (None: end) and its least value
PROPS = {
    "sw_payoff": (0, 0, 0, None, 1),
    "sw_frames": (1, 0, 0, None, 1),
    "lost_payoff": (0, 1, 0, None, 1),
    "lost_frames": (1, 1, 0, None, 1),
}


def _case(seed: int) -> tuple[list[np.ndarray], list[np.ndarray], int, int]:
    rng = np.random.default_rng(5800 + seed)
    n_frames = int(rng.integers(3, 7))
    frames = _frames(rng, n_frames)
    u = int(rng.integers(1, n_frames))
    l = max(1, u - int(rng.integers(0, 3)))
    pay = [rng.integers(1, 10, len(f)).astype(float) for f in frames]
    return frames, pay, l, u


def _ranges(seed: int, end: int) -> dict[str, tuple[int, int, int, int | None, int]]:
    """The case's two properties over random ranges and least values."""
    rng = np.random.default_rng(seed)
    a, b = sorted(int(x) for x in rng.integers(0, end + 1, 2))
    c = int(rng.integers(1, 3))
    return {"sw_count": (2, 0, a, None, c), "lost_range": (0, 1, a, b, c)}


def _hide(frames: list[np.ndarray], steps: list[dict[str, Any]]) -> list[np.ndarray]:
    out = [f.copy() for f in frames]
    for s in steps:
        gone = [int(h.split(":")[1]) for h in s["hidden"]]
        out[s["step"]] = np.delete(frames[s["step"]], gone, axis=0)
    return out


@pytest.mark.parametrize("seed", range(SCENES))
def test_optima_equal_brute_force_on_reference_sort(seed: int) -> None:
    frames, pay, l, u = _case(seed)
    end = len(frames) - 1
    props = {**PROPS, **_ranges(seed, end)}
    a, b, c = props["lost_range"][2], props["lost_range"][3], props["lost_range"][4]
    scene = scene_from_dict(_doc(frames, pay))
    spec = parse_spec(SPEC.format(l=l, u=u, a=a, b=b, c=c), "p.spec")
    got = {r["property"]: r for r in multi_results(scene, "s.json", (spec,))}
    runs = _brute(frames, pay, l, u)
    refs = _reference_boxes(frames)
    for name, (cost_of, which, lo, hi, least) in props.items():
        top = end if hi is None else hi
        want = min(
            (r[cost_of] for r in runs if _score(r[3], refs, lo, top)[which] >= least),
            default=math.inf,
        )
        res = got[name]
        opt = math.inf if res["optimum"] is None else res["optimum"]
        assert opt == want, (seed, name, opt, want)
        if res["counterexample"] is None:
            continue
        steps = res["counterexample"]
        assert all(l <= s["step"] <= u for s in steps if s["hidden"])
        hidden = [(s["step"], int(h.split(":")[1])) for s in steps for h in s["hidden"]]
        costs = (
            sum(pay[k][j] for k, j in hidden),
            sum(bool(s["hidden"]) for s in steps),
            len(hidden),
        )
        assert costs[cost_of] == want, (seed, name)
        out = sort_reference.reference_sort(_hide(frames, steps))
        assert _score(out, refs, lo, top)[which] >= least, (seed, name)


def _scene_file(tmp_path: Path, seed: int = 3) -> tuple[Path, list[np.ndarray], int, int]:
    frames, pay, l, u = _case(seed)
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(_doc(frames, pay)))
    return path, frames, l, u


def test_cli_check_sort_lists_hidden_detections(tmp_path: Path) -> None:
    frames = _frames(np.random.default_rng(1), 5)
    pay = [np.ones(len(f)) for f in frames]
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(_doc(frames, pay)))
    spec = tmp_path / "p.spec"
    spec.write_text(
        "property hijack { attack window 2..4 minimize count.frames\n"
        "  subject to switches(0..end) > 0 holds if optimum > 1 }\n"
    )
    r = lesmc("check", str(path), str(spec), "--design", "sort", "--json")
    assert "Traceback" not in r.stderr, r.stderr
    doc = json.loads(r.stdout)
    res = doc["results"][0]
    assert r.returncode == (0 if res["verdict"] == "holds" else 1)
    runs = _brute(frames, pay, 2, 4)
    refs = _reference_boxes(frames)
    want = min((x[1] for x in runs if _score(x[3], refs, 0, 4)[0] > 0), default=math.inf)
    assert (math.inf if res["optimum"] is None else res["optimum"]) == want
    if res["counterexample"] is not None:
        assert all("hidden" in s for s in res["counterexample"])
        hidden = [h for s in res["counterexample"] for h in s["hidden"]]
        assert all(h.split(":")[0] in {"2", "3", "4"} for h in hidden)


def test_switches_on_single_target_design_is_located_error(tmp_path: Path) -> None:
    path, *_ = _scene_file(tmp_path)
    doc = json.loads(path.read_text())
    doc["tracker"] = {"design": "single"}
    path.write_text(json.dumps(doc))
    spec = tmp_path / "p.spec"
    spec.write_text(
        "property p {\n  attack window 1..2 minimize payoff\n"
        "  subject to switches(0..end) > 0 holds if optimum > 1 }\n"
    )
    r = lesmc("check", str(path), str(spec))
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert f"{spec}:3:" in r.stderr and "switches" in r.stderr, r.stderr


def test_unsupported_multi_target_property_is_located_error(tmp_path: Path) -> None:
    path, *_ = _scene_file(tmp_path)
    spec = tmp_path / "p.spec"
    spec.write_text(
        "property p {\n  attack window 1..2 minimize payoff\n"
        "  subject to tau.rise(1..end) > 5 holds if optimum > 1 }\n"
    )
    r = lesmc("check", str(path), str(spec), "--design", "sort")
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert f"{spec}:3:" in r.stderr and "not supported yet" in r.stderr, r.stderr


def test_build_and_export_still_refuse_sort(tmp_path: Path) -> None:
    path, *_ = _scene_file(tmp_path)
    for verb in ("build", "export"):
        out = str(tmp_path / f"{verb}.lts")
        fmt = ["--format", "json"] if verb == "export" else []
        r = lesmc(verb, str(path), "--design", "sort", "--window", "1..2", *fmt, "-o", out)
        assert r.returncode == 2 and "not supported yet" in r.stderr, r.stderr
        assert "Traceback" not in r.stderr and not Path(out).exists()


def _spec(tmp_path: Path, objective: str, window: str = "1..2") -> Path:
    spec = tmp_path / "p.spec"
    spec.write_text(
        f"property p {{\n  attack window {window} minimize {objective}\n"
        "  subject to switches(0..end) > 0 holds if optimum > 1 }\n"
    )
    return spec


def test_unpriced_payoffs_count_frames_but_not_payoff(tmp_path: Path) -> None:
    path, frames, _, _ = _scene_file(tmp_path, seed=1)
    doc = json.loads(path.read_text())
    for f in doc["frames"]:
        for d in f["detections"]:
            d["payoff"] = "unpriced"
    path.write_text(json.dumps(doc))
    r = lesmc("check", str(path), str(_spec(tmp_path, "payoff")), "--design", "sort")
    assert r.returncode == 2 and "unpriced" in r.stderr and "Traceback" not in r.stderr
    r = lesmc("check", str(path), str(_spec(tmp_path, "count.frames")), "--design", "sort")
    assert r.returncode in (0, 1) and "Traceback" not in r.stderr, r.stderr
    runs = _brute(frames, [np.ones(len(f)) for f in frames], 1, 2)
    refs = _reference_boxes(frames)
    end = len(frames) - 1
    want = min((x[1] for x in runs if _score(x[3], refs, 0, end)[0] > 0), default=math.inf)
    assert (f"optimum {want:g}" if want < math.inf else "optimum inf") in r.stdout, r.stdout


def test_a_target_without_a_reference_track_is_an_error(tmp_path: Path) -> None:
    path, *_ = _scene_file(tmp_path)
    doc = json.loads(path.read_text())
    doc["target"]["start"] = [-500.0, -500.0]  # in no box of frame 0
    path.write_text(json.dumps(doc))
    r = lesmc("check", str(path), str(_spec(tmp_path, "payoff")), "--design", "sort")
    assert r.returncode == 2 and "no reference track" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr
    spec = str(_spec(tmp_path, "payoff"))
    r = lesmc("check", str(path), spec, "--design", "sort", "--payoffs", "interval")
    assert r.returncode == 2 and "not supported yet" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr


def test_max_states_stops_the_unfolding_with_exit_3(tmp_path: Path) -> None:
    frames = _frames(np.random.default_rng(1), 5)
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(_doc(frames, [np.ones(len(f)) for f in frames])))
    spec = _spec(tmp_path, "payoff", "2..4")
    r = lesmc("check", str(path), str(spec), "--design", "sort", "--max-states", "20")
    assert r.returncode == 3 and "--max-states 20" in r.stderr and "Traceback" not in r.stderr


def test_target_track_rule() -> None:
    """The confirmed track of largest IoU >= 0.5, the lower id of equals; none otherwise."""
    from lesmc.model.identity import NONE, indicators, target_track

    ids = np.array([7, 3, 9, 4])
    confirmed = np.array([True, True, True, False])
    assert target_track(np.array([0.8, 0.8, 0.6, 0.9]), ids, confirmed) == 3
    assert target_track(np.array([0.5, 0.2, 0.49, 0.9]), ids, confirmed) == 7
    assert target_track(np.array([0.4, 0.2, 0.49, 0.9]), ids, confirmed) == NONE
    # switches: a new id after an earlier one; lost: the reference without a track
    last = np.array([NONE, 3, 3, 3])
    tid = np.array([3, 3, 5, NONE])
    ref = np.array([True, True, True, True])
    assert indicators("switches", last, tid, ref).tolist() == [0, 0, 1, 0]
    assert indicators("lost", last, tid, ref).tolist() == [0, 0, 0, 1]


def test_a_crowded_frame_is_refused_before_its_subsets_are_listed(tmp_path: Path) -> None:
    """A frame of 40 attackable detections has 2^40 subsets: --max-states (and, without
    it, the per-step limit) refuses the step from the count alone, with exit 3, instead of
    listing the subsets until memory runs out (a review found 23 GB on examples/mot)."""
    frames = _frames(np.random.default_rng(2), 4)
    grid = [[x, y, x + 8.0, y + 8.0] for x in range(200, 400, 20) for y in range(200, 280, 20)]
    frames = [np.vstack([f, np.array(grid)]) for f in frames]  # 40 far-away extra boxes
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(_doc(frames, [np.ones(len(f)) for f in frames])))
    spec = _spec(tmp_path, "payoff", "1..2")
    r = lesmc("check", str(path), str(spec), "--design", "sort", "--max-states", "20000")
    assert r.returncode == 3 and "--max-states 20000" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr
    r = lesmc("check", str(path), str(spec), "--design", "sort")
    assert r.returncode == 3 and "successors" in r.stderr and "Traceback" not in r.stderr


@pytest.mark.parametrize("option", [["--engine", "bnb"], ["--no-paths"], ["--max-memory", "1G"]])
def test_options_the_multi_target_search_does_not_read_are_refused(
    tmp_path: Path, option: list[str]
) -> None:
    """Options that would be ignored are errors (docs/cli.md), on this path too."""
    path, *_ = _scene_file(tmp_path)
    r = lesmc("check", str(path), str(_spec(tmp_path, "payoff")), "--design", "sort", *option)
    assert r.returncode == 2 and option[0] in r.stderr and "not supported yet" in r.stderr
    assert "Traceback" not in r.stderr
