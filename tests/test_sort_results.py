"""SORT results (issue 58): the ``lesmc-multi-check`` document against its schema, the
``dist`` measures read by the target's id, ``attack window L..U within R``, the reference
from truth, motmetrics' SWITCH events on counterexample runs, and the bound on IoU arrays.
Every expectation comes from an independent computation: the reference SORT
(``sort-tracker-py``, run unchanged) on the scene with the hidden detections removed."""

from __future__ import annotations

import importlib
import itertools
import json
import math
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np
import pytest
from cli_run import lesmc

from lesmc.cli.multi_check import multi_results
from lesmc.language.parser import parse_spec
from lesmc.scene import scene_from_dict
from lesmc.schemas import SCHEMAS, schema, validate

sort_reference = pytest.importorskip("sort_reference")
pytest.importorskip("sort_tracker")
multi_attack = pytest.importorskip("test_multi_attack")

HIJACK = (
    "property hijack {{\n  attack window {w} minimize {obj}\n"
    "  subject to {con} holds if optimum > 1 }}\n"
)


def _scene(tmp_path: Path, seed: int = 1, n: int = 5) -> tuple[Path, list[np.ndarray]]:
    frames = multi_attack._frames(np.random.default_rng(seed), n)
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(multi_attack._doc(frames, [np.ones(len(f)) for f in frames])))
    return path, frames


def _spec(tmp_path: Path, w: str = "2..4", obj: str = "payoff", con: str = "") -> Path:
    spec = tmp_path / "p.spec"
    spec.write_text(HIJACK.format(w=w, obj=obj, con=con or "switches(0..end) > 0"))
    return spec


@pytest.mark.parametrize("objective", ["payoff", "count.frames"])
def test_multi_check_json_conforms_to_its_schema(tmp_path: Path, objective: str) -> None:
    path, _ = _scene(tmp_path)
    spec = tmp_path / "p.spec"
    spec.write_text(
        HIJACK.format(w="2..4", obj=objective, con="switches(0..end) > 0")
        + HIJACK.replace("hijack", "never").format(w="2..2", obj=objective, con="lost(0..1) > 0")
    )
    r = lesmc("check", str(path), str(spec), "--design", "sort", "--json")
    assert r.returncode in (0, 1) and "Traceback" not in r.stderr, r.stderr
    doc = json.loads(r.stdout)
    assert SCHEMAS[doc["format"]] == "multi-check"
    jsonschema.validate(doc, schema("multi-check"))
    validate(doc, "multi-check")  # the built-in validator agrees
    never = doc["results"][1]  # the window 2..2 cannot change steps 0..1
    assert never["optimum"] is None and never["counterexample"] is None
    bad = {**doc, "results": [{**doc["results"][0], "verdict": "maybe"}]}
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(bad, schema("multi-check"))


# ------------------------------------------------------------------ an independent brute force


def _combos(frames: list[np.ndarray], l: int, u: int, can: Any = None) -> Any:
    """Every way to hide subsets of the attackable detections of steps l..u: per step the
    indices hidden (``can(k, j)``: detection j of step k may be hidden; default all)."""
    per = []
    for k, boxes in enumerate(frames):
        idx = [j for j in range(len(boxes)) if l <= k <= u and (can is None or can(k, j))]
        per.append([s for r in range(len(idx) + 1) for s in itertools.combinations(idx, r)])
    return itertools.product(*per)


def _run_fresh(frames: list[np.ndarray], hidden: tuple[tuple[int, ...], ...], rid: int) -> Any:
    """The reference SORT (ids from 1) on ``frames`` without the ``hidden`` detections: its
    output per step, and per step the box of its track of id ``rid`` (None: not born yet,
    "gone": deleted), read from SORT's own trackers."""
    sort = importlib.import_module("sort_tracker.sort")
    sort.KalmanBoxTracker.count = 0
    tracker = sort.Sort(max_age=1, min_hits=3, iou_threshold=0.3)
    outs, boxes = [], []
    for k, f in enumerate(frames):
        kept = np.delete(f, list(hidden[k]), axis=0)
        dets = np.hstack([kept, np.ones((len(kept), 1))]) if len(kept) else np.empty((0, 5))
        with sort_reference._without_lap():
            res = tracker.update(dets)
        outs.append({int(r[-1]): np.asarray(r[:4], dtype=float) for r in res})
        mine = [t for t in tracker.trackers if t.id + 1 == rid]
        if mine:
            boxes.append(np.asarray(mine[0].get_state()[0], dtype=float))
        else:
            boxes.append("gone" if sort.KalmanBoxTracker.count >= rid else None)
    return outs, boxes


def _centre(b: np.ndarray) -> np.ndarray:
    return np.array([(b[0] + b[2]) / 2, (b[1] + b[3]) / 2])


def _dist_at(box: Any, ref: Any) -> float:
    """dist.at on x, y: the centres' distance; inf once deleted; 0 without both boxes."""
    if isinstance(box, str):
        return math.inf
    if box is None or ref is None:
        return 0.0
    return float(np.hypot(*(_centre(box) - _centre(ref))))


def _case(seed: int) -> tuple[list[np.ndarray], list[np.ndarray], int, int]:
    rng = np.random.default_rng(9100 + seed)
    n = int(rng.integers(4, 7))
    frames = multi_attack._frames(rng, n)
    u = int(rng.integers(1, n))
    l = max(1, u - int(rng.integers(0, 2)))
    pay = [rng.integers(1, 10, len(f)).astype(float) for f in frames]
    return frames, pay, l, u


