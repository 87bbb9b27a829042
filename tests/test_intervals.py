"""Payoff intervals: scenes with payoff_lower, and --payoffs attack|certified|interval
checked against the independent brute force over both payoff sets."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from cli_run import lesmc
from oracle import brute_force
from pipeline_run import design_runs

from lesmc.common.errors import InputError
from lesmc.language.parser import parse_spec
from lesmc.model.lts import to_lts
from lesmc.pipeline.check import bind_scene
from lesmc.scene import load_scene, scene_from_dict
from lesmc.unfold.unfold import build_model

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "tests" / "scenes"


def with_lower(name: str, seed: int) -> dict:
    """A bundled scene with a payoff_lower per detection: the payoff times U(0, 1);
    some unattackable detections get a finite lower bound."""
    doc = json.loads((SCENES / f"{name}.json").read_text())
    rng = np.random.default_rng(seed)
    for fr in doc["frames"]:
        for d in fr["detections"]:
            if d["payoff"] == "unattackable":
                d["payoff_lower"] = float(rng.uniform(0, 5)) if rng.random() < 0.5 else 0.0
            else:
                d["payoff_lower"] = float(d["payoff"]) * float(rng.uniform(0, 1))
    return doc


def test_scene_loader_checks_payoff_lower() -> None:
    doc = with_lower("rq1_platoon", 0)
    scene = scene_from_dict(doc)
    assert scene.has_lower
    bad = json.loads(json.dumps(doc))
    d = bad["frames"][2]["detections"][1]
    d["payoff_lower"] = float(d["payoff"]) + 1
    with pytest.raises(InputError, match=rf"frame 2, detection '{d['id']}': payoff_lower"):
        scene_from_dict(bad, "s.json")
    d["payoff_lower"] = -1
    with pytest.raises(InputError, match="payoff_lower must be a finite number >= 0"):
        scene_from_dict(bad, "s.json")
    d["payoff_lower"] = "unattackable"  # above a finite payoff
    with pytest.raises(InputError, match="exceeds payoff"):
        scene_from_dict(bad, "s.json")
    plain = load_scene(SCENES / "rq1_platoon.json")
    assert not plain.has_lower
    with pytest.raises(InputError, match="payoff_lower is missing"):
        plain.priced("certified")
    # written back, the bounds survive
    from lesmc.scene import scene_to_dict

    again = scene_from_dict(json.loads(json.dumps(scene_to_dict(scene))))
    assert again == scene


def brute(scene, spec_text: str) -> list[float]:
    spec = parse_spec(spec_text, "p.spec")
    out = []
    for bp in bind_scene(scene, [spec]):
        model = build_model(scene, (bp.l, bp.u), bp.end)
        out.append(brute_force(to_lts(model), bp).optimum)
    return out


SPEC = """property robustness {{
    attack window {l}..{u}
    minimize payoff
    subject to dist.sum(0..end) > {c}
    holds if optimum > {theta}
}}
property resilience {{
    attack window {l}..{u}
    minimize dist.max({l}..{u})
    subject to dist.at(end) > 1
    holds if optimum > {theta2}
}}
"""


@pytest.mark.parametrize("name", ["rq1_platoon", "rq2_parallel", "rq4_merge"])
@pytest.mark.parametrize("seed", range(3))
def test_interval_verdicts_match_brute_force_over_both_payoff_sets(
    name: str, seed: int, tmp_path: Path
) -> None:
    doc = with_lower(name, seed)
    scene = scene_from_dict(doc)
    end = scene.last_step - scene.target.step
    l, u = max(1, end - 4), max(1, end - 2)
    base = SPEC.format(l=l, u=u, c=40, theta=0, theta2=0)
    att = brute(scene, base)
    cer = brute(scene.priced("certified"), base)
    for a, c in zip(att, cer, strict=True):
        assert c <= a  # lower payoffs, more hideable detections: never a larger optimum
    # thresholds below, between and above the two optima exercise every verdict
    rng = np.random.default_rng(seed)
    path = tmp_path / "s.json"
    path.write_text(json.dumps(doc))
    seen = set()
    for _ in range(4):
        th = []
        for a, c in zip(att, cer, strict=True):
            lo_, hi_ = (c, a) if math.isfinite(a) else (c, c + 10)
            pick = rng.choice(["below", "between", "above"])
            if not math.isfinite(lo_):
                th.append(1.0)
            elif pick == "below":
                th.append(lo_ - 0.5)
            elif pick == "between" and hi_ > lo_:
                th.append((lo_ + hi_) / 2)
            else:
                th.append(hi_ + 0.5)
        spec = tmp_path / "p.spec"
        spec.write_text(SPEC.format(l=l, u=u, c=40, theta=th[0], theta2=th[1]))
        r = lesmc("check", str(path), str(spec), "--payoffs", "interval", "--json")
        assert "Traceback" not in r.stderr
        doc_out = json.loads(r.stdout)
        verdicts = []
        for res, a, c, t in zip(doc_out["results"], att, cer, th, strict=True):
            expect = "holds" if c > t else "violated" if a <= t else "unknown"
            assert res["verdict"] == expect, (res["property"], a, c, t)
            assert res["payoffs"] == "interval"
            for key, v in (("optimum_certified", c), ("optimum_attack", a)):
                got = res[key]
                assert (got == "inf") if math.isinf(v) else math.isclose(got, v, rel_tol=1e-9)
            if expect == "violated":
                assert res["counterexample"] is not None
                assert math.isclose(res["optimum"], a, rel_tol=1e-9)  # the counterexample's
            elif math.isinf(c) and math.isinf(a):
                assert res["optimum"] == "inf"  # no path violates, under either set
            elif not math.isclose(c, a, rel_tol=1e-12):
                # the optimum lies in [c, a]: never "inf", which means "none violates"
                assert res["optimum"] == "unknown"
                assert math.isclose(res["bounds"]["lower"], c, rel_tol=1e-9)
            elif res["optimum"] != "unknown":  # a point (or c, a one rounding apart)
                assert math.isclose(res["optimum"], a, rel_tol=1e-9)
            verdicts.append(expect)
            seen.add(expect)
        want = 1 if "violated" in verdicts else 3 if "unknown" in verdicts else 0
        assert r.returncode == want
        # the single modes agree with the brute force on their own payoff set
    for mode, truth in (("attack", att), ("certified", cer)):
        spec = tmp_path / "q.spec"
        spec.write_text(base)
        r = lesmc("check", str(path), str(spec), "--payoffs", mode, "--json")
        for res, v in zip(json.loads(r.stdout)["results"], truth, strict=True):
            assert res["payoffs"] == mode
            assert res["verdict"] == ("holds" if v > 0 else "violated")
    assert seen  # at least one verdict was compared


def test_payoffs_refused_without_lower_bounds_or_on_a_model(tmp_path: Path) -> None:
    r = lesmc(
        "check",
        str(SCENES / "rq1_platoon.json"),
        str(SCENES / "rq1_platoon.spec"),
        "--payoffs",
        "interval",
    )
    assert r.returncode == 2 and "payoff_lower is missing" in r.stderr
    assert "Traceback" not in r.stderr
    tiny = ROOT / "tests" / "golden" / "tiny"
    r = lesmc(
        "check", str(tiny / "model.lts"), str(tiny / "properties.spec"), "--payoffs", "certified"
    )
    assert r.returncode == 2 and "needs a scene" in r.stderr


def _payoffs_changed(scene, step: int, i: int):
    """``scene`` with detection i of frame ``step`` priced differently (finite either way)."""
    from dataclasses import replace

    frames = list(scene.frames)
    f = scene.frame(step)
    d = f.detections[i]
    new = 0.37 if not math.isfinite(d.payoff) else d.payoff * 2.5 + 0.11
    dets = list(f.detections)
    dets[i] = replace(d, payoff=new)
    frames[step - scene.frames[0].step] = replace(f, detections=tuple(dets))
    return replace(scene, frames=tuple(frames))


@pytest.mark.parametrize("design", ["single", "joint"])
@pytest.mark.parametrize("name", ["rq1_platoon", "rq2_parallel", "rq4_merge", "rq1_oncoming"])
def test_priced_detections_are_all_a_model_prices(name: str, design: str) -> None:
    """The oracle is a sensitivity sweep: every detection outside the probe's set is priced
    differently in turn, and the model's combined payoffs (Eq. 5) and graph must not move."""
    from lesmc.unfold.probe import priced_detections

    scene = load_scene(SCENES / f"{name}.json").with_tracker(design=design)
    # every payoff finite, as in a certified scene: the most detections a model can price
    finite = scene.with_lower(
        {f.step: np.where(f.payoffs() < np.inf, f.payoffs(), 5.0) for f in scene.frames}
    ).priced("certified")
    end = finite.last_step - finite.target.step
    win = (max(1, end - 4), max(1, end - 2))
    got = priced_detections(finite, win)
    base = build_model(finite, win)
    frames = range(finite.target.step + win[0], finite.target.step + win[1] + 1)
    assert set(got) <= set(frames)
    moved = 0
    for k in range(finite.frames[0].step, finite.last_step + 1):
        for i in range(len(finite.frame(k).detections)):
            other = build_model(_payoffs_changed(finite, k, i), win)
            same = (
                other.n_states == base.n_states
                and np.array_equal(other.dst, base.dst)
                and np.array_equal(other.combined, base.combined)
            )
            if i in got.get(k, ()):
                moved += not same
            else:
                assert same, (k, i)
    assert moved  # the sweep can see a change: some priced detection does move the model


