"""Trackers declared by their matrices (issue 26): Stone Soup as the oracle of the tracks,
an independent brute force for the optima, and every bad input through the real CLI."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("stonesoup")

from cli_run import lesmc
from filterpy.common import Q_continuous_white_noise
from oracle import brute_force
from stonesoup_oracle import oracle_track, random_model, simulated_scene

from lesmc.api import build
from lesmc.engines.check import bind_all, check
from lesmc.language.parser import parse_spec
from lesmc.model.lts import to_lts
from lesmc.scene import TrackerConfig, scene_from_dict
from lesmc.tracking.kalman import matrices
from lesmc.tracking.monitor import track
from lesmc.tracking.trackers import make_tracker

KINDS = ("cv2d", "ca2d", "random")


def _close(got: np.ndarray, want: np.ndarray) -> bool:
    """Equal to 1e-9 relative (of the largest entry)."""
    scale = max(float(np.abs(want).max(initial=0.0)), 1e-300)
    return bool(np.allclose(got, want, rtol=1e-9, atol=1e-9 * scale))


def _compare(scene_doc: dict[str, Any]) -> bool:
    """lesmc's unattacked track against Stone Soup's; False when a gate decision was too
    close to call (nothing compared)."""
    want = oracle_track(scene_doc, scene_doc["tracker"])
    if any(p.borderline for p in want):
        return False
    got = track(make_tracker(scene_from_dict(scene_doc)))
    assert len(got) == len(want)
    for g, w in zip(got, want, strict=True):
        assert g.obs == w.obs, (g.step, g.obs, w.obs)
        assert g.halted == w.halted
        assert _close(g.x, w.x), (g.step, g.x, w.x)
        assert _close(g.P, w.P), g.step
    return True


def test_tracks_equal_stone_soup_on_300_random_scenes_and_models() -> None:
    """cv2d, ca2d and random stable models (random SPD Q, R, P0, random measured components):
    every step's estimate, covariance, observation and halt as Stone Soup's."""
    compared = 0
    updates = 0
    for seed in range(330):
        rng = np.random.default_rng(seed)
        doc = simulated_scene(rng, random_model(rng, KINDS[seed % 3]))
        if _compare(doc):
            compared += 1
            updates += sum(p.obs is not None for p in oracle_track(doc, doc["tracker"]))
    assert compared >= 300
    assert updates >= 300  # the scenes exercise updates, not only predictions


def _write_tracker(tmp_path: Path, tracker: dict[str, Any], name: str) -> Path:
    path = tmp_path / name
    if name.endswith(".json"):
        path.write_text(json.dumps(tracker))
    else:  # TOML: the model's matrices as arrays of arrays
        m = tracker["model"]
        lines = [f'design = "{tracker["design"]}"', f"gate = {tracker['gate']!r}"]
        lines += [f'gate_type = "{tracker["gate_type"]}"', f"max_trace = {tracker['max_trace']!r}"]
        lines += ["[model]", f"state = {json.dumps(m['state'])}"]
        lines += [f"{k} = {json.dumps(m[k])}" for k in ("F", "H", "Q", "R", "P0")]
        path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize("name", ["tracker.json", "tracker.toml"])
def test_lesmc_track_writes_stone_soups_track(tmp_path: Path, name: str) -> None:
    """``lesmc track SCENE --tracker FILE --json`` (the real CLI) against Stone Soup."""
    for seed in (3, 4, 5):
        rng = np.random.default_rng(1000 + seed)
        tracker = random_model(rng, KINDS[seed % 3])
        doc = simulated_scene(rng, tracker)
        scene_file = tmp_path / "scene.json"
        plain = {k: v for k, v in doc.items() if k != "tracker"}
        scene_file.write_text(json.dumps(plain))
        tfile = _write_tracker(tmp_path, tracker, name)
        r = lesmc("track", str(scene_file), "--tracker", str(tfile), "--json")
        assert r.returncode == 0, r.stderr
        want = oracle_track(doc, tracker)
        got = json.loads(r.stdout)["track"]
        assert [g["obs"] for g in got] == [w.obs for w in want]
        for g, w in zip(got, want, strict=True):
            assert _close(np.array(g["s"]), w.x)


def test_presets_expand_to_the_textbook_matrices() -> None:
    """cv2d is Eq. 16-18; ca2d's Q is filterpy's continuous white-noise jerk."""
    cfg = TrackerConfig(model="ca2d", P0_sd=(1.0, 2.0, 3.0, 4.0, 5.0, 6.0), sigma_q=2.5)
    m = matrices(cfg, 0.4)
    want_q = Q_continuous_white_noise(dim=3, dt=0.4, spectral_density=6.25, block_size=2)
    # filterpy orders by dimension (x, vx, ax, y, vy, ay); lesmc by derivative
    order = [0, 3, 1, 4, 2, 5]
    assert np.allclose(m.Q, want_q[np.ix_(order, order)], rtol=1e-12, atol=0)
    f = np.array([[1, 0.4, 0.08], [0, 1, 0.4], [0, 0, 1]])
    assert np.allclose(m.F, np.kron(f, np.eye(2)))
    assert m.state == ("x", "y", "vx", "vy", "ax", "ay") and m.pos == (0, 1)
    assert np.allclose(m.P0, np.diag(np.square([1.0, 2, 3, 4, 5, 6])))
    paper = matrices(TrackerConfig(), 1.0)
    assert np.array_equal(paper.F[:2, 2:], np.eye(2)) and paper.state == ("x", "y", "vx", "vy")


SPEC = """
property robust {
    attack window 1..3
    minimize payoff
    subject to dist.at(end) > %(eps)s
    holds if optimum > 2
    on x, y
}
property resilient {
    attack window 1..3
    minimize dist.max(1..3)
    subject to dist.at(end) > %(eps)s
    holds if optimum > 5
    on x, y
}
"""


def test_optima_on_declared_models_equal_brute_force() -> None:
    """At least 100 built models of declared trackers (single and joint designs): every
    engine optimum equals the brute force over the model's paths."""
    models = checked = violated = 0
    for seed in range(140):
        rng = np.random.default_rng(5000 + seed)
        tracker = random_model(rng, KINDS[seed % 3])
        tracker["design"] = "joint" if seed % 4 == 3 else "single"
        tracker["max_trace"] = 1e30  # the unattacked track must reach step 4
        doc = simulated_scene(rng, tracker)
        doc["frames"] = doc["frames"][:6] if len(doc["frames"]) >= 5 else doc["frames"]
        if len(doc["frames"]) < 5:
            continue
        sc = scene_from_dict(doc)
        model = build(sc, (1, 3), 4)
        spec = parse_spec(SPEC % {"eps": float(rng.uniform(0.5, 20.0))})
        lts = to_lts(model)
        models += 1
        for bp, got in zip(bind_all(model, [spec]), check(model, [spec]), strict=True):
            want = brute_force(lts, bp).optimum
            if math.isinf(want):
                assert got.optimum == math.inf
            else:
                assert got.optimum is not None
                assert math.isclose(got.optimum, want, rel_tol=1e-12, abs_tol=1e-12)
                violated += 1
            checked += 1
    assert models >= 100 and checked == 2 * models and violated >= 50