def _check(frames: list[np.ndarray], pay: list[np.ndarray], text: str) -> dict[str, Any]:
    scene = scene_from_dict(multi_attack._doc(frames, pay))
    spec = parse_spec(text, "p.spec")
    return {r["property"]: r for r in multi_results(scene, "s.json", (spec,))}


DIST_SPEC = """
property far {{ attack window {l}..{u} minimize payoff
  subject to dist.max(0..end) > {c} holds if optimum > 1000 on x, y }}
property far_end {{ attack window {l}..{u} minimize count.frames
  subject to dist.at(end) > {c} holds if optimum > 1000 on x, y }}
property least_sum {{ attack window {l}..{u} minimize dist.sum({l}..end)
  subject to switches(0..end) > 0 holds if optimum > 1000 on x, y }}
"""


@pytest.mark.parametrize("seed", range(12))
def test_dist_reads_the_track_of_the_targets_id(seed: int) -> None:
    """dist.max / dist.at / dist.sum of the track with the target's id (its unattacked
    track's: the one born on detection 0 of frame 0) against the reference box, +inf once
    SORT deleted it: every attack of the window through the reference SORT."""
    frames, pay, l, u = _case(seed)
    c = float(np.random.default_rng(seed).uniform(3, 25))
    got = _check(frames, pay, DIST_SPEC.format(l=l, u=u, c=c))
    refs = multi_attack._reference_boxes(frames)
    first = sort_reference.reference_sort(frames)[0]
    rid = max(first, key=lambda i: multi_attack._iou(first[i], frames[0][0]))
    far, far_end, least = math.inf, math.inf, math.inf
    for hidden in _combos(frames, l, u):
        outs, boxes = _run_fresh(frames, hidden, rid)
        d = [_dist_at(b, r) for b, r in zip(boxes, refs, strict=True)]
        cost = math.fsum(pay[k][j] for k, s in enumerate(hidden) for j in s)
        if max(d) > c:
            far = min(far, cost)
        if d[-1] > c:
            far_end = min(far_end, sum(bool(s) for s in hidden))
        if multi_attack._score(outs, refs, 0, len(frames) - 1)[0] > 0:
            least = min(least, sum(d[l:]))
    for name, want in (("far", far), ("far_end", far_end), ("least_sum", least)):
        res = got[name]
        opt = math.inf if res["optimum"] is None else res["optimum"]
        assert opt == pytest.approx(want, rel=1e-9, abs=1e-9), (seed, name, opt, want)


WITHIN_SPEC = """
property near {{ attack window {l}..{u} within {r} minimize payoff
  subject to switches(0..end) > 0 holds if optimum > 1000 }}
property near_lost {{ attack window {l}..{u} within {r} minimize count.frames
  subject to lost(0..end) > 0 holds if optimum > 1000 }}
"""


@pytest.mark.parametrize("seed", range(10))
def test_attack_within_r_hides_only_detections_near_the_reference(seed: int) -> None:
    """``within R``: the brute force hides only detections whose centre lies within R px of
    the reference box's centre at their frame (none where the reference is absent)."""
    frames, pay, l, u = _case(seed)
    r = float(np.random.default_rng(seed).uniform(5, 40))
    got = _check(frames, pay, WITHIN_SPEC.format(l=l, u=u, r=r))
    refs = multi_attack._reference_boxes(frames)

    def can(k: int, j: int) -> bool:
        ref = refs[k]
        return ref is not None and np.hypot(*(_centre(frames[k][j]) - _centre(ref))) <= r

    end = len(frames) - 1
    near, near_lost = math.inf, math.inf
    for hidden in _combos(frames, l, u, can):
        outs, _ = _run_fresh(frames, hidden, 1)
        sw, lost = multi_attack._score(outs, refs, 0, end)
        if sw > 0:
            near = min(near, math.fsum(pay[k][j] for k, s in enumerate(hidden) for j in s))
        if lost > 0:
            near_lost = min(near_lost, sum(bool(s) for s in hidden))
    for name, want in (("near", near), ("near_lost", near_lost)):
        res = got[name]
        assert (math.inf if res["optimum"] is None else res["optimum"]) == want, (seed, name)
        for s in res["counterexample"] or []:
            assert all(can(s["step"], int(h.split(":")[1])) for h in s["hidden"])


@pytest.mark.parametrize(
    ("window", "want"), [("2..4 within 0", "must be positive"), ("2..4 within -3", "positive")]
)
def test_a_radius_not_above_zero_is_located(tmp_path: Path, window: str, want: str) -> None:
    path, _ = _scene(tmp_path)
    spec = _spec(tmp_path, w=window)
    r = lesmc("check", str(path), str(spec), "--design", "sort")
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    col = HIJACK.splitlines()[1].index("{w}") + window.index("within") + len("within ") + 1
    assert f"{spec}:2:{col}: " in r.stderr and want in r.stderr, r.stderr


def test_within_on_a_single_target_design_is_located(tmp_path: Path) -> None:
    path, _ = _scene(tmp_path)
    doc = json.loads(path.read_text())
    doc["tracker"] = {"design": "single"}
    path.write_text(json.dumps(doc))
    spec = _spec(tmp_path, w="1..2 within 30", con="dist.max(0..end) > 5")
    r = lesmc("check", str(path), str(spec))
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert f"{spec}:2:3: " in r.stderr and "within" in r.stderr, r.stderr
