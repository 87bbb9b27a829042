"""The joint design under ``allow hide, inject`` on a small video (issue 61, round 24): where
every candidate lies in the initiator's birth region of the target, a state keeps all of
them relevant, and one attacked step lists (hiding options) × 2^k rows.

- the check says so at once (exit 3), with the rows it would build counted with the
  hiding options and the ``--inject-cap`` that fits, instead of running for minutes;
- ``--timeout`` stops such a check between the joint design's chunks: inside a search the
  result is ``unknown`` and written (exit 3), not the alarm's "could not stop sooner";
- the combined payoffs (eq. 5) of a state with very many ranked successors are summed in
  linear time (the quadratic sum was the work that could not stop), equal to ``math.fsum``
  of each prefix.
"""

from __future__ import annotations

import json
import math
import random
import time
from pathlib import Path

import numpy as np
import pytest
from cli_run import lesmc

from lesmc import api
from lesmc.engines.check import check_lazy
from lesmc.model.growing import ExpansionStopped
from lesmc.model.kernel import combined_payoffs, prefix_sums
from lesmc.pipeline.check import bind_scene
from lesmc.scene import Detection, Frame, JointConfig, Scene, Target, TrackerConfig
from lesmc.tracking.parts.attacker_subsets import MAX_INJECT_ROWS
from lesmc.unfold.unfold import lazy_model

SPEC = (
    "property rob { attack window 2..3 allow hide, inject minimize payoff "
    "subject to dist.sum(0..end) > 20 holds if optimum > 3 }\n"
)


def crowded_scene(n_cands: int, clutter: int = 3) -> Scene:
    """A target moving right at 5 px a frame with ``clutter`` detections 3-9 px around it
    (the primary's gate takes them: hiding options) and, from frame 2 on, ``n_cands``
    injection candidates 10-40 px from it (inside the 150 px birth region: all relevant)."""
    rng = np.random.default_rng(3)
    frames = []
    for k in range(6):
        tx, ty = 100.0 + 5.0 * k, 100.0
        dets = [(tx, ty)] + [
            (tx + rng.uniform(-9, 9), ty + rng.uniform(-9, 9)) for _ in range(clutter)
        ]
        detections = tuple(
            Detection(f"{k}:{i}", x, y, 1.0 + i / 10) for i, (x, y) in enumerate(dets)
        )
        cands = []
        for j in range(n_cands if k >= 2 else 0):
            r, a = rng.uniform(10, 40), rng.uniform(0, 2 * math.pi)
            cid = f"{k}:{len(dets) + j}"
            cands.append(Detection(cid, tx + r * math.cos(a), ty + r * math.sin(a), 0.5))
        frames.append(Frame(k, detections, None, candidates=tuple(cands)))
    tracker = TrackerConfig(
        design="joint", joint=JointConfig(init_radius=150.0, init_distance=60.0)
    )
    return Scene(1.0, tuple(frames), Target(0, (100.0, 100.0), (5.0, 0.0)), tracker)


def test_a_step_too_large_is_refused_at_once_with_the_cap_that_fits(tmp_path: Path) -> None:
    """2^19 subsets of the candidates × the hiding options: more than MAX_INJECT_ROWS rows
    (2^19 alone is not: the old guard let the step run for minutes); the message counts
    the hiding options and names an --inject-cap that fits."""
    assert MAX_INJECT_ROWS == 1 << 20
    scene_path, spec = tmp_path / "s.json", tmp_path / "p.spec"
    api.save_scene(crowded_scene(19), scene_path)
    spec.write_text(SPEC)
    t0 = time.monotonic()
    r = lesmc("check", str(scene_path), str(spec), "--design", "joint", timeout=40)
    assert time.monotonic() - t0 < 20
    assert r.returncode == 3, r.stderr
    assert "Traceback" not in r.stderr
    msg = r.stderr
    assert "2^19 subsets" in msg and "hiding option" in msg and "--inject-cap" in msg
    opts = int(msg.split("up to ")[1].split(" hiding")[0])
    assert opts >= 2
    rows = int(msg.split(" rows, each")[0].rsplit("(", 1)[1].replace(",", ""))
    assert rows == opts << 19  # one state at the window's root
    cap = int(msg.split("offer at most ")[1].split(" candidates")[0])
    assert opts << cap <= MAX_INJECT_ROWS < opts << (cap + 1)


def test_the_suggested_cap_answers(tmp_path: Path) -> None:
    """With a few candidates a frame the same scene answers (exit 0 or 1) in seconds."""
    scene_path, spec = tmp_path / "s.json", tmp_path / "p.spec"
    api.save_scene(crowded_scene(6), scene_path)
    spec.write_text(SPEC)
    r = lesmc("check", str(scene_path), str(spec), "--design", "joint", "--json", timeout=40)
    assert r.returncode in (0, 1), r.stderr
    assert json.loads(r.stdout)["results"][0]["verdict"] in ("holds", "violated")


