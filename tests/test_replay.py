"""Replaying counterexamples through the real detector and tracker (lesmc/replay.py, issue 14).

One small synthetic video (768x768, 16 frames, seed 4) is verified once (plain
tracker, window 3..5); the tests replay its counterexamples, break one on
purpose, and check the results file, the replay JSON and the report.
"""

from __future__ import annotations

import copy
import json
import math
import subprocess
from pathlib import Path

import numpy as np
import pytest
from cli_run import lesmc
from hypothesis import given, settings
from hypothesis import strategies as st
from wami_video import synth_wami_video

from lesmc.results.read import results_of

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def verified(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, dict]:
    tmp = tmp_path_factory.mktemp("replay")
    video = tmp / "video"
    synth_wami_video(video)
    out = tmp / "v"
    r = lesmc(
        "verify", str(video), "--truth", str(video / "truth.json"), "--window", "3..5",
        "--design", "single", "--out", str(out), "--json",
    )  # fmt: skip
    assert r.returncode in (0, 1, 3), r.stderr
    assert "Traceback" not in r.stderr
    return video, out, json.loads((out / "results.json").read_text())


def test_verify_records_a_replay_for_every_violated_property(verified: tuple) -> None:
    import jsonschema

    from lesmc.schemas import schema

    _, _, doc = verified
    jsonschema.validate(doc, schema("results"))
    assert doc["perception"]["payoffs"] == "attack"
    replayed = [r for run in doc["runs"] for r in run["results"] if "replay" in r]
    assert replayed, "the plain tracker is violated on this video: something to replay"
    for r in replayed:
        rp = r["replay"]
        # a diverged counterexample is no proof: "violated" only when its replayed run
        # violates the property all the same (docs/semantics.md, "Violated on the frames")
        on = rp.get("on_frames") or {}
        assert (rp["status"] == "confirmed" or on.get("violated")) == (r["verdict"] == "violated")
        if rp["status"] == "diverged":
            assert rp["step"] is not None and rp["reason"]
            assert any(
                ("not a proof of violation" if r["verdict"] == "unknown" else on["why"]) in n
                for n in r["notes"]
            )
        else:
            assert rp["step"] is None and rp["max_error_px"] <= rp["tolerance_px"]["track"]
        for p in rp["perturbations"]:
            # the same attack recomputed: the payoff the model used
            assert abs(p["payoff_recomputed"] - p["payoff"]) <= 1e-3 * p["payoff"]
            assert np.asarray(p["delta"]).shape == (4, 21, 21)
            # the recorded perturbation's norm is the payoff (independent recomputation)
            assert np.linalg.norm(np.asarray(p["delta"])) == pytest.approx(p["payoff"], rel=1e-3)
    assert any(r["replay"]["status"] == "confirmed" for r in replayed)


def test_replay_verb_agrees_with_verify_and_validates(verified: tuple) -> None:
    import jsonschema

    from lesmc.schemas import schema

    video, out, doc = verified
    r = lesmc("replay", str(out / "results.json"), "--frames", str(video), "--json")
    assert "Traceback" not in r.stderr
    rep = json.loads(r.stdout)
    jsonschema.validate(rep, schema("replay"))
    got = {(x["design"], x["property"]): x["replay"]["status"] for x in rep["replays"]}
    want = {
        (run["design"], res["property"]): res["replay"]["status"]
        for run in doc["runs"]
        for res in run["results"]
        if "replay" in res
    }
    assert got == want
    confirmed = any(s == "confirmed" for s in got.values())
    assert r.returncode == (1 if confirmed else 3)


