"""The builder and on-the-fly checking agree; `lesmc build`, `track` and `check SCENE`."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from cli_run import lesmc
from hypothesis import given, settings
from hypothesis import strategies as st

from lesmc.common.errors import UsageError
from lesmc.engines.check import check_bound, check_lazy
from lesmc.language.parser import parse_spec
from lesmc.model.lts_format import load_lts
from lesmc.pipeline.check import bind_scene
from lesmc.scene import load_scene
from lesmc.unfold.unfold import build_model, lazy_model

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "tests" / "scenes"
NAMES = ["rq1_platoon", "rq1_oncoming", "rq2_parallel", "rq2_stop", "rq4_merge"]


@settings(max_examples=40, deadline=None)
@given(
    name=st.sampled_from(NAMES),
    design=st.sampled_from(["single", "joint"]),
    l=st.integers(3, 10),
    span=st.integers(0, 3),
    obj=st.sampled_from(["payoff", "payoff.mean", "dist.max({l}..{u})", "dist.sum(0..end)"]),
    con=st.sampled_from(["dist.sum(0..end) > 40", "dist.at(end) > 1", "dist.max({l}..end) >= 8"]),
    monitor=st.booleans(),
)
def test_on_the_fly_equals_explicit_model(name, design, l, span, obj, con, monitor) -> None:  # type: ignore[no-untyped-def]
    u = l + span
    measures = (obj.format(l=l, u=u), con.format(l=l, u=u))
    text = (
        f"property p {{ attack window {l}..{u} minimize {measures[0]} subject to {measures[1]} "
        f"holds if optimum > 3 {'monitor uncertainty' if monitor else ''} }}"
    )
    scene = load_scene(SCENES / f"{name}.json").with_tracker(design=design)
    (bp,) = bind_scene(scene, [parse_spec(text)])
    model = build_model(scene, (l, u))
    explicit = [check_bound(model, bp, engine) for engine in ("bnb", "enumerate")]  # type: ignore[arg-type]
    for lazy_engine in ("bnb", "levels"):  # levels: narrow dives, side by side (lanes)
        lazy = check_lazy(lazy_model(scene, (bp.l, bp.u), bp.end), bp, lazy_engine)  # type: ignore[arg-type]
        for r in explicit:
            assert (lazy.verdict, lazy.optimum, lazy.witness_value) == (
                r.verdict,
                r.optimum,
                r.witness_value,
            )
        # the lazy engine builds no more than the model holds
        assert lazy.stats.extra["states_built"] <= model.n_states


def test_build_errors() -> None:
    scene = load_scene(SCENES / "rq2_parallel.json")
    with pytest.raises(UsageError, match=r"window 6\.\.30 must satisfy"):
        build_model(scene, (6, 30))
    with pytest.raises(UsageError, match="end 40 is beyond the scene"):
        build_model(scene, (6, 8), end=40)


def test_cli_build_then_check_equals_check_scene(tmp_path: Path) -> None:
    out = tmp_path / "m.lts"
    r = lesmc("build", str(SCENES / "rq4_merge.json"), "--window", "6..8", "-o", str(out))
    assert r.returncode == 0, r.stderr
    model = load_lts(out)
    assert model.meta["window"] == [6, 8] and model.meta["design"] == "single"
    spec = str(SCENES / "rq4_merge.spec")
    a = json.loads(lesmc("check", str(out), spec, "--json").stdout)["results"]
    b = json.loads(lesmc("check", str(SCENES / "rq4_merge.json"), spec, "--json").stdout)["results"]
    assert [(x["verdict"], x["optimum"]) for x in a] == [(x["verdict"], x["optimum"]) for x in b]
    # a property whose window the model was not built for gets a note
    wide = tmp_path / "wide.spec"
    wide.write_text(
        "property w { attack window 5..9 minimize payoff subject to dist.at(end) > 1 "
        "holds if optimum > 1 }"
    )
    r = lesmc("check", str(out), str(wide), "--json")
    notes = json.loads(r.stdout)["results"][0]["notes"]
    assert any("built for attacks in 6..8" in n for n in notes)


def test_cli_joint_design_and_track(tmp_path: Path) -> None:
    r = lesmc(
        "check",
        str(SCENES / "rq4_merge.json"),
        str(SCENES / "rq4_merge.spec"),
        "--design",
        "joint",
        "--json",
    )
    res = {x["property"]: x for x in json.loads(r.stdout)["results"]}
    assert res["robustness"]["optimum"] == "inf" and res["robustness"]["verdict"] == "holds"
    r = lesmc("track", str(SCENES / "rq2_stop.json"), "--json")
    doc = json.loads(r.stdout)
    assert doc["design"] == "single" and len(doc["track"]) == 20
    assert {"step", "frame", "obs", "s", "tau", "alarm", "halted"} <= set(doc["track"][0])
    r = lesmc("track", str(SCENES / "rq2_stop.json"))
    assert r.returncode == 0 and "unattacked track" in r.stdout


def test_cli_scene_errors(tmp_path: Path) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text('{"format": "lesmc-scene", "version": 1, "frames": []}')
    r = lesmc("build", str(bad), "--window", "1..2", "-o", str(tmp_path / "m.lts"))
    assert r.returncode == 2 and f"{bad}:1:41: frames: must be a non-empty list" in r.stderr
    assert not (tmp_path / "m.lts").exists()
    r = lesmc(
        "build", str(SCENES / "rq2_stop.json"), "--window", "8-6", "-o", str(tmp_path / "m.lts")
    )
    assert r.returncode == 2 and "--window must look like L..U" in r.stderr
    r = lesmc(
        "check",
        str(ROOT / "tests/golden/tiny/model.lts"),
        str(SCENES / "rq2_stop.spec"),
        "--design",
        "joint",
    )
    assert r.returncode == 2 and "--design applies to scenes" in r.stderr


@pytest.mark.parametrize("design", ["single", "joint"])
def test_enumerate_walks_one_tree_for_every_property_and_answers_as_alone(
    design: str, tmp_path: Path
) -> None:
    """``check SCENE SPEC --engine enumerate`` with three properties of one window: one walk
    of the tree (stats say so) and every result as when the property is checked alone."""
    spec = tmp_path / "three.spec"
    spec.write_text(
        (ROOT / "specs" / "robustness.spec").read_text()
        + (ROOT / "specs" / "resilience.spec").read_text()
        + (ROOT / "examples" / "count.spec").read_text().split("property frames_robustness")[0]
    )
    scene = str(SCENES / "rq1_platoon.json")
    together = lesmc("check", scene, str(spec), "--engine", "enumerate", "--json", "--design",
                     design)  # fmt: skip
    assert together.returncode in (0, 1), together.stderr
    rows = {r["property"]: r for r in json.loads(together.stdout)["results"]}
    assert len(rows) == 3
    for name, row in rows.items():
        assert row["stats"]["tree_shared_by"] == 3
        alone = lesmc("check", scene, str(spec), "--engine", "enumerate", "--json",
                      "--property", name, "--design", design)  # fmt: skip
        (want,) = json.loads(alone.stdout)["results"]
        for key in ("verdict", "optimum", "witness_value", "counterexample", "witness", "bounds"):
            assert row[key] == want[key], (name, key)


@pytest.mark.parametrize("design", ["single", "joint"])
@pytest.mark.parametrize("name", ["rq1_platoon", "rq4_merge"])
def test_hash_collisions_share_states_as_the_hash_does(
    name: str, design: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """States are shared by their exact words, not by their hash: with a hash that makes
    nearly every state collide (the exact fallback on every batch), the same model."""
    import numpy as np

    from lesmc.unfold import unfold
    from lesmc.unfold.hashing import row_hash

    scene = load_scene(SCENES / f"{name}.json").with_tracker(design=design)
    want = build_model(scene, (5, 8))
    monkeypatch.setattr(unfold, "row_hash", lambda w: row_hash(w) & np.uint64(3))
    got = build_model(scene, (5, 8))
    assert got.n_states == want.n_states
    for f in ("step", "S", "halted", "ptr", "dst", "payoff", "rank", "original", "obs"):
        assert np.array_equal(getattr(got, f), getattr(want, f)), f
    # the covariance table is numbered in the order batches meet it: compare the matrices
    if want.cov is not None:
        assert got.cov is not None and got.P_table is not None and want.P_table is not None
        assert np.array_equal(got.cov < 0, want.cov < 0)
        assert np.array_equal(got.P_table[got.cov], want.P_table[want.cov])


def test_equal_rows_hash_equally_and_distinct_rows_rarely_collide() -> None:
    import numpy as np

    from lesmc.unfold.hashing import row_hash

    rng = np.random.default_rng(3)
    for width in (1, 5, 64, 70):
        words = rng.integers(0, 2**63, size=(4000, width), dtype=np.int64).view(np.uint64)
        words[2000:] = words[:2000]
        h = row_hash(words)
        assert np.array_equal(h[2000:], h[:2000])
        assert len(np.unique(h[:2000])) == 2000
        # rows that differ in one bit of one word
        flipped = words[:2000].copy()
        flipped[np.arange(2000), rng.integers(0, width, 2000)] ^= np.uint64(1) << np.uint64(
            rng.integers(0, 64)
        )
        assert not np.any(row_hash(flipped) == h[:2000])