def test_missing_lower_payoffs_count_as_zero() -> None:
    scene = scene_from_dict(with_lower("rq1_platoon", 1))
    f = scene.frames[3]
    low = np.array([np.nan] * len(f.detections))
    part = scene.with_lower({})
    assert part == scene
    # drop the bounds of one frame: those detections get 0 in the certified model
    from dataclasses import replace

    stripped = replace(
        scene,
        frames=tuple(
            replace(g, detections=tuple(replace(d, payoff_lower=None) for d in g.detections))
            if g.step == f.step
            else g
            for g in scene.frames
        ),
    )
    assert stripped.any_lower and not stripped.has_lower
    cert = stripped.priced("certified")
    assert (np.asarray(cert.frame(f.step).payoffs()) == 0).all()
    first = scene.priced("certified").frames[0].payoffs()
    assert (np.asarray(cert.frames[0].payoffs()) == np.asarray(first)).all()
    # with_lower puts bounds back, capped by the payoff; nan leaves a detection as it is
    back = stripped.with_lower({f.step: low})
    assert back == stripped
    vals = np.array([d.payoff_lower for d in scene.frame(f.step).detections], float)
    again = stripped.with_lower({f.step: vals})
    assert again == scene


@pytest.mark.parametrize("design", ["single", "joint"])
def test_a_check_says_when_it_read_detections_without_a_bound(design: str, tmp_path: Path) -> None:
    """Missing bounds count as 0; a certified check that prices one says so, one that prices
    none does not (the frames are chosen by the probe's set, an independent build; the
    joint design also reads payoffs outside the window, which never count)."""
    from lesmc.unfold.probe import priced_detections

    doc = with_lower("rq1_platoon", 2)
    doc["tracker"]["design"] = design
    scene = scene_from_dict(doc)
    end = scene.last_step - scene.target.step
    l, u = max(1, end - 4), max(1, end - 2)
    spec = tmp_path / "p.spec"
    spec.write_text(SPEC.format(l=l, u=u, c=40, theta=0, theta2=0))
    hidden = priced_detections(scene, (l, u))
    step = max(hidden, key=lambda k: len(hidden[k]))  # a frame whose detections a model prices
    quiet = scene.target.step + u + 1  # after the window: read by joint, never priced
    assert quiet not in hidden and quiet <= scene.last_step
    for strip, noted in ((step, True), (quiet, False)):
        bad = json.loads(json.dumps(doc))
        for f in bad["frames"]:
            if f["step"] == strip:
                for d in f["detections"]:
                    del d["payoff_lower"]
        path = tmp_path / f"s{strip}.json"
        path.write_text(json.dumps(bad))
        r = lesmc("check", str(path), str(spec), "--payoffs", "interval", "--json")
        assert "Traceback" not in r.stderr and r.returncode in (0, 1, 3), r.stderr
        notes = [n for res in json.loads(r.stdout)["results"] for n in res["notes"]]
        said = any("carry no certified bound" in n for n in notes)
        assert said == noted, notes