def test_replay_of_the_attacked_frames_alone_equals_a_pass_over_every_frame(
    verified: tuple,
) -> None:
    """``replay(..., clean=...)`` (what verify does with its own perception: only the
    attacked frames, each run of them after the 4 frames the front end needs, go through
    the detector) gives the same replay objects as the pass over every frame."""
    from lesmc.perception.attack_settings import AttackConfig
    from lesmc.perception.cnn import load_nets
    from lesmc.perception.run import PerceiveOptions, perceive
    from lesmc.replay.run import replay
    from lesmc.video.reader import open_frames

    video, _, doc = verified
    frames, nets = open_frames(str(video), 5), load_nets()
    run = perceive(frames, PerceiveOptions(history=4, nets=nets, attack=AttackConfig()))
    full = replay(results_of(doc), frames, nets)
    clean = {fd.index: fd for fd in run.detections}
    sparse = replay(results_of(doc), frames, nets, clean=clean)
    assert full.replays and sparse.replays == full.replays
    # and with the perception's registrations: no frame described again, the same replays
    import lesmc.perception.frontend as fe_module

    described: list[int] = []
    real = fe_module.describe

    def counting(*args: object) -> object:
        described.append(1)
        return real(*args)  # type: ignore[arg-type]

    fe_module.describe = counting  # type: ignore[assignment]
    try:
        known = replay(results_of(doc), frames, nets, clean=clean, registrations=run.registrations)
    finally:
        fe_module.describe = real
    assert known.replays == full.replays
    assert not described


def test_cases_that_hide_the_same_detections_share_one_attack(verified: tuple) -> None:
    """Two design runs with the same counterexamples (as single and joint often have):
    each frame's attack runs once per distinct group of hidden detections, and each
    case's replay is the one it gets alone."""
    import copy

    import lesmc.replay.run as replay_module
    from lesmc.perception.cnn import load_nets
    from lesmc.video.reader import open_frames

    video, _, doc = verified
    frames, nets = open_frames(str(video), 5), load_nets()
    calls: list[int] = []
    real = replay_module.attack_frame

    def counting(*args: object, **kwargs: object) -> object:
        calls.append(1)
        return real(*args, **kwargs)  # type: ignore[arg-type]

    replay_module.attack_frame = counting  # type: ignore[assignment]
    try:
        alone = replay_module.replay(results_of(doc), frames, nets)
        once = len(calls)
        twice = copy.deepcopy(doc)
        twice["runs"].append(copy.deepcopy(doc["runs"][0]))
        both = replay_module.replay(results_of(twice), frames, nets)
    finally:
        replay_module.attack_frame = real
    assert once and len(calls) == 2 * once  # not 3x: the copy's attacks were shared
    assert alone.replays
    for (i, j), obj in alone.replays.items():
        assert both.replays[(i, j)] == obj
        assert both.replays[(len(doc["runs"]), j)] == obj


def test_a_counterexample_that_the_tracker_does_not_follow_is_diverged(verified: tuple) -> None:
    """Constructed: the counterexample's recorded track is moved by 5 px from step 2 on; the
    replay must stop at step 2 and say the position differs."""
    from lesmc.perception.cnn import load_nets
    from lesmc.replay.run import apply, replay
    from lesmc.video.reader import open_frames

    video, _, doc = verified
    bad = copy.deepcopy(doc)
    run = bad["runs"][0]
    j = next(
        i for i, r in enumerate(run["results"]) if r.get("replay", {}).get("status") == "confirmed"
    )
    prop = run["results"][j]["property"]
    path = run["paths"][run["roles"]["counterexample"][j] - 1]
    for q in path["states"][2:]:
        run["states"][q]["s"][0] += 5.0
    run["results"][j]["verdict"] = "violated"
    out = replay(results_of(bad), open_frames(str(video), 5), load_nets(), prop)
    obj = out.replays[(0, j)]
    assert obj["status"] == "diverged" and obj["step"] == 2
    assert "px from the model's" in obj["reason"]
    apply(bad, out)
    # the replayed run is the confirmed attack's: violated on the frames when the replay
    # judges the property (tests/test_replay_property.py), else unknown
    on = obj["on_frames"]
    assert run["results"][j]["verdict"] == ("violated" if on["violated"] else "unknown")


