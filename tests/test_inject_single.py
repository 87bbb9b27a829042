"""Injection on the nearest-neighbour tracker ``single`` (issue 61): ``attack window L..U
allow hide, inject``. Against a brute force written here: on random small scenes with
injection candidates every subset of every attacked frame's detections is hidden and every
subset of its candidates injected, and an independent Kalman filter with gated
nearest-neighbour association (numpy, from the paper's equations 1-3 and 19 and the
scene's declared matrices) tracks what is left; the optimum of ``minimize payoff subject
to dist.max(0..end) > D`` is the cheapest combination whose track strays beyond D (the
Euclidean distance of the whole state x, y, vx, vy from the unattacked one's: the
measure's default).
Every engine's optimum must equal it; hide-only is never below hide + inject; Storm
agrees on DRN exports of the injected models."""

from __future__ import annotations

import importlib.util
import itertools
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_run import lesmc
from inject_scale import cases

from lesmc import api
from lesmc.engines import registry as engines
from lesmc.scene import scene_from_dict

SCENES = cases(100, 200)  # LESMC_INJECT_FULL=1: the 200 (tests/inject_scale.py)
STORM = cases(20, 60)
DT = 1.0
Q_SD, R_SD, P0_SD = 2.0, 4.0, 10.0
GATE = 3.0


def _matrices() -> dict[str, np.ndarray]:
    """The declared model: constant velocity (Eq. 16), Q of Eq. 17, H, R of Eq. 18."""
    F = np.eye(4)
    F[0, 2] = F[1, 3] = DT
    q1 = np.array([[DT**3 / 3, DT**2 / 2], [DT**2 / 2, DT]]) * Q_SD**2
    Q = np.zeros((4, 4))
    Q[np.ix_([0, 2], [0, 2])] = q1
    Q[np.ix_([1, 3], [1, 3])] = q1
    H = np.zeros((2, 4))
    H[0, 0] = H[1, 1] = 1.0
    return {"F": F, "Q": Q, "H": H, "R": np.eye(2) * R_SD**2, "P0": np.eye(4) * P0_SD**2}


M = _matrices()


def _case(rng: np.random.Generator) -> dict[str, Any]:
    """A target moving right, 3-4 frames after the target's, ≤3 detections and ≤2
    candidates per frame around the truth; window of up to 2 attacked steps."""
    n_frames = int(rng.integers(4, 6))
    frames, dets, cands = [], [], []
    for k in range(n_frames):
        truth = np.array([10.0 * k, 0.0])
        d = truth + rng.normal(0, 6, (int(rng.integers(0, 4)), 2))
        c = truth + rng.normal(0, 9, (int(rng.integers(0, 3)), 2))
        dp = np.round(rng.uniform(0.5, 5, len(d)), 2)
        if len(d) and rng.random() < 0.15:
            dp[int(rng.integers(0, len(d)))] = np.inf
        cp = np.round(rng.uniform(0, 4, len(c)), 2)
        dets.append((d, dp))
        cands.append((c, cp))
        fr: dict[str, Any] = {
            "step": k,
            "detections": [
                {"id": f"{k}:{i}", "x": float(p[0]), "y": float(p[1]), "payoff": _pay(v)}
                for i, (p, v) in enumerate(zip(d, dp, strict=True))
            ],
        }
        if len(c):
            fr["candidates"] = [
                {"id": f"{k}:{len(d) + j}", "x": float(p[0]), "y": float(p[1]), "payoff": float(v)}
                for j, (p, v) in enumerate(zip(c, cp, strict=True))
            ]
        frames.append(fr)
    end = n_frames - 1
    lo = int(rng.integers(1, end + 1))
    hi = min(end, lo + int(rng.integers(0, 2)))
    doc = {
        "format": "lesmc-scene",
        "version": 3,
        "frames": frames,
        "target": {"step": 0, "start": [0.0, 0.0], "velocity": [10.0, 0.0]},
        "tracker": {
            "design": "single",
            "gate": GATE,
            "gate_type": "mahalanobis",
            "max_trace": 1e12,
            "model": {
                "state": ["x", "y", "vx", "vy"],
                **{k: v.tolist() for k, v in M.items()},
            },
        },
    }
    return {"doc": doc, "dets": dets, "cands": cands, "window": (lo, hi), "end": end}


