"""Payoffs priced on demand (lesmc/experiment/pricing.py, scene/frames.py; issue 31).

A model built over frames whose payoffs are priced when it reads them is the model of
the same scene priced up front (the oracle: the scene file's own payoffs), and it asks
for fewer payoffs than the scene has; a model that reads an unpriced payoff with
nobody to price it stops with exit 2 and names the detection; windows kept compact
come back bit for bit; ``lesmc verify`` gives the results of ``--price-all``.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_run import lesmc

from lesmc.perception.windows import compact, cut, expand
from lesmc.scene import (
    Detection,
    Frame,
    OnDemandPayoffs,
    PricedFrame,
    Scene,
    UnpricedPayoff,
    load_scene,
    save_scene,
    scene_to_dict,
)
from lesmc.unfold.unfold import build_model
from lesmc.video.synth import SynthConfig
from lesmc.video.write import write_video

SCENES = Path(__file__).parent / "scenes"
FIELDS = ("step", "S", "halted", "ptr", "dst", "payoff", "rank", "original", "obs")


def _with_far_traffic(scene: Scene) -> Scene:
    """``scene`` with, in every frame, detections far from every track (never read)."""
    rng = np.random.default_rng(5)
    frames = tuple(
        replace(
            f,
            detections=f.detections
            + tuple(
                Detection(f"{f.step}:far{i}", 5000.0 + 40 * i, 5000.0, float(rng.uniform(0.5, 4)))
                for i in range(6)
            ),
        )
        for f in scene.frames
    )
    return replace(scene, frames=frames)


def _unpriced(scene: Scene) -> Scene:
    """``scene`` with every payoff unpriced (plain frames)."""
    frames = tuple(
        Frame(f.step, tuple(replace(d, payoff=math.nan) for d in f.detections), f.to_next)
        for f in scene.frames
    )
    return replace(scene, frames=frames)


class _Oracle:
    """Prices from the fully priced scene, counting what it is asked."""

    def __init__(self, scene: Scene) -> None:
        self.scene = scene
        self.asked: list[tuple[int, int]] = []

    def __call__(self, wanted: Mapping[int, np.ndarray]) -> dict[int, np.ndarray]:
        out = {}
        for k, idx in wanted.items():
            self.asked += [(k, int(i)) for i in idx]
            col = np.full(len(self.scene.frame(k).detections), np.nan)
            col[idx] = [self.scene.frame(k).detections[int(i)].payoff for i in idx]
            out[k] = col
        return out


def _on_demand(scene: Scene, oracle: _Oracle) -> tuple[Scene, OnDemandPayoffs]:
    bare = _unpriced(scene)
    prices = OnDemandPayoffs({f.step: f.payoff_values() for f in bare.frames}, oracle)
    frames = tuple(PricedFrame(f.step, f.detections, f.to_next, prices) for f in bare.frames)
    return replace(bare, frames=frames), prices


def _same_model_on_demand(
    scene: Scene, oracle: _Oracle, window: tuple[int, int]
) -> tuple[Scene, OnDemandPayoffs]:
    """Builds ``scene`` priced up front and priced on demand by ``oracle``: the same
    model, field by field; the on-demand scene and its prices."""
    want = build_model(scene, window)
    lazy, prices = _on_demand(scene, oracle)
    got = build_model(lazy, window)
    for f in FIELDS:
        assert np.array_equal(getattr(got, f), getattr(want, f)), f
    return lazy, prices


@pytest.mark.parametrize("design", ["single", "joint"])
@pytest.mark.parametrize("name", ["rq1_platoon", "rq2_parallel", "rq4_merge"])
def test_a_model_priced_on_demand_is_the_model_priced_up_front(name: str, design: str) -> None:
    scene = _with_far_traffic(load_scene(SCENES / f"{name}.json").with_tracker(design=design))
    oracle = _Oracle(scene)
    lazy, prices = _same_model_on_demand(scene, oracle, (5, 8))
    # each detection priced once, none of the far ones, fewer than all of them
    assert len(oracle.asked) == len(set(oracle.asked)) == prices.asked
    assert not any("far" in scene.frame(k).detections[i].id for k, i in oracle.asked)
    assert 0 < len(oracle.asked) < sum(len(f.detections) for f in scene.frames)
    # what was priced is written into the detections; the rest stays unpriced
    settled = lazy.settled()
    for f, g in zip(settled.frames, scene.frames, strict=True):
        for i, (d, e) in enumerate(zip(f.detections, g.detections, strict=True)):
            assert d.payoff == e.payoff if (f.step, i) in oracle.asked else math.isnan(d.payoff)


class _BlobOracle(_Oracle):
    """Prices as perception does: detections 2j and 2j+1 share a blob, whose attack
    prices both; counts the blobs attacked."""

    def __init__(self, scene: Scene) -> None:
        super().__init__(scene)
        self.blobs: list[tuple[int, int]] = []

    def __call__(self, wanted: Mapping[int, np.ndarray]) -> dict[int, np.ndarray]:
        out = {}
        for k, idx in wanted.items():
            dets = self.scene.frame(k).detections
            blobs = sorted({int(i) // 2 for i in idx})
            self.blobs += [(k, b) for b in blobs]
            col = np.full(len(dets), np.nan)
            for b in blobs:
                for i in (2 * b, 2 * b + 1):
                    if i < len(dets):
                        col[i] = dets[2 * b].payoff  # a blob's detections share its payoff
            out[k] = col
        return out


def _blob_payoffs(scene: Scene) -> Scene:
    """``scene`` whose detections 2j and 2j+1 carry detection 2j's payoff."""
    frames = tuple(
        replace(
            f,
            detections=tuple(
                replace(d, payoff=f.detections[i - i % 2].payoff)
                for i, d in enumerate(f.detections)
            ),
        )
        for f in scene.frames
    )
    return replace(scene, frames=frames)