def test_without_repair_interacting_perturbations_diverge_where_they_act(verified: tuple) -> None:
    """On this video hiding a detection changes its neighbours (a blob no longer crowded is
    output at its own centroid, an overlapping window loses or gains detections): without
    the repaired joint attack some counterexample diverges at an attacked step, and the
    reason names the frame's detections."""
    from lesmc.perception.cnn import load_nets
    from lesmc.replay.run import replay
    from lesmc.video.reader import open_frames

    video, _, doc = verified
    out = replay(results_of(doc), open_frames(str(video), 5), load_nets(), repair=False)
    diverged = [o for o in out.replays.values() if o["status"] == "diverged"]
    assert diverged
    for o in diverged:
        steps = {p["step"] for p in o["perturbations"]}
        assert o["step"] >= min(steps)
        assert "detection" in o["reason"]


def test_perturbations_of_one_frame_add_up_where_windows_overlap() -> None:
    from lesmc.replay.perturbed import perturb

    frame = np.full((40, 40), 100.0)
    stack = [frame.copy() for _ in range(4)]
    d = np.zeros((2, 4, 21, 21))
    d[:, -1] = 0.1  # +25.5 grey levels over each window of the current frame
    out = perturb(stack, [(np.array([[15.0, 15.0], [20.0, 15.0]]), d)], 21).frames
    cur = out[-1]
    assert cur[15, 7] == pytest.approx(125.5)  # first window only
    assert cur[15, 15] == pytest.approx(151.0)  # both windows
    assert cur[15, 29] == pytest.approx(125.5)  # second window only
    assert cur[0, 39] == 100.0 and np.array_equal(out[0], frame)
    big = perturb(stack, [(np.array([[15.0, 15.0]]), np.ones((1, 4, 21, 21)))], 21).frames
    assert big[-1].max() == 255.0  # clipped to the pixel range


def test_report_shows_the_patches_and_the_replay(verified: tuple, tmp_path: Path) -> None:
    video, out, _ = verified
    r = lesmc("report", str(out / "results.json"), "--out", str(tmp_path / "r"), "--frames",
              str(video))  # fmt: skip
    assert r.returncode == 0, r.stderr
    html = (tmp_path / "r/report.html").read_text()
    assert "perturbation" in html and "Replay of the counterexamples" in html
    assert (tmp_path / "r/figures/single-perturbations.png").is_file()
    assert "tightness" in html


def test_replay_needs_frames_and_a_results_file(verified: tuple, tmp_path: Path) -> None:
    """The frames default to those the results file names; without them, --frames."""
    _, out, doc = verified
    assert doc["perception"]["frames"]
    unnamed = copy.deepcopy(doc)
    del unnamed["perception"]["frames"]
    (tmp_path / "results.json").write_text(json.dumps(unnamed))
    r = lesmc("replay", str(tmp_path / "results.json"))
    assert r.returncode == 2 and "--frames" in r.stderr and "Traceback" not in r.stderr
    r = lesmc("replay", str(out / "results.json"), "--frames", str(tmp_path), "--property", "nope")
    assert r.returncode == 2 and "nope" in r.stderr


