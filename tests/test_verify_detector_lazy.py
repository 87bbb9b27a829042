"""``lesmc verify FRAMES --detector det.toml`` prices a heatmap detector's detections on
demand and keeps its perception in OUT/cache (issue 60: verify through a detector file).

On a tiny video (a spot moving past a static one) and a hand-set heatmap network made
here: the default run prices only the detections its model reads (the others are
``"unpriced"`` in OUT/scene.json), and its verdict and optimum equal those of a run with
``--price-all``, whose scene carries every payoff, equal to the ones priced on demand. A
rerun in the same OUT reads the perception (and the replay) back from OUT/cache and
prices nothing.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from cli_run import lesmc
from spot_detector import SPEC, write_spot_detector
from test_campaign_detector import _frames

pytest.importorskip("onnx")
pytest.importorskip("onnxscript")


def _verify(d: Path, out: str, *extra: str) -> Any:
    return lesmc(
        "verify", str(d / "video0"), "--detector", str(d / "spot.toml"), "--target",
        "10,30@0", "--spec", str(d / "p.spec"), "--design", "single", "--out", str(d / out),
        *extra,
    )  # fmt: skip


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    d = tmp_path_factory.mktemp("lazydet")
    _frames(d, 0)
    write_spot_detector(d)
    (d / "p.spec").write_text(SPEC)
    lazy = _verify(d, "lazy")
    again = _verify(d, "lazy")
    full = _verify(d, "full", "--price-all")
    return {"dir": d, "lazy": lazy, "again": again, "full": full}


def _doc(d: Path, out: str, name: str) -> Any:
    return json.loads((d / out / name).read_text())


def _result(d: Path, out: str) -> dict[str, Any]:
    (r,) = [x for rr in _doc(d, out, "results.json")["runs"] for x in rr["results"]]
    return dict(r)


def test_runs_end(runs: dict[str, Any]) -> None:
    for key in ("lazy", "again", "full"):
        r = runs[key]
        assert "Traceback" not in r.stderr and "internal error" not in r.stderr, r.stderr
        assert r.returncode in (0, 1), r.stdout + r.stderr
    assert runs["lazy"].returncode == runs["full"].returncode == runs["again"].returncode


def test_only_what_the_model_reads_is_priced(runs: dict[str, Any]) -> None:
    d = runs["dir"]
    lazy = _doc(d, "lazy", "scene.json")
    full = _doc(d, "full", "scene.json")
    pays = [x["payoff"] for f in lazy["frames"] for x in f["detections"]]
    every = [x["payoff"] for f in full["frames"] for x in f["detections"]]
    assert len(pays) == len(every)
    assert "unpriced" in pays and "unpriced" not in every
    priced = [(p, q) for p, q in zip(pays, every, strict=True) if p != "unpriced"]
    assert priced and lazy["meta"]["priced"]["detections"] == len(priced)
    for p, q in priced:  # the same attack, on demand or up front
        assert p == q if isinstance(p, str) else p == pytest.approx(q, rel=1e-5, abs=1e-7)
    facts = _doc(d, "lazy", "results.json")["perception"]["detections"]
    assert facts["priced"] == len(priced) and facts["detections"] == len(pays)


def test_the_verdict_is_the_price_all_one(runs: dict[str, Any]) -> None:
    d = runs["dir"]
    lazy, full = _result(d, "lazy"), _result(d, "full")
    assert lazy["verdict"] == full["verdict"]
    assert lazy["optimum"] == pytest.approx(full["optimum"], rel=1e-5)


def test_a_rerun_reads_the_cache_and_prices_nothing(runs: dict[str, Any]) -> None:
    err = runs["again"].stderr
    assert "reusing the perception of" in err, err
    assert "priced 0 detections on demand" in err, err
    if runs["lazy"].returncode == 1:  # violated: the counterexamples' replay is kept too
        assert "reusing the replay of" in err, err
    d = runs["dir"]
    assert _result(d, "lazy")["verdict"] == _result(d, "full")["verdict"]