# ---------------------------------------------------------------- bad input, real CLI

GOOD = {
    "state": ["x", "y", "vx", "vy"],
    "F": [[1, 0, 1, 0], [0, 1, 0, 1], [0, 0, 1, 0], [0, 0, 0, 1]],
    "H": [[1, 0, 0, 0], [0, 1, 0, 0]],
    "Q": np.eye(4).tolist(),
    "R": (np.eye(2) * 25).tolist(),
    "P0": (np.eye(4) * 100).tolist(),
}


def _bad(**change: Any) -> dict[str, Any]:
    model = {**GOOD, **change}
    return {"model": model}


BAD = [
    (
        _bad(F=[[1, 0, 1, 0], [0, 1, 0, 1], [0, 0, 1, 0]]),
        "model.F must be a 4x4 matrix (the state has 4 components)",
        "got 3 rows",
    ),
    (_bad(H=[[1, 0, 0], [0, 1, 0]]), "model.H row 0 must have 4 entries", "got 3"),
    (_bad(Q=[[1, 2, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]), "model.Q", "symmetric"),
    (_bad(R=[[1, 0], [0, -1]]), "model.R must be positive definite", "eigenvalue"),
    (_bad(P0=np.zeros((4, 4)).tolist()), "model.P0 must be positive definite", ""),
    (_bad(Q=(-np.eye(4)).tolist()), "model.Q must be positive semi-definite", ""),
    (_bad(H=[[1, 0, 0, 0], [1, 0, 0, 0]]), "measures fewer than two components", "'x'"),
    (_bad(H=[[2, 0, 0, 0], [0, 1, 0, 0]]), "model.H row 0", "single 1"),
    (_bad(state=["x", "y", "vx", "x"]), "names component 'x' twice", ""),
    ({"model": GOOD, "sigma_q": 3.0}, "sigma_q does not apply", ""),
    ({"model": "cv3d"}, 'model must be "cv2d" or "ca2d"', ""),
    ({"model": "ca2d", "P0_sd": [1, 2, 3, 4]}, 'P0_sd must have 6 entries for model "ca2d"', ""),
]


@pytest.mark.parametrize(("tracker", "want", "also"), BAD)
def test_a_bad_tracker_file_is_refused_with_what_is_wrong(
    tmp_path: Path, tracker: dict[str, Any], want: str, also: str
) -> None:
    tfile = tmp_path / "t.json"
    tfile.write_text(json.dumps(tracker))
    out = tmp_path / "m.lts"
    r = lesmc(
        "build", "examples/merge.json", "--window", "6..8", "--tracker", str(tfile), "-o", str(out)
    )
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr
    assert want in r.stderr and also in r.stderr, r.stderr
    assert str(tfile) in r.stderr
    assert not out.exists()


def test_a_bad_model_in_a_scene_names_the_scene(tmp_path: Path) -> None:
    doc = json.loads(Path("examples/merge.json").read_text())
    doc["tracker"]["model"] = {**GOOD, "R": [[1, 1e13], [0, 1]]}
    path = tmp_path / "s.json"
    path.write_text(json.dumps(doc))
    r = lesmc("track", str(path))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    text = path.read_text()
    col = text.index(json.dumps(1e13)) + 1  # the entry, on the file's one line
    assert f"{path}:1:{col}: tracker: model.R[0][1] must be a finite number" in r.stderr


def test_toml_syntax_errors_are_located(tmp_path: Path) -> None:
    tfile = tmp_path / "t.toml"
    tfile.write_text('model = "ca2d"\ngate = = 2\n')
    r = lesmc("track", "examples/merge.json", "--tracker", str(tfile))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert f"{tfile}:2:" in r.stderr


def test_toml_nan_is_refused(tmp_path: Path) -> None:
    tfile = tmp_path / "t.toml"
    tfile.write_text("gate = nan\n")
    r = lesmc("track", "examples/merge.json", "--tracker", str(tfile))
    assert r.returncode == 2 and "gate must be a number" in r.stderr


def test_a_spec_naming_a_component_the_state_lacks(tmp_path: Path) -> None:
    tracker = {"model": {**GOOD, "state": ["px", "py", "vx", "vy"]}}
    tfile = tmp_path / "t.json"
    tfile.write_text(json.dumps(tracker))
    r = lesmc("check", "examples/merge.json", "specs/robustness.spec", "--tracker", str(tfile))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "specs/robustness.spec:9:" in r.stderr and "'x'" in r.stderr, r.stderr


def test_a_velocity_without_vx_vy_is_refused(tmp_path: Path) -> None:
    doc = json.loads(Path("examples/merge.json").read_text())
    doc["target"]["velocity"] = [3.0, 1.0]
    doc["tracker"] = {"model": {**GOOD, "state": ["x", "y", "u", "v"]}}
    path = tmp_path / "s.json"
    path.write_text(json.dumps(doc))
    r = lesmc("track", str(path))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "needs state components named vx and vy" in r.stderr


def test_the_declared_twin_of_a_preset_gives_the_same_verdicts(tmp_path: Path) -> None:
    """examples/trackers/ca6.json declares the ca2d preset's matrices (sigma_q = 2,
    sigma_r = 4): checking with either gives the same table."""
    preset = tmp_path / "ca.toml"
    preset.write_text(
        'model = "ca2d"\nsigma_q = 2.0\nsigma_r = 4.0\n'
        "P0_sd = [30.0, 30.0, 20.0, 20.0, 10.0, 10.0]\n"
    )
    runs = []
    for t in (str(preset), "examples/trackers/ca6.json"):
        r = lesmc("check", "examples/merge.json", "examples/merge.spec", "--tracker", t, "--json")
        assert r.returncode in (0, 1), r.stderr
        doc = json.loads(r.stdout)
        runs.append([(x["property"], x["status"], x["optimum"]) for x in doc["results"]])
    assert runs[0] == runs[1]