def test_verify_in_interval_mode_certifies_what_its_models_can_hide(
    verified: tuple, tmp_path: Path
) -> None:
    """``--payoffs interval`` on a video: only the detections the models can hide are
    certified, every hidden one among them; verdicts follow both optima (docs/semantics.md);
    the written scene gives `lesmc check` the same certified optima."""
    import jsonschema

    from lesmc.schemas import schema

    video, _, att = verified
    out = tmp_path / "vi"
    r = lesmc(
        "verify", str(video), "--truth", str(video / "truth.json"), "--window", "3..5",
        "--design", "single", "--out", str(out), "--payoffs", "interval", "--json",
    )  # fmt: skip
    assert "Traceback" not in r.stderr and r.returncode in (0, 1, 3), r.stderr
    doc = json.loads((out / "results.json").read_text())
    jsonschema.validate(doc, schema("results"))
    cert = doc["perception"]["certified"]
    scene = json.loads((out / "scene.json").read_text())
    bounded = {d["id"] for f in scene["frames"] for d in f["detections"] if "payoff_lower" in d}
    assert 0 < cert["detections"] == len(bounded) < cert["of"]
    lows = {
        d["id"]: d["payoff_lower"]
        for f in scene["frames"]
        for d in f["detections"]
        if "payoff_lower" in d
    }
    pays = {d["id"]: d["payoff"] for f in scene["frames"] for d in f["detections"]}
    assert all(0 <= lows[i] <= pays[i] for i in lows)
    results = doc["runs"][0]["results"]
    for res, a in zip(results, att["runs"][0]["results"], strict=True):
        assert res["payoffs"] == "interval"
        assert not any("carry no certified bound" in n for n in res["notes"])
        # the attack's optimum is the attack mode's own: that mode attacked only what its
        # models read, in other batches, so to float32 rounding (docs/cnn.md)
        o_attack, o_own = res["optimum_attack"], a["optimum"]
        if isinstance(o_attack, float) and isinstance(o_own, float):
            assert o_attack == pytest.approx(o_own, rel=1e-5)
        else:
            assert o_attack == o_own or (o_attack == "inf" and o_own is None)
        c, t, o = res["optimum_certified"], res["threshold"], res["optimum_attack"]
        c = math.inf if c in ("inf", None) else c
        o = math.inf if o in ("inf", None) else o
        assert c <= o
        if res["verdict"] == "holds":
            assert c > t
        elif res["verdict"] == "violated":
            assert o <= t and res["replay"]["status"] == "confirmed"
    for hid in doc["runs"][0]["hidden"].values():
        for h in hid:  # every detection a counterexample hides was certified
            assert h["obs"] in bounded and h["payoff_lower"] == pytest.approx(lows[h["obs"]])
    # the partially certified scene checks alone, to the same certified optima
    for res in results:
        spec = tmp_path / f"{res['property']}.spec"
        text = (ROOT / "specs" / f"{res['property']}.spec").read_text()
        spec.write_text(text.replace("6..8", "3..5"))  # as --window 3..5 does
        r = lesmc("check", str(out / "scene.json"), str(spec), "--payoffs", "interval", "--json")
        assert "Traceback" not in r.stderr and r.returncode in (0, 1, 3), r.stderr
        again = json.loads(r.stdout)["results"][0]
        want = res["optimum_certified"]
        assert again["optimum_certified"] == (
            want if isinstance(want, str) else pytest.approx(want)
        )


def test_default_video_violations_are_replayed_in_interval_mode(
    default_verify: tuple[Path, subprocess.CompletedProcess[str], list[float]],
) -> None:
    """The main job (`lesmc verify` on the embedded default video), in interval mode:
    every violated verdict is a replay-confirmed attack, every diverged counterexample an
    unknown with its note, and only the detections the models can hide are certified."""
    out, r, times = default_verify
    assert "Traceback" not in r.stderr and r.returncode in (0, 1, 3), r.stderr
    # stderr is no terminal: a log line at least every 10 s (the heartbeat; 5 s of slack)
    gaps = [b - a for a, b in zip([0.0, *times], times, strict=False)]
    assert max(gaps) <= 15.0, (max(gaps), r.stderr)
    doc = json.loads((out / "results.json").read_text())
    cert = doc["perception"]["certified"]
    assert 0 < cert["detections"] <= cert["of"] // 20  # a handful near the target
    violated = 0
    for run in doc["runs"]:
        for res in run["results"]:
            c, a = (
                math.inf if v in ("inf", None) else v
                for v in (res["optimum_certified"], res["optimum_attack"])
            )
            assert c <= a
            # verify certified every detection its models price: no bound read as 0
            assert not any("carry no certified bound" in n for n in res["notes"])
            rp = res.get("replay")
            real = rp is not None and (rp.get("on_frames") or {}).get("violated", False)
            if res["verdict"] == "violated":
                violated += 1
                assert rp is not None and (rp["status"] == "confirmed" or real), rp
            if rp is not None and rp["status"] == "diverged" and not real:
                assert res["verdict"] == "unknown"
                assert any("not a proof of violation" in n for n in res["notes"])
    assert violated  # the plain tracker's robustness breaks under a real attack
    # the improved design's monitor alarms on the unattacked track itself: every holds of
    # it is vacuous, and says so in the JSON and the report, never as a plain holds
    monitored = [run for run in doc["runs"] if run["design"] == "improved"]
    assert monitored
    for res in monitored[0]["results"]:
        assert res["original_alarms"] and res["vacuous"]
        assert res["status"] == "holds (vacuous)" and res["verdict"] == "holds"
    page = (out / "report.html").read_text()
    from html_tables import table_problems

    assert table_problems(page) == []
    assert "<span class='holds--vacuous-'>holds (vacuous: the unattacked track" in page


