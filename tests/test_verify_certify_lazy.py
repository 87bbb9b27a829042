"""``lesmc verify --detector det.toml --payoffs interval`` certifies a heatmap detector's
detections on demand (issue 60, round 23).

On a tiny video (a spot moving past a static one) and the hand-set heatmap network of
tests/spot_detector.py: the default run certifies only the detections its models can hide
(through the campaign's certifier, lesmc/pipeline/certify.py and
``detector_verify.file_certifier``), ``--price-all`` certifies every detection up front
(as ``perceive --certify``). Each run goes through ``python -m lesmc`` with the crop
bound propagation (``heatmap_certify.certify_cells``, which both ways call) wrapped to
count the detections it bounds: the count is the test's own, not the run's report. Both
runs give the same verdict, optimum, certified and attack optima and payoffs, and the
on-demand run bounds fewer detections, each as the up-front run bounds it.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from cli_run import ROOT
from spot_detector import SPEC, write_spot_detector
from test_campaign_detector import _frames

pytest.importorskip("onnx")

#: ``python -m lesmc`` with heatmap_certify.certify_cells counting the detections it bounds
#: (one line per call: how many) into the file $COUNT_FILE.
RUNNER = """
import os, runpy, sys
import lesmc.perception.heatmap_certify as hc
real = hc.certify_cells
def counted(det, frame, cells, *args, **kwargs):
    with open(os.environ["COUNT_FILE"], "a") as f:
        f.write(f"{len(cells)}\\n")
    return real(det, frame, cells, *args, **kwargs)
hc.certify_cells = counted
sys.argv = ["lesmc", *sys.argv[1:]]
runpy.run_module("lesmc", run_name="__main__", alter_sys=True)
"""


def _verify(d: Path, out: str, *extra: str) -> tuple[subprocess.CompletedProcess[str], int]:
    """verify through the spot detector in interval mode; also how many detections the
    crop bound propagation bounded."""
    count = d / f"{out}.count"
    count.write_text("")
    args = [
        "verify", str(d / "video0"), "--detector", str(d / "spot.toml"), "--target", "10,30@0",
        "--spec", str(d / "p.spec"), "--design", "single", "--payoffs", "interval", "--out",
        str(d / out), *extra,
    ]  # fmt: skip
    r = subprocess.run(
        [sys.executable, str(d / "runner.py"), *args], capture_output=True, text=True,
        cwd=ROOT, timeout=600,
        env={**os.environ, "PYTHONPATH": str(ROOT), "COUNT_FILE": str(count)},
    )  # fmt: skip
    return r, sum(int(n) for n in count.read_text().split())


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    d = tmp_path_factory.mktemp("certlazy")
    _frames(d, 0)
    write_spot_detector(d, dynamo=False)
    (d / "p.spec").write_text(SPEC)
    (d / "runner.py").write_text(RUNNER)
    lazy, n_lazy = _verify(d, "lazy")
    full, n_full = _verify(d, "full", "--price-all")
    return {"dir": d, "lazy": lazy, "full": full, "n_lazy": n_lazy, "n_full": n_full}


def _doc(d: Path, out: str, name: str) -> Any:
    return json.loads((d / out / name).read_text())


def _detections(d: Path, out: str) -> list[dict[str, Any]]:
    return [x for f in _doc(d, out, "scene.json")["frames"] for x in f["detections"]]


def test_both_runs_end_alike(runs: dict[str, Any]) -> None:
    for key in ("lazy", "full"):
        r = runs[key]
        assert "Traceback" not in r.stderr and "internal error" not in r.stderr, r.stderr
        assert r.returncode in (0, 1), r.stdout + r.stderr
    assert runs["lazy"].returncode == runs["full"].returncode


def test_the_same_verdicts_optima_and_payoffs(runs: dict[str, Any]) -> None:
    d = runs["dir"]
    lazy = [x for r in _doc(d, "lazy", "results.json")["runs"] for x in r["results"]]
    full = [x for r in _doc(d, "full", "results.json")["runs"] for x in r["results"]]
    assert len(lazy) == len(full) == 1
    for a, b in zip(lazy, full, strict=True):
        assert (a["design"], a["property"], a["verdict"]) == (
            b["design"], b["property"], b["verdict"],
        )  # fmt: skip
        for key in ("optimum", "optimum_certified", "optimum_attack"):
            assert a[key] == pytest.approx(b[key], rel=1e-6), key
    pays = [x["payoff"] for x in _detections(d, "lazy")]
    assert pays == pytest.approx([x["payoff"] for x in _detections(d, "full")], rel=1e-6)


def test_fewer_detections_certified_on_demand(runs: dict[str, Any]) -> None:
    d = runs["dir"]
    lazy, full = _detections(d, "lazy"), _detections(d, "full")
    assert runs["n_full"] == len(full)  # up front: every detection, once
    assert all(x.get("payoff_lower") is not None for x in full)
    bounded = [(a["payoff_lower"], b["payoff_lower"]) for a, b in zip(lazy, full, strict=True)
               if a.get("payoff_lower") is not None]  # fmt: skip
    assert 0 < runs["n_lazy"] == len(bounded) < len(full), (runs["n_lazy"], len(full))
    for got, want in bounded:  # each bound its own: the up-front one
        assert got == pytest.approx(want, rel=1e-6, abs=1e-9)
    cert = _doc(d, "lazy", "results.json")["perception"]["certified"]
    assert (cert["detections"], cert["of"]) == (len(bounded), len(full))
    assert f"certifying {len(bounded)} of {len(full)} detections through" in runs["lazy"].stderr