def test_a_stop_inside_a_search_expansion_ends_unknown() -> None:
    """The joint design's ``stop`` raising inside an expansion the engine asked for: the
    check ends ``unknown`` (timeout) with bounds that hold, the model left as it was."""
    scene = crowded_scene(6)
    armed = [False]

    def stop() -> None:
        if armed[0]:
            raise ExpansionStopped("timeout", "--timeout 1 s ran out (test)")

    (bp,) = bind_scene(scene, [api.parse_spec(SPEC)])
    model = lazy_model(scene, (bp.l, bp.u), bp.end, inject=True, stop=stop)
    built = model.n_states
    armed[0] = True
    res = check_lazy(model, bp)
    assert res.verdict == "unknown" and res.stats.stopped == "timeout"
    assert res.lower <= 0.0 and res.upper == math.inf
    assert "ran out" in res.stats.extra["stopped_inside"]
    assert model.n_states == built
    armed[0] = False  # the same model answers once the stop is lifted
    assert check_lazy(model, bp).verdict in ("holds", "violated")


def test_prefix_sums_are_fsum_of_each_prefix() -> None:
    """Against math.fsum of each slice, on random values over many magnitudes (cancellation
    free: payoffs are >= 0), infinities and sums past the largest float included."""
    rng = random.Random(61)
    scales = [0.0, 1e-300, 1e-17, 0.1, 1.0, 3.0, 1e16, 1e300, 1.7e308, math.inf]
    for _ in range(2000):
        n = rng.randint(1, 30)
        vals = [rng.choice(scales) * rng.random() for _ in range(n)]
        a = rng.randint(0, n - 1)
        ends = sorted(rng.sample(range(a + 1, n + 1), rng.randint(1, n - a)))
        got = prefix_sums(vals, [a] * len(ends), ends)
        for b, g in zip(ends, got, strict=True):
            try:
                want = math.fsum(vals[a:b])
            except OverflowError:
                want = math.inf
            assert g == want, (vals, a, b)


def test_combined_payoffs_of_a_wide_state_take_linear_time() -> None:
    """One state with 60,000 successors of distinct ranks: every combined payoff is the
    fsum of the payoffs before it, in well under the quadratic sum's minutes."""
    m = 60_000
    pay = np.random.default_rng(1).uniform(0.0, 3.0, m)
    t0 = time.perf_counter()
    got = combined_payoffs(np.array([0, m]), pay, np.arange(m))
    assert time.perf_counter() - t0 < 5.0
    check = [*np.random.default_rng(2).integers(0, m, 200).tolist(), 0, 1, 2, m - 1]
    for i in check:
        assert got[i] == math.fsum(pay[:i].tolist())


@pytest.mark.parametrize("ranks", [[0, 0, 1, 1, 1, 2, 3, 3], [0, 1, 2, 3, 4, 5, 6, 7]])
def test_combined_payoffs_with_ties_and_two_states(ranks: list[int]) -> None:
    """Two states (rows) with ties in rank: a transition's combined payoff sums the
    payoffs of the transitions of strictly lower rank out of its own state."""
    pay = np.array([0.1, 0.2, 0.3, 1e16, 1.0, 0.7, 2.0, 5.0] * 2)
    rank = np.array(ranks * 2)
    got = combined_payoffs(np.array([0, 8, 16]), pay, rank)
    for s in (0, 8):
        for i in range(8):
            lower = [pay[s + j] for j in range(8) if rank[s + j] < rank[s + i]]
            assert got[s + i] == math.fsum(lower)


def test_max_states_on_sort_names_what_limits_injection(tmp_path: Path) -> None:
    """The --max-states refusal of a multi-target step under inject names what limits the
    injection candidates (the scene's: perceive --inject-cap), not only ``within R``, which
    does not reach them; under hide only it names ``within R`` alone."""
    from test_inject import HIJACK_SPEC, _doc, _hijack_case, _write

    frames, pay, cands, cpay, _, _ = _hijack_case()
    scene, spec = _write(tmp_path, _doc(frames, pay, cands, cpay), HIJACK_SPEC)
    r = lesmc("check", str(scene), str(spec), "--max-states", "4", timeout=60)
    assert r.returncode == 3 and "Traceback" not in r.stderr, r.stderr
    assert "fewer injection candidates" in r.stderr and "--inject-cap" in r.stderr
    spec.write_text(HIJACK_SPEC.replace(" allow hide, inject", ""))
    r = lesmc("check", str(scene), str(spec), "--max-states", "1", timeout=60)
    assert r.returncode == 3 and "within R" in r.stderr, r.stderr
    assert "--inject-cap" not in r.stderr