def _pay(v: float) -> float | str:
    return "unattackable" if math.isinf(v) else float(v)


def _step(x: np.ndarray, P: np.ndarray, Z: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """One step of the plain tracker: predict (Eq. 1), take the nearest visible measurement
    (ties: the first listed) if sqrt(yᵀS⁻¹y) ≤ gate (Eq. 19), update (Eq. 2-3)."""
    F, Q, H, R = M["F"], M["Q"], M["H"], M["R"]
    x = F @ x
    P = F @ P @ F.T + Q
    if not Z:
        return x, P
    zs = np.array(Z)
    z = zs[int(np.argmin(np.linalg.norm(zs - H @ x, axis=1)))]
    y = z - H @ x
    S = H @ P @ H.T + R
    if math.sqrt(float(y @ np.linalg.solve(S, y))) > GATE:
        return x, P
    K = P @ H.T @ np.linalg.inv(S)
    return x + K @ y, (np.eye(4) - K @ H) @ P


def _subsets(n: int) -> list[tuple[int, ...]]:
    return [s for r in range(n + 1) for s in itertools.combinations(range(n), r)]


def _brute(case: dict[str, Any], inject: bool, hide: bool = True) -> list[tuple[float, float]]:
    """(cost, dist.max(0..end)) of every way to hide (if ``hide``) and inject (if
    ``inject``) in the window."""
    lo, hi = case["window"]
    end = case["end"]
    x0 = np.array([0.0, 0.0, 10.0, 0.0])

    def run(choice: dict[int, tuple[tuple[int, ...], tuple[int, ...]]]) -> list[np.ndarray]:
        x, P, out = x0, M["P0"], [x0]
        for k in range(1, end + 1):
            (d, _), (c, _) = case["dets"][k], case["cands"][k]
            hid, inj = choice.get(k, ((), ()))
            Z = [d[i] for i in range(len(d)) if i not in hid] + [c[j] for j in inj]
            x, P = _step(x, P, Z)
            out.append(x)
        return out

    original = run({})
    per_step = []
    for k in range(lo, hi + 1):
        (d, dp), (c, cp) = case["dets"][k], case["cands"][k]
        can = [i for i in range(len(d)) if math.isfinite(dp[i])] if hide else []
        hides = [s for r in range(len(can) + 1) for s in itertools.combinations(can, r)]
        injs = _subsets(len(c)) if inject else [()]
        per_step.append(
            [(k, h, j, sum(dp[list(h)]) + sum(cp[list(j)])) for h in hides for j in injs]
        )
    out = []
    for combo in itertools.product(*per_step):
        track = run({k: (h, j) for k, h, j, _ in combo})
        dev = max(float(np.linalg.norm(a - b)) for a, b in zip(track, original, strict=True))
        out.append((sum(c for *_, c in combo), dev))
    return out


def _optimum(leaves: list[tuple[float, float]], bound: float) -> float:
    return min((c for c, d in leaves if d > bound), default=math.inf)


def _spec(case: dict[str, Any], bound: float, inject: bool, hide: bool = True) -> str:
    lo, hi = case["window"]
    allow = (" allow hide, inject" if hide else " allow inject") if inject else ""
    return (
        f"property p {{ attack window {lo}..{hi}{allow} end {case['end']} minimize payoff "
        f"subject to dist.max(0..end) > {bound} holds if optimum > 100 }}\n"
    )


def _bound(leaves: list[tuple[float, float]], rng: np.random.Generator) -> float:
    """A bound between two of the reachable deviations (never on one)."""
    devs = sorted({round(d, 6) for _, d in leaves})
    if len(devs) < 2:
        return round(devs[0] + 1.0, 3)
    i = int(rng.integers(0, len(devs) - 1))
    return round((devs[i] + devs[i + 1]) / 2, 6)


def _check(doc: dict[str, Any], spec: str, engine: str) -> float:
    res = api.check(scene_from_dict(doc), api.parse_spec(spec), engine=engine)
    assert len(res) == 1
    return float(res[0].optimum) if res[0].optimum is not None else math.inf


def _cases(n: int, seed: int) -> list[dict[str, Any]]:
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < n:
        case = _case(rng)
        lo, hi = case["window"]
        if not any(len(case["cands"][k][0]) for k in range(lo, hi + 1)):
            continue  # nothing to inject in the window
        out.append(case)
    return out


@pytest.mark.parametrize("chunk", range(4))
def test_every_engine_equals_the_brute_force_with_injection(chunk: int) -> None:
    rng = np.random.default_rng(100 + chunk)
    strict = 0
    for case in _cases(SCENES // 4, 7 + chunk):
        both = _brute(case, inject=True)
        hide = _brute(case, inject=False)
        bound = _bound(both, rng)
        want, want_hide = _optimum(both, bound), _optimum(hide, bound)
        assert want_hide >= want  # adding inject never raises an optimum
        strict += want < want_hide
        for engine in engines.names():
            got = _check(case["doc"], _spec(case, bound, True), engine)
            assert got == pytest.approx(want, abs=1e-9), (engine, case["window"], bound)
        got_hide = _check(case["doc"], _spec(case, bound, False), engines.names()[0])
        assert got_hide == pytest.approx(want_hide, abs=1e-9)
    assert strict  # some case where injecting is strictly cheaper


def test_inject_alone_equals_the_brute_force() -> None:
    """``allow inject`` without hide: the attacker only adds candidates."""
    rng = np.random.default_rng(5)
    for case in _cases(20, 11):
        leaves = _brute(case, inject=True, hide=False)
        bound = _bound(leaves, rng)
        want = _optimum(leaves, bound)
        for engine in engines.names():
            got = _check(case["doc"], _spec(case, bound, True, hide=False), engine)
            assert got == pytest.approx(want, abs=1e-9), (engine, case["window"], bound)


def test_hide_only_optimum_can_exceed_the_injected_one() -> None:
    """The first frame has one detection on the track; a cheap candidate far aside drags it."""
    case = _cases(1, 1)[0]
    doc = case["doc"]
    doc["frames"] = [
        {"step": 0, "detections": []},
        {
            "step": 1,
            "detections": [{"id": "1:0", "x": 10.0, "y": 0.5, "payoff": 5.0}],
            "candidates": [{"id": "1:1", "x": 10.0, "y": 12.0, "payoff": 1.0}],
        },
        {"step": 2, "detections": [{"id": "2:0", "x": 20.0, "y": 0.0, "payoff": 5.0}]},
    ]
    spec = (
        "property p { attack window 1..1 allow hide, inject minimize payoff "
        "subject to dist.max(0..end) > 3 holds if optimum > 10 }\n"
    )
    for engine in engines.names():
        assert _check(doc, spec, engine) == pytest.approx(6.0)  # hide 1:0 (5), inject 1:1 (1)
    hide_only = spec.replace(" allow hide, inject", "")
    assert _check(doc, hide_only, "levels") == math.inf  # hiding alone never strays 3


def test_cli_counterexample_names_the_injected_candidate(tmp_path: Path) -> None:
    case = _cases(1, 1)[0]
    doc = case["doc"]
    doc["frames"] = [
        {"step": 0, "detections": []},
        {
            "step": 1,
            "detections": [{"id": "1:0", "x": 10.0, "y": 0.5, "payoff": 5.0}],
            "candidates": [{"id": "1:1", "x": 10.0, "y": 12.0, "payoff": 1.0}],
        },
        {"step": 2, "detections": [{"id": "2:0", "x": 20.0, "y": 0.0, "payoff": 5.0}]},
    ]
    scene, spec = tmp_path / "s.json", tmp_path / "p.spec"
    scene.write_text(json.dumps(doc))
    spec.write_text(
        "property p { attack window 1..1 allow hide, inject minimize payoff "
        "subject to dist.max(0..end) > 3 holds if optimum > 10 }\n"
    )
    r = lesmc("check", str(scene), str(spec), "--json")
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
    res = json.loads(r.stdout)["results"][0]
    assert res["optimum"] == pytest.approx(6.0)
    assert "1:1" in json.dumps(res["counterexample"])


def test_storm_agrees_on_drn_exports_with_injections(tmp_path: Path) -> None:
    """Storm's exact optimum of the exported MDP (rewards: the own payoffs of Eq. 5, the
    ranks ordered by cost) equals the brute force, on 20 built models with injections."""
    pytest.importorskip("stormpy")
    from test_export import assert_equal_exactly, storm_optimum

    from lesmc.engines.check import bind_all
    from lesmc.exporters.drn import to_drn
    from lesmc.unfold.unfold import build_model

    rng = np.random.default_rng(23)
    for case in _cases(STORM, 29):
        leaves = _brute(case, inject=True)
        bound = _bound(leaves, rng)
        model = build_model(scene_from_dict(case["doc"]), case["window"], inject=True)
        assert model.meta["actions"] == ["hide", "inject"]
        spec = api.parse_spec(_spec(case, bound, True))
        text, _ = to_drn(model, bind_all(model, [spec])[0])
        got = storm_optimum(text, tmp_path)
        assert_equal_exactly(got, _optimum(leaves, bound), text, case["end"] + 1)


def test_cli_export_builds_the_property_attacker_and_a_model_keeps_it(tmp_path: Path) -> None:
    """``lesmc export SCENE --spec`` builds with the property's actions (its DRN has the
    injected candidate's transition); a hide-only property on that model is refused."""
    case = _cases(1, 1)[0]
    doc = case["doc"]
    doc["frames"] = [
        {"step": 0, "detections": []},
        {
            "step": 1,
            "detections": [{"id": "1:0", "x": 10.0, "y": 0.5, "payoff": 5.0}],
            "candidates": [{"id": "1:1", "x": 10.0, "y": 12.0, "payoff": 1.0}],
        },
        {"step": 2, "detections": [{"id": "2:0", "x": 20.0, "y": 0.0, "payoff": 5.0}]},
    ]
    scene, spec, out = tmp_path / "s.json", tmp_path / "p.spec", tmp_path / "m.drn"
    scene.write_text(json.dumps(doc))
    text = (
        "property p { attack window 1..1 allow hide, inject minimize payoff "
        "subject to dist.max(0..end) > 3 holds if optimum > 10 }\n"
    )
    spec.write_text(text)
    r = lesmc("export", str(scene), "--format", "drn", "--spec", str(spec), "-o", str(out))
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    if importlib.util.find_spec("stormpy") is not None:
        from test_export import storm_optimum

        assert storm_optimum(out.read_text(), tmp_path) == 6
    lts = tmp_path / "m.lts"
    r = lesmc("build", str(scene), "--window", "1..1", "-o", str(lts))
    assert r.returncode == 0, r.stderr  # built hide-only: the inject property is refused
    r = lesmc("check", str(lts), str(spec))
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert f"{spec}:1:" in r.stderr and "meta.actions" in r.stderr


def test_one_spec_mixing_hide_only_and_inject_properties_checks_each_on_its_model() -> None:
    """The pipeline keys its models by the attacker's actions: a hide-only property and an
    inject one in one spec each get their own brute-force optimum."""
    rng = np.random.default_rng(41)
    for case in _cases(5, 43):
        both, hide = _brute(case, inject=True), _brute(case, inject=False)
        bound = _bound(both, rng)
        text = _spec(case, bound, False) + _spec(case, bound, True).replace(
            "property p", "property q"
        )
        res = api.check(scene_from_dict(case["doc"]), api.parse_spec(text))
        got = {r.property: math.inf if r.optimum is None else float(r.optimum) for r in res}
        assert got["p"] == pytest.approx(_optimum(hide, bound), abs=1e-9)
        assert got["q"] == pytest.approx(_optimum(both, bound), abs=1e-9)
