"""Injection candidates from the WAMI pipeline and their replay (issue 61).

- the attack towards "vehicle" (perception/attacks.py, ``towards="inject"``) on a linear
  two-logit network, whose smallest flipping perturbation is known in closed form;
- the cheapest way to force an update (tracking/parts/attacker.py ``forcing_update``)
  against a brute force over every hide/inject combination;
- ``lesmc perceive --inject-within`` on the small test video writes candidates (scene
  format 3), ``lesmc check`` with ``allow hide, inject`` finds a cheaper counterexample
  than hiding alone, and ``lesmc replay`` confirms it on the frames;
- bad ``--inject-within`` input is a located error with exit 2.
"""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from cli_run import lesmc
from torch import nn
from wami_video import TARGET, perceive_with_candidates, synth_wami_video

from lesmc.perception.attack_settings import AttackConfig, threshold_logit
from lesmc.perception.attacks import payoffs
from lesmc.tracking.parts.attacker import forcing_update

DELTA = 0.6  # N_dr's acceptance threshold in the linear tests


class Linear(nn.Module):
    """Two logits whose difference is w.x + b: N_dr's margin is linear."""

    def __init__(self, w: torch.Tensor, b: float) -> None:
        super().__init__()
        self.w, self.b = w, b

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        d = (x.flatten(1) * self.w.flatten()).sum(1) + self.b
        return torch.stack([torch.zeros_like(d), d], dim=1)


