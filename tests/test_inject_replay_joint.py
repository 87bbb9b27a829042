"""Replay of ``allow hide, inject`` counterexamples on the ``joint`` design (issue 61, item 4).

On the small test video, with the injection candidates of each frame cut down to the
three nearest the target (so that joint's every-subset options stay few), ``joint``'s
counterexample under ``allow hide, inject`` takes an injected candidate; ``lesmc
replay`` walks its path on the scene, applies the cheapest attack (hide the primary's
nearest detections, inject the candidates), detects the frames again and confirms it.
The same counterexample with the path's candidate replaced by another one diverges
where it was changed. The costs Eq. 5 gives each outcome are checked against the costs
they were made from.
"""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest
from cli_run import lesmc
from wami_video import perceive_with_candidates, synth_wami_video

SPEC = """property robustness {
    attack window 3..5 allow hide, inject
    minimize payoff
    subject to dist.sum(0..end) > 120
    holds if optimum > 3.0
    on x, y
}
"""
TARGET = (206.434, 202.672, 4)
KEEP = 3  # candidates kept per frame


def _near_target(doc: dict) -> dict:
    """The scene with each frame's candidates cut to the KEEP nearest the target, followed
    frame to frame as the detection nearest its previous position (written here, not the
    tracker's), in the scene's own order."""
    at = np.array(TARGET[:2])
    for f in doc["frames"]:
        if f["step"] < TARGET[2]:
            f["candidates"] = []
            continue
        pos = np.array([[d["x"], d["y"]] for d in f["detections"]], float)
        if f["step"] > TARGET[2]:
            at = pos[np.argmin(np.linalg.norm(pos - at, axis=1))]
        cands = f.get("candidates", [])
        near = sorted(cands, key=lambda c: float(np.hypot(c["x"] - at[0], c["y"] - at[1])))
        kept = {c["id"] for c in near[:KEEP]}
        f["candidates"] = [c for c in cands if c["id"] in kept]
    return doc


@pytest.fixture(scope="module")
def checked(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, dict, dict]:
    tmp = tmp_path_factory.mktemp("injectjoint")
    video = tmp / "video"
    synth_wami_video(video)
    full = tmp / "full.json"
    perceive_with_candidates(video, full)
    scene = tmp / "scene.json"
    sdoc = _near_target(json.loads(full.read_text()))
    scene.write_text(json.dumps(sdoc))
    spec = tmp / "rob.spec"
    spec.write_text(SPEC)
    r = lesmc(
        "check", str(scene), str(spec), "--design", "joint", "--json",
        "--report", str(tmp / "r"),
    )  # fmt: skip
    assert "Traceback" not in r.stderr
    assert r.returncode == 1, r.stderr
    res = json.loads(r.stdout)["results"][0]
    return video, tmp / "r" / "results.json", res, sdoc


def test_joint_injection_counterexample_replays_confirmed(checked: tuple) -> None:
    video, results, res, sdoc = checked
    taken = [s["obs"] for s in res["counterexample"]["steps"] if s.get("obs")]
    injected_on_path = [o for o in taken if ":c" in o]
    assert injected_on_path, taken  # the primary takes an injected candidate
    r = lesmc("replay", str(results), "--frames", str(video), "--json")
    assert "Traceback" not in r.stderr
    assert r.returncode == 1, r.stderr  # confirmed: violated
    rep = json.loads(r.stdout)["replays"][0]
    assert rep["verdict"] == "violated"
    assert rep["replay"]["status"] == "confirmed", rep["replay"]["reason"]
    perts = rep["replay"]["perturbations"]
    pay = {d["id"]: d["payoff"] for f in sdoc["frames"] for d in f["detections"]}
    pay |= {c["id"]: c["payoff"] for f in sdoc["frames"] for c in f.get("candidates", [])}
    inj = [p for p in perts if p.get("action") == "inject"]
    assert set(injected_on_path) <= {p["obs"] for p in inj}
    for p in perts:  # every recomputed attack is the one the scene priced
        assert p["payoff_recomputed"] == pytest.approx(pay[p["obs"]], rel=1e-3)
        assert 3 <= p["step"] <= 5  # inside the attack window
    for p in inj:  # the perturbation towards "vehicle" is that norm
        assert np.linalg.norm(np.asarray(p["delta"])) == pytest.approx(
            p["payoff_recomputed"], rel=1e-3
        )
    # the attacks replayed (before any repair) cost what the model says
    assert sum(p["payoff_recomputed"] for p in perts) == pytest.approx(res["optimum"], rel=1e-3)


