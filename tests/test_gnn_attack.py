"""The exact cheapest identity attack on ``gnn`` (``lesmc check --design gnn``) against a
brute force: on random small scenes (3 objects crossing, <= 4 detections a frame, attack
windows of 1-3 steps) every subset of every attacked frame's detections is hidden, an
independent plain-Python gnn tracker (tests/gnn_plain.py, itself checked against Stone
Soup here) tracks the rest, and switches / lost are scored from its output. The optima of
payoff and count.frames must agree, and each counterexample's hidden detections, run
through the plain tracker, must do as claimed."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_run import lesmc

from lesmc.cli.multi_check import multi_results
from lesmc.common.errors import UsageError
from lesmc.language.parser import parse_spec
from lesmc.scene import scene_from_dict

gnn_reference = pytest.importorskip("gnn_reference")  # needs stonesoup
import gnn_plain  # noqa: E402
from scipy.stats import chi2  # noqa: E402
from test_gnn import same_runs, scene_doc  # noqa: E402

SCENES = 30
PARAMS = gnn_reference.Params(min_hits=2, confirm_window=3, max_age=1)


def _frames(rng: np.random.Generator, n: int) -> list[np.ndarray]:
    """Three objects crossing, each missed at random (not in frame 0), sometimes clutter."""
    pos = np.array([[20.0, 50.0], [80.0, 52.0], [50.0, 20.0]]) + rng.normal(0, 3, (3, 2))
    vel = np.array([[10.0, 0.5], [-10.0, 0.0], [0.0, 9.0]]) + rng.normal(0, 2, (3, 2))
    out = []
    for k in range(n):
        p = pos + k * vel + rng.normal(0, 1, (3, 2))
        rows = [q for q in p if k == 0 or rng.random() < 0.85]
        if len(rows) < 4 and rng.random() < 0.15:
            rows.append(rng.uniform(20, 80, 2))
        out.append(np.array(rows, dtype=float).reshape(-1, 2))
    return out


def _case(seed: int) -> tuple[list[np.ndarray], list[np.ndarray], int, int]:
    rng = np.random.default_rng(6100 + seed)
    n_frames = int(rng.integers(3, 8))
    frames = _frames(rng, n_frames)
    u = int(rng.integers(1, n_frames))
    l = max(1, u - int(rng.integers(0, 3)))
    pay = [rng.integers(1, 10, len(f)).astype(float) for f in frames]
    return frames, pay, l, u


Out = list[dict[int, tuple[np.ndarray, np.ndarray]]]


def _plain(frames: list[np.ndarray]) -> Out:
    t = gnn_plain.Plain(PARAMS)
    return [t.step(Z) for Z in frames]


def _refs(frames: list[np.ndarray]) -> list[np.ndarray | None]:
    """The target's reference: the unattacked track born on frame 0's detection 0 (the
    target's start; frame 0 starts a track per detection, ids 1, 2, ... in order), where
    it is output."""
    return [o[1][0] if 1 in o else None for o in _plain(frames)]


def _score(out: Out, refs: list[np.ndarray | None], lo: int, hi: int) -> tuple[int, int]:
    """switches(lo..hi) and lost(lo..hi) of one run: the target's track is the output
    track nearest the reference (Mahalanobis under its H P Hᵀ + R) within the gate, the
    lower id of equals."""
    gate2 = chi2.ppf(PARAMS.gate_probability, 2)
    switches = lost = 0
    last = None
    for k, (tracks, ref) in enumerate(zip(out, refs, strict=True)):
        if ref is None:
            continue
        best, top = None, math.inf
        for i in sorted(tracks):
            y = ref - tracks[i][0]
            d2 = float(y @ np.linalg.solve(tracks[i][1], y))
            if d2 < gate2 and d2 < top:
                best, top = i, d2
        if best is None:
            lost += lo <= k <= hi
            continue
        if last is not None and best != last and lo <= k <= hi:
            switches += 1
        last = best
    return switches, lost


Leaf = tuple[float, int, int, Out]


def _brute(frames: list[np.ndarray], pay: list[np.ndarray], l: int, u: int) -> list[Leaf]:
    """(payoff, frames attacked, detections hidden, the plain tracker's output) of every
    way to hide subsets of the detections of steps l..u (prefixes shared by copying)."""
    end = len(frames) - 1
    results: list[Leaf] = []

    def run(t: Any, k: int, hist: Out, cost: float, n: int, h: int) -> None:
        if k > end:
            results.append((cost, n, h, hist))
            return
        Z = frames[k]
        subsets: list[tuple[int, ...]] = [()]
        if l <= k <= u:
            idx = range(len(Z))
            subsets = [s for r in range(len(Z) + 1) for s in itertools.combinations(idx, r)]
        for sub in subsets:
            c = t.copy() if len(subsets) > 1 else t
            got = c.step(np.delete(Z, list(sub), axis=0))
            cc = cost + math.fsum(pay[k][list(sub)]) if sub else cost
            run(c, k + 1, [*hist, got], cc, n + bool(sub), h + len(sub))

    run(gnn_plain.Plain(PARAMS), 0, [], 0.0, 0, 0)
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
  subject to switches(0..end) >= 2 holds if optimum > 1000 }}
"""

#: each property: the cost (0 payoff, 1 frames, 2 detections hidden), the measure (0
#: switches, 1 lost) and its least value
PROPS = {
    "sw_payoff": (0, 0, 1),
    "sw_frames": (1, 0, 1),
    "lost_payoff": (0, 1, 1),
    "lost_frames": (1, 1, 1),
    "sw_count": (2, 0, 2),
}


def _hide(frames: list[np.ndarray], steps: list[dict[str, Any]]) -> list[np.ndarray]:
    out = [f.copy() for f in frames]
    for s in steps:
        gone = [int(h.split(":")[1]) for h in s["hidden"]]
        out[s["step"]] = np.delete(frames[s["step"]], gone, axis=0)
    return out


@pytest.mark.parametrize("seed", range(SCENES))
def test_gnn_optima_equal_brute_force(seed: int) -> None:
    frames, pay, l, u = _case(seed)
    end = len(frames) - 1
    scene = scene_from_dict(scene_doc(frames, PARAMS, pay))
    spec = parse_spec(SPEC.format(l=l, u=u), "p.spec")
    refs = _refs(frames)
    if all(r is None for r in refs):  # the target's track is never output: no reference
        with pytest.raises(UsageError, match="no reference track"):
            multi_results(scene, "s.json", (spec,))
        return
    got = {r["property"]: r for r in multi_results(scene, "s.json", (spec,))}
    runs = _brute(frames, pay, l, u)
    for name, (cost_of, which, least) in PROPS.items():
        want = min(
            (r[cost_of] for r in runs if _score(r[3], refs, 0, end)[which] >= least),
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
        out = _plain(_hide(frames, steps))
        assert _score(out, refs, 0, end)[which] >= least, (seed, name)


@pytest.mark.parametrize("seed", range(10))
def test_plain_reference_equals_stone_soup(seed: int) -> None:
    """The brute force's tracker is Stone Soup's composition (positions to 1e-6)."""
    frames, *_ = _case(seed)
    ours = [{i: v[0] for i, v in o.items()} for o in _plain(frames)]
    theirs = [{i: x[:2] for i, x in o.items()} for o in gnn_reference.run(frames, PARAMS)]
    same_runs(ours, theirs)


def test_cli_check_gnn_lists_hidden_detections(tmp_path: Path) -> None:
    frames = _frames(np.random.default_rng(1), 6)
    pay = [np.ones(len(f)) for f in frames]
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(scene_doc(frames, PARAMS, pay)))
    spec = tmp_path / "p.spec"
    spec.write_text(
        "property hijack { attack window 2..4 minimize count.frames\n"
        "  subject to switches(0..end) > 0 holds if optimum > 1 }\n"
    )
    r = lesmc("check", str(path), str(spec), "--design", "gnn", "--json")
    assert "Traceback" not in r.stderr, r.stderr
    res = json.loads(r.stdout)["results"][0]
    assert r.returncode == (0 if res["verdict"] == "holds" else 1)
    runs = _brute(frames, pay, 2, 4)
    refs = _refs(frames)
    want = min((x[1] for x in runs if _score(x[3], refs, 0, 5)[0] > 0), default=math.inf)
    assert (math.inf if res["optimum"] is None else res["optimum"]) == want


def test_a_gnn_target_far_from_every_detection_is_an_error(tmp_path: Path) -> None:
    """A point target's reference is the track of a detection within the gate of its start
    (under R): none there is exit status 2, no traceback."""
    frames = _frames(np.random.default_rng(1), 6)
    doc = scene_doc(frames, PARAMS)
    doc["target"]["start"] = [frames[0][0][0], frames[0][0][1] + 200.0]  # 40 σ_r away
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(doc))
    spec = tmp_path / "p.spec"
    spec.write_text(
        "property p { attack window 1..2 minimize payoff\n"
        "  subject to switches(0..end) > 0 holds if optimum > 1 }\n"
    )
    r = lesmc("check", str(path), str(spec))
    assert r.returncode == 2 and "no reference track" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr


def test_gnn_m_above_n_through_design_override_is_an_error(tmp_path: Path) -> None:
    """min_hits > confirm_window in a scene made for another design, then --design gnn."""
    frames = _frames(np.random.default_rng(1), 4)
    doc = scene_doc(frames, PARAMS)
    doc["tracker"].update(design="single", min_hits=4, confirm_window=3)
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(doc))
    r = lesmc("track", str(path), "--design", "gnn")
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert "must be at most confirm_window" in r.stderr and str(path) in r.stderr