def _linear(seed: int) -> tuple[Linear, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    w = rng.standard_normal((2, 5, 5)) * 0.1
    x = (0.5 + 0.02 * rng.standard_normal((6, 2, 5, 5))).astype(np.float32)
    return Linear(torch.from_numpy(w.astype(np.float32)), 0.0), w, x


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_inject_attack_is_the_distance_to_the_acceptance_plane(seed: int) -> None:
    net, w, x = _linear(seed)
    t = threshold_logit(DELTA)
    raw = (x.reshape(len(x), -1).astype(np.float64) @ w.ravel()).astype(np.float64)
    # put every window just below the threshold: N_dr rejects them all
    gap = np.linspace(0.05, 0.3, len(x))
    b = float(t - gap.max())  # one bias for all; each window's own margin below
    net.b = b
    margin = raw + b - t
    x = x + ((-gap - margin) / (w.ravel() @ w.ravel()))[:, None, None, None] * w[None]
    x = x.astype(np.float32)
    margin = x.reshape(len(x), -1).astype(np.float64) @ w.ravel() + b - t
    assert (margin < 0).all()
    cfg = AttackConfig()
    got = payoffs(net, x, DELTA, cfg, "inject")
    # the smallest L2 perturbation reaching w.x + b = t is |margin| / ||w||; DeepFool
    # reaches it in one step on a linear margin and scales it by 1 + overshoot
    want = (1 + cfg.overshoot) * np.abs(margin) / np.linalg.norm(w)
    assert got.flipped.all()
    np.testing.assert_allclose(got.payoff, want, rtol=1e-3)
    after = (x + got.perturbation).reshape(len(x), -1).astype(np.float64) @ w.ravel() + b
    assert (after > t).all()  # N_dr now accepts every window (P(vehicle) > delta)
    # hiding them is free: they are not vehicles already
    assert (payoffs(net, x, DELTA, cfg, "hide").payoff == 0).all()


def test_inject_attack_with_pgd_is_an_upper_bound_near_the_distance() -> None:
    net, w, x = _linear(3)
    t = threshold_logit(DELTA)
    net.b = float(t - 0.2 - float(x[0].ravel() @ w.ravel().astype(np.float32)))
    got = payoffs(net, x[:1], DELTA, AttackConfig(method="pgd"), "inject")
    exact = 0.2 / np.linalg.norm(w)
    assert got.flipped[0]
    assert exact * (1 - 1e-6) <= got.payoff[0] <= 1.05 * exact


def _brute_force(
    det_d: np.ndarray,
    det_p: np.ndarray,
    cand_d: np.ndarray,
    cand_p: np.ndarray,
    taken: int,
    candidate: bool,
) -> float:
    """The least cost of any hide/inject combination whose nearest visible measurement is
    ``taken`` (ties: a detection before a candidate, then the lower index)."""
    best = np.inf
    n, c = len(det_d), len(cand_d)
    for hide in itertools.product([False, True], repeat=n):
        for inj in itertools.product([False, True], repeat=c):
            seen = [(det_d[i], 0, i) for i in range(n) if not hide[i]]
            seen += [(cand_d[j], 1, j) for j in range(c) if inj[j]]
            if not seen or min(seen) != (
                (cand_d[taken], 1, taken) if candidate else (det_d[taken], 0, taken)
            ):
                continue
            cost = sum(det_p[i] for i in range(n) if hide[i])
            cost += sum(cand_p[j] for j in range(c) if inj[j])
            best = min(best, cost)
    return float(best)


@pytest.mark.parametrize("seed", range(40))
def test_forcing_update_is_the_cheapest_combination(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n, c = int(rng.integers(0, 5)), int(rng.integers(0, 4))
    det_d = rng.integers(0, 6, n).astype(float)  # small integers: ties happen
    cand_d = rng.integers(0, 6, c).astype(float)
    det_p, cand_p = rng.uniform(0.1, 2, n), rng.uniform(0.1, 2, c)
    for candidate, count in ((False, n), (True, c)):
        for taken in range(count):
            hid, inj = forcing_update(det_d, cand_d, taken, candidate)
            cost = det_p[hid].sum() + cand_p[inj].sum()
            want = _brute_force(det_d, det_p, cand_d, cand_p, taken, candidate)
            assert cost == pytest.approx(want)
            assert list(inj) == ([taken] if candidate else [])


# ---------------------------------------------------------------- the small test video

SPEC = """property robustness {{
    attack window 3..5{allow}
    minimize payoff
    subject to dist.sum(0..end) > 120
    holds if optimum > 3.0
    on x, y
}}
"""


@pytest.fixture(scope="module")
def perceived(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, dict]:
    tmp = tmp_path_factory.mktemp("injectwami")
    video = tmp / "video"
    synth_wami_video(video)
    scene = tmp / "scene.json"
    perceive_with_candidates(video, scene)
    return video, scene, json.loads(scene.read_text())


def test_perceive_writes_priced_candidates_apart_from_the_detections(perceived: tuple) -> None:
    _, _, doc = perceived
    assert doc["version"] == 3
    assert doc["meta"]["candidates"]["within_px"] == 30
    n = 0
    for f in doc["frames"]:
        dets = np.array([[d["x"], d["y"]] for d in f["detections"]], float)
        for c in f.get("candidates", []):
            n += 1
            assert c["id"].startswith(f"{f['step']}:c")
            assert 0 < c["payoff"] < 1e12
            d = np.linalg.norm(dets - [c["x"], c["y"]], axis=1)
            assert d.min() <= 30  # within the radius of a detection
            assert d.min() > 1.0  # not a detection already (the replay's tolerance)
        assert len(f.get("candidates", [])) <= 32
    assert n > 0


def _check(scene: Path, tmp: Path, allow: str, report: Path | None = None) -> dict:
    spec = tmp / f"rob{len(allow)}.spec"
    spec.write_text(SPEC.format(allow=allow))
    args = ["check", str(scene), str(spec), "--design", "single", "--json"]
    if report is not None:
        args += ["--report", str(report)]
    r = lesmc(*args)
    assert r.returncode in (0, 1), r.stderr
    assert "Traceback" not in r.stderr
    out: dict = json.loads(r.stdout)["results"][0]
    return out


def test_injection_counterexample_replays_confirmed(perceived: tuple, tmp_path: Path) -> None:
    video, scene, doc = perceived
    hide = _check(scene, tmp_path, "")
    both = _check(scene, tmp_path, " allow hide, inject", tmp_path / "r")
    # the larger threat model is never dearer
    assert both["optimum"] <= hide["optimum"]
    assert both["optimum"] < hide["optimum"]  # and on this video strictly cheaper
    r = lesmc("replay", str(tmp_path / "r" / "results.json"), "--frames", str(video), "--json")
    assert "Traceback" not in r.stderr
    assert r.returncode == 1, r.stderr  # confirmed: violated
    rep = json.loads(r.stdout)["replays"][0]
    assert rep["verdict"] == "violated"
    assert rep["replay"]["status"] == "confirmed", rep["replay"]["reason"]
    perts = rep["replay"]["perturbations"]
    injected = [p for p in perts if p.get("action") == "inject"]
    assert injected
    cands = {c["id"]: c for f in doc["frames"] for c in f.get("candidates", [])}
    for p in injected:
        # the recomputed attack is the one the scene priced, its perturbation that norm
        assert p["payoff_recomputed"] == pytest.approx(cands[p["obs"]]["payoff"], rel=1e-3)
        assert np.linalg.norm(np.asarray(p["delta"])) == pytest.approx(
            p["payoff_recomputed"], rel=1e-3
        )
    # the attacks replayed cost what the model says
    assert sum(p["payoff_recomputed"] for p in perts) == pytest.approx(both["optimum"], rel=1e-3)
    # the results record the attacker's actions
    res = json.loads((tmp_path / "r" / "results.json").read_text())
    assert res["runs"][0]["properties"][0]["actions"] == ["hide", "inject"]


def test_inject_cap_keeps_the_candidates_nearest_a_detection(
    perceived: tuple, tmp_path: Path
) -> None:
    video, _, doc = perceived
    scene = tmp_path / "capped.json"
    r = lesmc(
        "perceive", str(video), "-o", str(scene), "--inject-within", "30", "--inject-cap", "3",
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    capped = json.loads(scene.read_text())
    assert capped["meta"]["candidates"]["cap_per_frame"] == 3
    wide = {f["step"]: f for f in doc["frames"]}
    for f in capped["frames"]:
        got = f.get("candidates", [])
        assert len(got) <= 3

        def near(c: dict, fr: dict = f) -> float:  # distance to the frame's nearest detection
            return min(np.hypot(d["x"] - c["x"], d["y"] - c["y"]) for d in fr["detections"])

        # the 3 kept are no farther from a detection than any left out (independent sort)
        rest = [c for c in wide[f["step"]].get("candidates", []) if c["id"] not in
                {g["id"] for g in got}]  # fmt: skip
        if got and rest and len(got) == 3:
            assert max(near(c) for c in got) <= min(near(c) for c in rest) + 1e-9


def test_injection_candidates_within_a_smaller_radius_are_fewer(
    perceived: tuple, tmp_path: Path
) -> None:
    video, _, doc = perceived
    scene = tmp_path / "near.json"
    r = lesmc(
        "perceive", str(video), "-o", str(scene), "--target", TARGET,
        "--inject-within", "12",
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    near = json.loads(scene.read_text())
    wide = {c["id"]: c["payoff"] for f in doc["frames"] for c in f.get("candidates", [])}
    got = {c["id"]: c["payoff"] for f in near["frames"] for c in f.get("candidates", [])}
    assert len(got) < len(wide)
    for cid, p in got.items():  # the same candidates, the same prices
        assert wide[cid] == pytest.approx(p, rel=1e-5)  # batch shapes round apart


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--inject-within", "-1", "-o", "{out}"], "--inject-within"),
        (["--inject-within", "nan", "-o", "{out}"], "--inject-within"),
        (["--inject-within", "5"], "--inject-within needs -o"),
        (["--inject-cap", "3", "-o", "{out}"], "--inject-cap"),
        (["--inject-within", "5", "--inject-cap", "0", "-o", "{out}"], "--inject-cap"),
    ],
)
def test_bad_inject_within_is_exit_2(
    perceived: tuple, tmp_path: Path, args: list, needle: str
) -> None:
    video, _, _ = perceived
    out = tmp_path / "s.json"
    r = lesmc("perceive", str(video), *[a.format(out=out) for a in args])
    assert r.returncode == 2, r.stderr
    assert needle in r.stderr
    assert "Traceback" not in r.stderr
    assert not out.exists()


def test_verify_with_candidates_replays_the_injection(perceived: tuple, tmp_path: Path) -> None:
    video, scene, _ = perceived
    spec = tmp_path / "rob.spec"
    spec.write_text(SPEC.format(allow=" allow hide, inject"))
    out = tmp_path / "v"
    r = lesmc(
        "verify", str(video), "--truth", str(video / "truth.json"), "--spec", str(spec),
        "--design", "single", "--out", str(out), "--inject-within", "30",
        "--target", TARGET, "--json",
    )  # fmt: skip
    assert "Traceback" not in r.stderr
    assert r.returncode == 1, r.stderr
    doc = json.loads((out / "results.json").read_text())
    res = doc["runs"][0]["results"][0]
    assert res["verdict"] == "violated"
    assert res["replay"]["status"] == "confirmed", res["replay"]["reason"]
    assert any(p.get("action") == "inject" for p in res["replay"]["perturbations"])
    written = json.loads((out / "scene.json").read_text())
    assert written["version"] == 3 and written["meta"]["candidates"]["within_px"] == 30
    # the scene perceive wrote with the same settings has the same candidates
    same = json.loads(scene.read_text())
    ids = {c["id"] for f in same["frames"] for c in f.get("candidates", [])}
    assert ids == {c["id"] for f in written["frames"] for c in f.get("candidates", [])}


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--inject-cap", "3"], "--inject-cap"),
        (["--scene", "{scene}", "--inject-within", "5"], "--inject-within"),
    ],
)
def test_verify_refuses_candidates_it_cannot_perceive(
    perceived: tuple, tmp_path: Path, args: list, needle: str
) -> None:
    _, scene, _ = perceived
    out = tmp_path / "v"
    r = lesmc("verify", *[a.format(scene=scene) for a in args], "--out", str(out))
    assert r.returncode == 2, r.stderr
    assert needle in r.stderr
    assert "Traceback" not in r.stderr
    assert not (out / "results.json").exists()