def test_verify_certified_nothing_still_checks() -> None:
    """verify found no detection to certify (nothing hideable): the certified model is read
    as is, not refused for want of bounds."""
    from dataclasses import replace

    scene = load_scene(SCENES / "rq1_platoon.json")
    certified = replace(scene, meta={**scene.meta, "certified": {"detections": 0, "of": 1}})
    spec = parse_spec(SPEC.format(l=1, u=1, c=40, theta=0, theta2=0), "p.spec")
    runs = design_runs(certified, [spec], ["single"], payoffs="interval")
    att = design_runs(scene, [spec], ["single"])
    # independently: the same scene with every payoff written as 0, by brute force
    doc = json.loads((SCENES / "rq1_platoon.json").read_text())
    for f in doc["frames"]:
        for d in f["detections"]:
            d["payoff"] = 0.0
    zero = brute(scene_from_dict(doc), SPEC.format(l=1, u=1, c=40, theta=0, theta2=0))
    for r, a, z in zip(runs[0].results, att[0].results, zero, strict=True):
        assert r.payoffs == "interval"
        assert r.lower <= a.upper
        c = r.optimum_certified
        assert (c is None and math.isinf(z)) or math.isclose(c, z, abs_tol=1e-9)


@pytest.mark.parametrize("design", ["single", "joint"])
def test_a_probe_stopped_by_a_budget_keeps_what_it_read(design: str) -> None:
    """lesmc campaign's probe within a unit's budgets: stopped by --max-states it says so and
    returns part of the full probe's set (what the model read before it stopped)."""
    from lesmc.common.budget import Budget
    from lesmc.pipeline.certify import probe
    from lesmc.unfold.probe import priced_detections

    scene = load_scene(SCENES / "rq4_merge.json").with_tracker(design=design)
    end = scene.last_step - scene.target.step
    win = (max(1, end - 4), end)
    full = priced_detections(scene, win)
    got, complete = probe(scene, win, Budget()).found, probe(scene, win, Budget()).finished
    assert complete and {k: v.tolist() for k, v in got.items()} == {
        k: v.tolist() for k, v in full.items()
    }
    assert sum(map(len, full.values()))
    for budget in (Budget(max_states=1), Budget(check_timeout=0.0)):  # one state; no time
        stopped = probe(scene, win, budget)
        part, complete = stopped.found, stopped.finished
        assert not complete
        for k, v in part.items():
            assert set(v.tolist()) <= set(full.get(k, np.array([])).tolist())
        if design == "single":  # (the joint design reads whole payoff columns up front)
            assert sum(map(len, part.values())) < sum(map(len, full.values()))


