"""What a joint counterexample under ``allow hide, inject`` says the attacker does (issue 61,
item 2): on each attacked step the detections hidden and the candidates injected by the
cheapest way to the step's outcome. Checked against tests/joint_oracle.py (filterpy
filters, the greedy likelihood scan, written from the paper, not from lesmc): the listed
hide/inject sets applied to the scene and run through the oracle tracker reproduce the
path's primary estimates step by step, at exactly the path's cost."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from cli_run import lesmc
from inject_scale import cases
from joint_oracle import Joint, Oracle, _warp, oracle_paths
from test_inject_joint import _cases, _spec
from test_inject_single import _cases as _single_cases

import lesmc.unfold.unfold as unfold
from lesmc import api
from lesmc.model.arrays import ArrayModel
from lesmc.pipeline.check import run
from lesmc.pipeline.job import Job
from lesmc.results.document import run_json
from lesmc.scene import Scene, scene_from_dict
from lesmc.tracking.trackers import make_tracker


class Applied(Oracle):
    """The oracle tracker on a frame whose listed detections are hidden and listed
    candidates injected (they join after the detections, in their order)."""

    def apply(self, st: Joint, frame_step: int, hidden: list[str], injected: list[str]) -> Joint:
        Hm = self.scene.frame(frame_step - 1).to_next
        preds = []
        for x, P in st.tracks:
            x = x.copy()
            x[:2] = _warp(Hm, x[:2])
            kf = self._kf(x, P)
            kf.predict()
            preds.append(kf)
        pending = np.array([_warp(Hm, p) for p in st.pending]).reshape(-1, 2)
        frame = self.scene.frame(frame_step)
        ids = [d.id for d in frame.detections] + [c.id for c in frame.candidates]
        C = np.array([[c.x, c.y] for c in frame.candidates]).reshape(-1, 2)
        ZC = np.vstack([frame.positions().reshape(-1, 2), C])
        n = len(frame.detections)
        off = {ids.index(h) for h in hidden}
        off |= {i for i in range(n, len(ids)) if ids[i] not in injected}
        return self._step(preds, pending, ZC, off)


def cost_of(scene: Scene, frame_step: int, hidden: list[str], injected: list[str]) -> float:
    """What hiding and injecting the listed ones costs, from the scene's payoffs."""
    frame = scene.frame(frame_step)
    pay = {d.id: d.payoff for d in (*frame.detections, *frame.candidates)}
    return float(sum(pay[i] for i in (*hidden, *injected)))


def model_paths(cm: ArrayModel) -> list[list[int]]:
    """Every root-to-leaf path of the model as its transitions."""
    out: list[list[int]] = []
    todo: list[tuple[int, list[int]]] = [(0, [])]
    while todo:
        q, ts = todo.pop()
        lo, hi = int(cm.ptr[q]), int(cm.ptr[q + 1])
        if lo == hi:
            out.append(ts)
        todo.extend((int(cm.dst[t]), [*ts, t]) for t in range(lo, hi))
    return out


def test_listed_attacks_reproduce_every_joint_path_through_the_oracle() -> None:
    """On random joint scenes with candidates, every path of the model under hide +
    inject: the hidden and injected ids ``attack_of`` lists, applied through the oracle,
    give the path's primary estimates and halts, and cost the path's combined payoffs."""
    checked = injected = hidden_n = 0
    for scene, window in _cases(cases(12, 60), 610):
        cm = unfold.build_model(scene, window, inject=True)
        of = unfold.attack_of(scene, cm)
        assert of is not None
        oracle = Applied(scene)
        src = np.repeat(np.arange(len(cm.ptr) - 1), np.diff(cm.ptr))
        for path in model_paths(cm)[:40]:
            st = oracle.initial()
            for k, t in enumerate(path, start=1):
                step = scene.target.step + k
                q = int(src[t])
                if window[0] <= k <= window[1]:
                    hid, inj = of(q, k, int(cm.rank[t]))
                    lo, hi = int(cm.ptr[q]), int(cm.ptr[q + 1])
                    own = sum(float(cm.payoff[s]) for s in range(lo, hi) if cm.rank[s] < cm.rank[t])
                    assert cost_of(scene, step, hid, inj) == pytest.approx(own)
                    st = oracle.apply(st, step, hid, inj)
                    injected += len(inj)
                    hidden_n += len(hid)
                else:
                    st = oracle.options(st, step, False)[0][1]
                got = st.tracks[0][0]
                assert np.allclose(got, cm.S[int(cm.dst[t])], rtol=1e-7, atol=1e-6), (k, window)
                assert st.halted == bool(cm.halted[int(cm.dst[t])])
            checked += 1
    assert checked and injected and hidden_n  # both actions were listed somewhere