@settings(max_examples=60, deadline=None)
@given(st.data())
def test_perturbed_inputs_and_difference_equal_whole_float64_frames(data: st.DataObject) -> None:
    """The replay perturbs in float64 only inside the windows' box and keeps float32 frames:
    the CNNs' windows and the difference image equal those of the arithmetic on whole
    float64 frames (the oracle below, written out), over repair rounds too, with windows
    that overlap and that reach past the frame's edge."""
    import cv2

    from lesmc.perception.background import Aligned, median
    from lesmc.perception.frontend import FrontEndOutput
    from lesmc.perception.windows import cut
    from lesmc.replay.perturbed import difference, perturb

    seed = data.draw(st.integers(0, 2**31))
    rng = np.random.default_rng(seed)
    h, w, size, m = 40, 48, 21, 3
    clean = [rng.integers(0, 256, (h, w), dtype=np.uint8) for _ in range(4)]
    frame = rng.integers(0, 256, (h, w), dtype=np.uint8)
    valid = np.where(rng.random((h, w)) < 0.9, 255, 0).astype(np.uint8)
    bg = cv2.convertScaleAbs(median(clean), alpha=1.05)
    out = FrontEndOutput(0, frame, None, Aligned(clean, valid), bg, None)  # type: ignore[arg-type]
    rounds = []
    for _ in range(data.draw(st.integers(1, 3))):
        k = data.draw(st.integers(1, 3))
        centres = rng.uniform(-5, [w + 5, h + 5], (k, 2))
        deltas = rng.normal(0, data.draw(st.sampled_from([1e-9, 0.05, 0.5])), (k, 4, size, size))
        rounds.append((centres, deltas.astype(np.float32)))
    base = [*clean[1:], frame]
    # the oracle: whole frames in float64, each round added at cut()'s pixels, then clipped
    whole = [s.astype(np.float64) for s in base]
    for centres, deltas in rounds:
        for (cx, cy), d in zip(np.rint(centres).astype(int), deltas, strict=True):
            ys = np.clip(cy - size // 2 + np.arange(size), 0, h - 1)
            xs = np.clip(cx - size // 2 + np.arange(size), 0, w - 1)
            yy, xx = np.meshgrid(ys, xs, indexing="ij")
            for c in range(4):
                np.add.at(whole[c], (yy, xx), 255.0 * d[c].astype(np.float64))
        whole = [np.clip(s, 0.0, 255.0) for s in whole]
    pert_aligned = [clean[0], *whole[:-1]]
    alpha = cv2.mean(frame, mask=valid)[0] / cv2.mean(median(clean), mask=valid)[0]
    changed = np.zeros((h, w), bool)
    for a, b in zip(pert_aligned, clean, strict=True):
        changed |= a != b
    bg64 = bg.astype(np.float64)
    if changed.any():
        ys, xs = np.nonzero(changed)
        sl = (slice(ys.min(), ys.max() + 1), slice(xs.min(), xs.max() + 1))
        now = np.median(np.stack([a[sl] for a in pert_aligned]), axis=0)
        was = np.median(np.stack([b[sl].astype(np.float64) for b in clean]), axis=0)
        bg64[sl] += alpha * (now - was)
    want_diff = np.abs(whole[-1] - bg64).astype(np.float32)

    p = perturb(base, rounds, size)
    centres = rng.uniform(0, [w, h], (30, 2))
    assert np.array_equal(cut(p.frames, centres, size), cut(whole, centres, size))
    assert np.array_equal(difference(out, p, m), want_diff)
