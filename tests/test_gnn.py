"""The ``gnn`` design against the same composition built in Stone Soup 1.9
(tests/gnn_reference.py): on random scenes (objects born and dying, crossing, missed,
clutter; random dt, noise, gate probability, M, N and max_age) the same output tracks
per frame, ids up to one renaming fixed at first sight, states to 1e-6; plus the gnn
preset's tracker-file keys and located errors."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_run import lesmc

from lesmc.scene import scene_from_dict
from lesmc.tracking.gnn import GnnDesign

gnn_reference = pytest.importorskip("gnn_reference")  # needs stonesoup

SCENES = 100


def random_frames(rng: np.random.Generator, n: int) -> list[np.ndarray]:
    """2-5 objects on straight noisy paths, each in the scene for a random span of
    frames, missed at random; clutter; sometimes an empty frame."""
    k = int(rng.integers(2, 6))
    pos = rng.uniform(0, 100, (k, 2))
    vel = rng.normal(0, 6, (k, 2))
    span = np.sort(rng.integers(0, n + 1, (k, 2)), axis=1)
    span[0] = (0, n)
    out = []
    for t in range(n):
        rows = [
            pos[i] + t * vel[i] + rng.normal(0, 1.5, 2)
            for i in range(k)
            if span[i, 0] <= t < span[i, 1] and rng.random() < 0.85
        ]
        rows += [rng.uniform(0, 100, 2) for _ in range(int(rng.integers(0, 3)))]
        if rng.random() < 0.05:
            rows = []
        out.append(np.array(rows, dtype=float).reshape(-1, 2))
    return out


def random_params(rng: np.random.Generator) -> Any:
    m = int(rng.integers(1, 5))
    return gnn_reference.Params(  # dt in ms: Stone Soup's times are datetimes (to 1 µs)
        dt=float(rng.choice([1.0, 0.5, round(float(rng.uniform(0.1, 2.0)), 3)])),
        sigma_q=float(rng.uniform(0.5, 6.0)),
        sigma_r=float(rng.uniform(1.0, 8.0)),
        P0_sd=tuple(float(x) for x in rng.uniform(5.0, 40.0, 4)),  # type: ignore[arg-type]
        gate_probability=float(rng.choice([0.99, 0.95, float(rng.uniform(0.5, 0.9999))])),
        min_hits=m,
        confirm_window=m + int(rng.integers(0, 4)),
        max_age=int(rng.integers(0, 4)),
    )


def scene_doc(frames: list[np.ndarray], p: Any, pay: list[np.ndarray] | None = None) -> dict:
    """A scene (format 1: points) with the gnn tracker of ``p``; the target is frame 0's
    first detection (an empty frame 0: (0, 0))."""
    dets = [
        {
            "step": k,
            "detections": [
                {
                    "id": f"{k}:{j}",
                    "x": float(z[0]),
                    "y": float(z[1]),
                    "payoff": 1.0 if pay is None else float(pay[k][j]),
                }
                for j, z in enumerate(Z)
            ],
        }
        for k, Z in enumerate(frames)
    ]
    tracker = {
        "design": "gnn",
        "sigma_q": p.sigma_q,
        "sigma_r": p.sigma_r,
        "P0_sd": list(p.P0_sd),
        "gate_probability": p.gate_probability,
        "min_hits": p.min_hits,
        "confirm_window": p.confirm_window,
        "max_age": p.max_age,
    }
    doc: dict[str, Any] = {"format": "lesmc-scene", "version": 1, "dt": p.dt, "frames": dets}
    doc["tracker"] = tracker
    start = [float(frames[0][0][0]), float(frames[0][0][1])] if len(frames[0]) else [0.0, 0.0]
    doc["target"] = {"step": 0, "start": start}
    return doc


def lesmc_states(frames: list[np.ndarray], p: Any) -> list[dict[int, np.ndarray]]:
    """lesmc's output (confirmed) tracks per frame, {id: state [x, y, vx, vy]}."""
    design = GnnDesign(scene_from_dict(scene_doc(frames, p)))
    tracker = design.tracker
    state = tracker.initial()
    out = []
    for Z in frames:
        state, ft = tracker.step(state, Z)
        t = state.tracks
        assert np.array_equal(t.id, ft.ids)
        out.append({int(i): t.X[j].copy() for j, i in enumerate(t.id) if ft.confirmed[j]})
    return out