def test_a_joint_counterexample_with_another_candidate_diverges(checked: tuple) -> None:
    """Constructed: the path's injected candidate replaced by another candidate of its
    frame. The walk along the path loses it there, nothing is injected, and the replayed
    tracker takes something else: diverged at that step."""
    from lesmc.perception.cnn import load_nets
    from lesmc.replay.run import replay
    from lesmc.results.read import results_of
    from lesmc.video.reader import open_frames

    video, results, _, sdoc = checked
    doc = json.loads(results.read_text())
    bad = copy.deepcopy(doc)
    run = bad["runs"][0]
    path = run["paths"][run["roles"]["counterexample"][0] - 1]
    k = next(i for i, o in enumerate(path["obs"]) if o is not None and ":c" in o)
    frame = int(path["obs"][k].split(":")[0])
    others = [
        c["id"]
        for f in sdoc["frames"]
        if f["step"] == frame
        for c in f["candidates"]
        if c["id"] != path["obs"][k]
    ]
    path["obs"][k] = others[0]
    out = replay(results_of(bad), open_frames(str(video), 5), load_nets())
    obj = out.replays[(0, 0)]
    assert obj["status"] == "diverged"
    assert obj["step"] == k + 1  # obs[k] is the measurement entering step k + 1
    assert others[0] in obj["reason"] or "px from the model's" in obj["reason"]


def test_a_joint_injection_replay_without_its_scene_is_refused(checked: tuple) -> None:
    """The walk needs the scene the model was built from: results that name none that
    exists are a usage error (exit 2), before any frame is read."""
    from lesmc.common.errors import UsageError
    from lesmc.replay.run import replay
    from lesmc.results.read import results_of

    _, results, _, _ = checked
    doc = json.loads(results.read_text())
    doc["meta"]["scene"] = str(results.parent / "no-such-scene.json")
    with pytest.raises(UsageError, match=r"meta\.scene"):
        replay(results_of(doc), None, None)  # type: ignore[arg-type]


@pytest.mark.parametrize("seed", range(20))
def test_forcing_costs_invert_the_own_payoffs(seed: int) -> None:
    """Eq. 5: an outcome's cost is the sum of the own payoffs of its source's lower ranks;
    from outcomes made from known costs (sorted per source, own payoff = next cost minus
    this one), the costs come back."""
    from lesmc.replay.joint_forcing import forcing_costs
    from lesmc.tracking.design import Batch, Successors

    rng = np.random.default_rng(seed)
    n_src = int(rng.integers(1, 5))
    src, rank, payoff, want = [], [], [], []
    for s in range(n_src):
        costs = np.sort(np.r_[0.0, rng.uniform(0, 3, int(rng.integers(0, 5)))])
        own = np.r_[np.diff(costs), 0.0]
        src += [s] * len(costs)
        rank += list(range(len(costs)))
        payoff += own.tolist()
        want += costs.tolist()
    order = rng.permutation(len(src))  # any order of the rows
    a = [np.asarray(v)[order] for v in (src, rank, payoff, want)]
    z = np.zeros(len(order))
    succ = Successors(a[0], a[1], a[2], z.astype(int), Batch(z[:, None], z, z.astype(bool)))
    assert forcing_costs(succ) == pytest.approx(a[3])