def test_a_sweep_over_payoff_sources_is_each_mode_checked_alone(tmp_path: Path) -> None:
    """``--sweep payoffs=attack,certified,interval`` (with an ε sweep): each variant's
    verdict and optimum as ``--payoffs MODE`` with that ε gives; an attack named by an
    algorithm other than the scene's, and certified payoffs of a model file, are refused."""
    scene = tmp_path / "lower.json"
    doc = with_lower("rq1_platoon", 4)
    doc.setdefault("meta", {})["attack"] = {"method": "deepfool"}
    scene.write_text(json.dumps(doc))
    spec = ROOT / "specs" / "robustness.spec"
    swept = lesmc("check", str(scene), str(spec), "--sweep", "payoffs=deepfool,certified,interval",
                  "--sweep", "eps=60,200", "--json")  # fmt: skip
    assert swept.returncode in (0, 1), swept.stderr
    got = {r["property"]: r for r in json.loads(swept.stdout)["results"]}
    assert len(got) == 6
    text = spec.read_text()
    for eps in (60, 200):
        edited = tmp_path / "r.spec"
        edited.write_text(text.replace("> 120", f"> {eps}"))
        assert "> 120" in text
        for source, mode in (("deepfool", "attack"), ("certified", "certified"),
                             ("interval", "interval")):  # fmt: skip
            one = lesmc("check", str(scene), str(edited), "--payoffs", mode, "--json")
            want = json.loads(one.stdout)["results"][0]
            r = got[f"robustness@payoffs={source},eps={eps}"]
            assert (r["status"], r["optimum"], r["payoffs"]) == (
                want["status"], want["optimum"], want["payoffs"]
            )  # fmt: skip
    assert {r["payoffs"] for r in got.values()} == {"attack", "certified", "interval"}
    rep = lesmc("check", str(scene), str(spec), "--sweep", "payoffs=attack,certified",
                "--report", str(tmp_path / "rep"))  # fmt: skip
    assert rep.returncode in (0, 1) and "Traceback" not in rep.stderr  # no ε: no curve
    assert (tmp_path / "rep" / "report.html").is_file()
    pgd = lesmc("check", str(scene), str(spec), "--sweep", "payoffs=pgd")
    assert pgd.returncode == 2 and "made by deepfool (meta.attack.method)" in pgd.stderr
    model = tmp_path / "m.lts"
    assert lesmc("build", str(scene), "--window", "6..8", "-o", str(model)).returncode == 0
    res = lesmc("check", str(model), str(spec), "--sweep", "payoffs=attack,certified")
    assert res.returncode == 2 and "certified payoffs need a scene" in res.stderr
    assert "Traceback" not in res.stderr + pgd.stderr