def test_the_results_document_lists_a_joint_counterexamples_attack() -> None:
    """The results document of a joint check under hide + inject (lesmc check --report's
    results.json, built in process): the violated property's ``hidden`` and ``injected``
    lists, applied through the oracle, move the track beyond the bound at exactly the
    optimum's cost (before, the lists were empty and a note said they were not derived)."""
    done = 0
    for scene, window in _cases(30, 620, max_trace=1e12):
        end = unfold.original_end(scene, make_tracker(scene))
        original = oracle_paths(scene, (end + 1, end + 1), end)[0][0]
        spec = api.parse_spec(_spec(window, end, 1e-3, " allow hide, inject"))
        res = run(Job((spec,), scene=scene, full_models=True))
        (r,) = res.results
        if r.verdict != "violated" or not float(r.optimum or 0) > 0:
            continue  # no attack needed or none possible: nothing listed to check
        assert not any("does not yet say" in n for n in r.notes)
        doc = run_json(res.runs[0])
        steps: dict[int, tuple[list[str], list[str]]] = {}
        for key, i in (("hidden", 0), ("injected", 1)):
            for item in doc[key]["p"]:
                steps.setdefault(item["step"], ([], []))[i].append(item["obs"])
                if key == "injected":
                    c = next(
                        c for c in scene.frame(item["frame"]).candidates if c.id == item["obs"]
                    )
                    assert (item["x"], item["y"], item["payoff"]) == (c.x, c.y, c.payoff)
        assert steps  # an attack of positive cost hides or injects something
        oracle = Applied(scene)
        st, cost, xs = oracle.initial(), 0.0, []
        xs.append(st.tracks[0][0][:2])
        for k in range(1, end + 1):
            if st.halted:
                break
            step = scene.target.step + k
            hid, inj = steps.get(k, ([], []))
            cost += cost_of(scene, step, hid, inj)
            st = oracle.apply(st, step, hid, inj)
            xs.append(st.tracks[0][0][:2])
        dev = max(math.dist(a, b[:2]) for a, b in zip(xs, original, strict=False))
        assert dev > 1e-3
        assert cost == pytest.approx(float(r.optimum), abs=1e-9)
        done += 1
        if done == 3:
            break
    assert done


def test_single_lists_the_candidate_it_injects() -> None:
    """On single the ``injected`` list names the candidate the cheapest attack injects
    (1:1, 3 px below the prediction (10, 0), cheaper than hiding 1:0), with its payoff and
    position; ``hidden`` is empty."""
    doc = _single_cases(1, 1)[0]["doc"]  # its tracker and target: prediction (10, 0)
    doc |= {
        "frames": [
            {"step": 0, "detections": []},
            {
                "step": 1,
                "detections": [{"id": "1:0", "x": 10.0, "y": 6.0, "payoff": 5.0}],
                "candidates": [{"id": "1:1", "x": 10.0, "y": -3.0, "payoff": 1.0}],
            },
            {"step": 2, "detections": [{"id": "2:0", "x": 20.0, "y": 0.0, "payoff": 5.0}]},
        ],
    }
    spec = api.parse_spec(
        "property p { attack window 1..1 allow hide, inject end 2 minimize payoff "
        "subject to dist.max(0..end) > 3 holds if optimum > 10 }\n"
    )
    res = run(Job((spec,), scene=scene_from_dict(doc), full_models=True))
    assert float(res.results[0].optimum) == pytest.approx(1.0)
    got = run_json(res.runs[0])
    assert got["hidden"]["p"] == []
    assert [(i["step"], i["obs"], i["payoff"], i["x"], i["y"]) for i in got["injected"]["p"]] == [
        (1, "1:1", 1.0, 10.0, -3.0)
    ]


def test_too_many_candidates_for_joint_is_a_budget_stop_not_a_blow_up(tmp_path: Path) -> None:
    """A frame with 21 injection candidates would make the joint design build 2^21
    subsets per state (the default video offers 100-175 a frame): ``lesmc check`` stops
    with exit status 3 and says so, before listing any (it used to grow without bound)."""
    import dataclasses

    from lesmc.scene import Detection

    scene, window = _cases(1, 610)[0]
    frames = []
    for f in scene.frames:
        extra = tuple(Detection(f"{f.step}:x{i}", 400.0 + 7 * i, 300.0, 1.0) for i in range(21))
        frames.append(dataclasses.replace(f, candidates=f.candidates + extra))
    path, spec = tmp_path / "s.json", tmp_path / "p.spec"
    api.save_scene(dataclasses.replace(scene, frames=tuple(frames)), path)
    end = unfold.original_end(scene, make_tracker(scene))
    spec.write_text(_spec(window, end, 1.0, " allow hide, inject"))
    r = lesmc("check", str(path), str(spec), timeout=120)
    assert r.returncode == 3, r.stderr
    assert "subsets of the frame's injection candidates" in r.stderr
    assert "Traceback" not in r.stderr