def test_an_inject_grid_counterexample_is_not_replayed(perceived: tuple, tmp_path: Path) -> None:
    """An ``inject grid`` property's points are a modelling device, not places on the
    frames: its violation stays "not replayed" (no command offered) and ``lesmc replay``
    skips it instead of failing on a grid point's id (the review of round 20)."""
    video, scene, _ = perceived
    spec = tmp_path / "grid.spec"
    text = SPEC.format(allow=" allow hide, inject").replace(
        "    on x, y\n", "    on x, y\n    inject grid 4 within 8 payoff 0.001\n"
    )
    spec.write_text(text)
    r = lesmc(
        "check", str(scene), str(spec), "--design", "single", "--json",
        "--report", str(tmp_path / "r"),
    )  # fmt: skip
    assert "Traceback" not in r.stderr
    assert r.returncode == 1, r.stderr
    res = json.loads(r.stdout)["results"][0]
    steps = [s for s in res["counterexample"]["steps"] if s.get("obs")]
    assert any("grid" in str(s["obs"]) for s in steps), steps  # the grid is what is cheap
    assert res["replay"] == {"status": "not replayed"}
    doc = json.loads((tmp_path / "r" / "results.json").read_text())
    assert doc["runs"][0]["properties"][0]["inject_grid"] == {
        "spacing": 4.0, "radius": 8.0, "payoff": 0.001,
    }  # fmt: skip
    r = lesmc("replay", str(tmp_path / "r" / "results.json"), "--frames", str(video), "--json")
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr
    assert r.returncode in (0, 1, 2), r.stderr