@pytest.mark.parametrize("design", ["single", "joint"])
def test_a_model_priced_by_blobs_is_the_model_priced_up_front(design: str) -> None:
    """Priced as perception prices, a blob's detections together: the up-front model,
    no blob attacked twice (on this scene no model reads a blob's detections in two
    batches; test_a_blobs_other_detection_is_not_attacked_again makes one)."""
    scene = _blob_payoffs(
        _with_far_traffic(load_scene(SCENES / "rq4_merge.json").with_tracker(design=design))
    )
    oracle = _BlobOracle(scene)
    _, prices = _same_model_on_demand(scene, oracle, (4, 9))
    assert oracle.blobs and len(oracle.blobs) == len(set(oracle.blobs))
    assert prices.asked >= len(oracle.blobs)


def test_a_blobs_other_detection_is_not_attacked_again() -> None:
    """Reading one detection of a blob prices the blob: its sibling, read later, costs
    no second attack and has the same payoff."""
    attacked: list[list[int]] = []

    def price(wanted: Mapping[int, np.ndarray]) -> dict[int, np.ndarray]:
        blobs = sorted({int(i) // 2 for i in wanted[0]})
        attacked.append(blobs)
        col = np.full(6, np.nan)
        for b in blobs:
            col[2 * b : 2 * b + 2] = 1.0 + b + 0.1 * len(attacked)  # another batch: other bits
        return {0: col}

    prices = OnDemandPayoffs({0: np.full(6, np.nan)}, price)
    first = prices.read(0, np.array([0]))
    second = prices.read(0, np.array([1]))
    assert attacked == [[0]] and first[0] == second[0]
    assert prices.read(0, np.array([1, 4]))[1] == prices.read(0, np.array([5]))[0]
    assert attacked == [[0], [2]] and prices.asked == 4


KEYS: list[Any] = [
    3, -1, slice(None), slice(1, 5), np.array([0, 2, 2, 5]), np.array([-1, 0]),
    np.array([True, False] * 4), np.array([[1, 2], [3, 4]]), (np.array([1, 3]),),
]  # fmt: skip


@pytest.mark.parametrize("key", KEYS, ids=[repr(k)[:20] for k in KEYS])
def test_the_payoff_columns_index_as_arrays_do(key: Any) -> None:
    values = np.array([0.5, np.nan, 2.0, np.inf, 1.5, np.nan, 0.25, 3.0])
    truth = np.where(np.isnan(values), 9.0, values)  # what the pricer would say
    dets = tuple(Detection(f"0:{i}", float(i), 0.0, float(v)) for i, v in enumerate(values))
    plain = Frame(0, dets)
    wants_unpriced = np.isnan(np.atleast_1d(values[key])).any()
    if wants_unpriced:
        with pytest.raises(UnpricedPayoff):
            plain.payoffs()[key]
    else:
        assert np.array_equal(plain.payoffs()[key], values[key])

    def price(wanted: Mapping[int, np.ndarray]) -> dict[int, np.ndarray]:
        col = np.full(len(values), np.nan)
        col[wanted[0]] = truth[wanted[0]]
        return {0: col}

    prices = OnDemandPayoffs({0: values}, price)
    lazy = PricedFrame(0, dets, None, prices)
    assert np.array_equal(lazy.payoffs()[key], truth[key])
    assert len(lazy.payoffs()) == len(values)
    assert np.array_equal(np.asarray(lazy.payoffs()), truth)


def test_a_priced_frame_refuses_other_detections() -> None:
    scene = load_scene(SCENES / "rq1_platoon.json")
    lazy, _ = _on_demand(scene, _Oracle(scene))
    with pytest.raises(ValueError, match="detections"):
        replace(lazy.frames[0], detections=())


def test_a_lower_bound_for_an_unpriced_payoff_is_refused() -> None:
    bare = _unpriced(load_scene(SCENES / "rq1_platoon.json"))
    with pytest.raises(ValueError, match="unpriced"):
        bare.with_lower({bare.frames[0].step: np.full(len(bare.frames[0].detections), 0.1)})


def test_a_model_that_reads_an_unpriced_payoff_stops() -> None:
    scene = load_scene(SCENES / "rq1_platoon.json")
    with pytest.raises(UnpricedPayoff) as err:
        build_model(_unpriced(scene), (6, 8))
    assert "unpriced" in err.value.render() and "--price-all" in err.value.render()


def _write(scene: Scene, path: Path) -> Path:
    save_scene(scene, path)
    return path


@pytest.mark.parametrize("verb", ["check", "build", "export"])
def test_reading_an_unpriced_payoff_exits_2_naming_it(verb: str, tmp_path: Path) -> None:
    scene = load_scene(SCENES / "rq1_platoon.json")
    path = _write(_unpriced(scene), tmp_path / "scene.json")
    assert '"unpriced"' in path.read_text()
    out = tmp_path / "out.lts"
    args = {
        "check": [str(SCENES / "rq1_platoon.spec")],
        "build": ["--window", "6..8", "-o", str(out)],
        "export": ["--window", "6..8", "--format", "dot", "-o", str(out)],
    }[verb]
    r = lesmc(verb, str(path), *args)
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr and not out.exists()
    said = [line for line in r.stderr.splitlines() if "--price-all" in line]
    # at the payoff's FILE:LINE:COL (tests/test_hostile_round22.py checks which line)
    assert len(said) == 1 and re.match(rf"{re.escape(str(path))}:\d+:\d+: frame ", said[0])
    assert "detection '" in said[0] and "--price-all" in said[0]


def test_unpriced_payoffs_no_model_reads_change_nothing(tmp_path: Path) -> None:
    """Only the far detections unpriced: the same results as the fully priced scene."""
    scene = _with_far_traffic(load_scene(SCENES / "rq1_platoon.json"))
    part = replace(
        scene,
        frames=tuple(
            replace(
                f,
                detections=tuple(
                    replace(d, payoff=math.nan) if "far" in d.id else d for d in f.detections
                ),
            )
            for f in scene.frames
        ),
    )
    spec = str(SCENES / "rq1_platoon.spec")
    docs = []
    for s, name in ((scene, "full.json"), (part, "part.json")):
        r = lesmc("check", str(_write(s, tmp_path / name)), spec, "--json")
        assert r.returncode in (0, 1), r.stderr
        docs.append(json.loads(r.stdout))
    opt = [[(x["verdict"], x["optimum"]) for x in d["results"]] for d in docs]
    assert opt[0] == opt[1]


@pytest.mark.parametrize("design", ["single", "joint"])
def test_the_unattacked_track_reads_no_payoff(design: str, tmp_path: Path) -> None:
    """``lesmc track`` on a scene with every payoff unpriced: the fully priced scene's track."""
    scene = load_scene(SCENES / "rq4_merge.json")
    outs = []
    for s, name in ((scene, "full.json"), (_unpriced(scene), "bare.json")):
        r = lesmc("track", str(_write(s, tmp_path / name)), "--design", design, "--json")
        assert r.returncode == 0, r.stderr
        outs.append(json.loads(r.stdout)["track"])
    assert outs[0] == outs[1]


def test_unpriced_round_trips_through_the_scene_file(tmp_path: Path) -> None:
    scene = _unpriced(load_scene(SCENES / "rq1_platoon.json"))
    doc = scene_to_dict(scene)
    assert {d["payoff"] for f in doc["frames"] for d in f["detections"]} == {"unpriced"}
    again = load_scene(_write(scene, tmp_path / "s.json"))
    assert again.unpriced == scene.unpriced == sum(len(f.detections) for f in scene.frames)


def test_a_lower_bound_needs_a_priced_payoff(tmp_path: Path) -> None:
    doc = scene_to_dict(load_scene(SCENES / "rq1_platoon.json"))
    det = doc["frames"][2]["detections"][1]
    det["payoff"], det["payoff_lower"] = "unpriced", 0.5
    path = tmp_path / "s.json"
    path.write_text(json.dumps(doc, indent=1))
    r = lesmc("check", str(path), str(SCENES / "rq1_platoon.spec"))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert f"detection '{det['id']}'" in r.stderr or det["id"] in r.stderr
    assert "payoff_lower needs a priced payoff" in r.stderr


def test_compact_windows_come_back_bit_for_bit() -> None:
    rng = np.random.default_rng(2)
    frames = [rng.integers(0, 256, (64, 80), dtype=np.uint8) for _ in range(4)]
    centres = rng.uniform(-5, 85, (50, 2))  # some past the edges
    win = cut(frames, centres, 21)
    small = compact(win)
    assert small.dtype == np.uint8 and small.nbytes * 4 == win.nbytes
    assert np.array_equal(expand(small), win)
    assert np.array_equal(expand(small).view(np.uint32), win.view(np.uint32))


# ------------------------------------------------------------------ lesmc verify


@pytest.fixture(scope="module")
def video(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("pricing") / "tiny"
    write_video(SynthConfig(frames=12, width=448, height=448, seed=4, density=3.0), out)
    return out


def _verify(video: Path, out: Path, *extra: str) -> tuple[str, dict[str, Any]]:
    r = lesmc("verify", str(video), "--truth", str(video / "truth.json"), "--out", str(out),
              "--window", "3..4", *extra)  # fmt: skip
    assert r.returncode in (0, 1, 3), r.stderr
    assert "Traceback" not in r.stderr
    return r.stderr, json.loads((out / "results.json").read_text())


def _outcomes(doc: dict[str, Any]) -> list[tuple[str, str, str, Any]]:
    return [
        (run["design"], r["property"], r["verdict"], r["optimum"])
        for run in doc["runs"]
        for r in run["results"]
    ]


def _payoffs(out: Path) -> dict[str, Any]:
    doc = json.loads((out / "scene.json").read_text())
    return {d["id"]: d["payoff"] for f in doc["frames"] for d in f["detections"]}


def test_verify_prices_on_demand_what_price_all_gives(video: Path, tmp_path: Path) -> None:
    log, lazy = _verify(video, tmp_path / "lazy", "--design", "single")
    _, full = _verify(video, tmp_path / "full", "--design", "single", "--price-all")
    assert "detections on demand" in log
    a, b = _outcomes(lazy), _outcomes(full)
    assert [x[:3] for x in a] == [x[:3] for x in b]
    for x, y in zip(a, b, strict=True):  # float32 attacks batched differently
        assert x[3] == y[3] or x[3] == pytest.approx(y[3], rel=1e-5)
    got, want = _payoffs(tmp_path / "lazy"), _payoffs(tmp_path / "full")
    assert got.keys() == want.keys() and "unpriced" not in want.values()
    priced = {k: v for k, v in got.items() if v != "unpriced"}
    assert 0 < len(priced) < len(got)
    for k, v in priced.items():
        assert v == want[k] or v == pytest.approx(want[k], rel=1e-5), k
    meta = json.loads((tmp_path / "lazy" / "scene.json").read_text())["meta"]["priced"]
    assert meta["detections"] == len(priced) and meta["of"] == len(got)


def test_a_rerun_that_reads_more_payoffs_perceives_again(video: Path, tmp_path: Path) -> None:
    """The cached perception has no windows: a rerun whose models read payoffs it lacks
    perceives the video again and prices them; then its cache has them too."""
    out = tmp_path / "out"
    _verify(video, out, "--design", "single")
    log, doc = _verify(video, out, "--design", "joint")
    assert "reusing the perception" in log
    assert "perceiving the video again: a check reads payoffs its cache lacks" in log
    _, full = _verify(video, tmp_path / "full", "--design", "joint", "--price-all")
    assert [x[:3] for x in _outcomes(doc)] == [x[:3] for x in _outcomes(full)]
    for x, y in zip(_outcomes(doc), _outcomes(full), strict=True):
        assert x[3] == y[3] or x[3] == pytest.approx(y[3], rel=1e-5)
    log, again = _verify(video, out, "--design", "joint")
    assert "perceiving" not in log
    assert _outcomes(again) == _outcomes(doc)


def test_price_all_perceives_an_entry_with_unpriced_payoffs_again(
    video: Path, tmp_path: Path
) -> None:
    out = tmp_path / "out"
    _verify(video, out, "--design", "single")
    assert "unpriced" in _payoffs(out).values()
    log, _ = _verify(video, out, "--design", "single", "--price-all")
    assert "perceiving the video again: its cached perception has unpriced payoffs" in log
    assert "unpriced" not in _payoffs(out).values()


def test_a_cache_that_does_not_match_the_video_is_refused(tmp_path: Path) -> None:
    from lesmc.common.errors import UsageError
    from lesmc.experiment.cache import StageCache
    from lesmc.experiment.verify_perception import same_detections

    footage = load_scene(SCENES / "rq1_platoon.json").footage
    moved = replace(
        footage,
        frames=(
            replace(
                footage.frames[0],
                detections=tuple(replace(d, x=d.x + 1) for d in footage.frames[0].detections),
            ),
            *footage.frames[1:],
        ),
    )
    cache = StageCache(tmp_path)
    same_detections(footage, footage, cache)
    with pytest.raises(UsageError, match="differ"):
        same_detections(footage, moved, cache)