def same_runs(ours: list[dict[int, np.ndarray]], theirs: list[dict[Any, np.ndarray]]) -> None:
    """The same tracks per frame, ids up to one renaming fixed at first sight, states
    to 1e-6."""
    name: dict[Any, int] = {}
    for k, (a, b) in enumerate(zip(ours, theirs, strict=True)):
        assert len(a) == len(b), (k, sorted(a), len(b))
        for tid, x in b.items():
            if tid not in name:  # first sight: the one of ours not named yet at this state
                free = [i for i in a if i not in name.values()]
                near = [i for i in free if np.allclose(a[i], x, rtol=0, atol=1e-6)]
                assert len(near) == 1, (k, tid, x, {i: a[i] for i in free})
                name[tid] = near[0]
            i = name[tid]
            assert i in a, (k, tid, i, sorted(a))
            np.testing.assert_allclose(a[i], x, rtol=0, atol=1e-6, err_msg=f"frame {k}")


@pytest.mark.parametrize("seed", range(SCENES))
def test_gnn_equals_stone_soup(seed: int) -> None:
    rng = np.random.default_rng(5900 + seed)
    frames = random_frames(rng, int(rng.integers(6, 16)))
    p = random_params(rng)
    same_runs(lesmc_states(frames, p), gnn_reference.run(frames, p))


def test_default_gnn_equals_stone_soup_and_confirms_tracks() -> None:
    """The defaults (M 3 of N 5, max_age 1, p 0.99, the paper's noise), crossing objects:
    tracks are confirmed and kept."""
    rng = np.random.default_rng(7)
    frames = random_frames(rng, 15)
    p = gnn_reference.Params()
    ours = lesmc_states(frames, p)
    same_runs(ours, gnn_reference.run(frames, p))
    assert sum(len(o) for o in ours) >= 10


def test_cli_track_gnn_json_matches_stone_soup(tmp_path: Path) -> None:
    """``lesmc track --design gnn --json``: per step every track's id, position, status;
    the confirmed ones are Stone Soup's output (positions to 1e-6, ids renamed)."""
    rng = np.random.default_rng(11)
    frames = random_frames(rng, 10)
    p = gnn_reference.Params(min_hits=2, confirm_window=3)
    doc = scene_doc(frames, p)
    doc["tracker"]["design"] = "single"
    path = tmp_path / "s.json"
    path.write_text(json.dumps(doc))
    r = lesmc("track", str(path), "--design", "gnn", "--json")
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    out = json.loads(r.stdout)
    assert out["design"] == "gnn"
    ours = [
        {t["id"]: np.array(t["position"]) for t in s["tracks"] if t["status"] == "confirmed"}
        for s in out["track"]
    ]
    theirs = [{i: x[:2] for i, x in o.items()} for o in gnn_reference.run(frames, p)]
    same_runs(ours, theirs)
    assert all(set(t) == {"id", "position", "status"} for s in out["track"] for t in s["tracks"])
    from lesmc.schemas import schema

    jsonschema = pytest.importorskip("jsonschema")
    jsonschema.validate(out, schema("track"))


@pytest.mark.parametrize(
    ("key", "value", "what"),
    [
        ("gate_probability", 1.0, "gate_probability must be a number in (0, 1)"),
        ("gate_probability", 0, "gate_probability must be a number in (0, 1)"),
        ("confirm_window", 0, "confirm_window must be an integer in 1.."),
        ("min_hits", 0, "min_hits must be an integer in 1.."),
        ("max_age", -1, "max_age must be an integer in 0.."),
        ("min_hits", 6, "min_hits 6 must be at most confirm_window 5"),
    ],
)
def test_bad_gnn_keys_are_located_errors(tmp_path: Path, key: str, value: Any, what: str) -> None:
    frames = random_frames(np.random.default_rng(3), 4)
    doc = scene_doc(frames, gnn_reference.Params())
    doc["tracker"][key] = value
    if key == "min_hits":
        doc["tracker"]["confirm_window"] = 5
    path = tmp_path / "s.json"
    path.write_text(json.dumps(doc, indent=1))
    r = lesmc("track", str(path), "--json")
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert what in r.stderr and f"{path}:" in r.stderr, r.stderr
