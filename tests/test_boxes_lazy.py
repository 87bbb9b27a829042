"""Box detectors priced on demand, and a campaign's certified payoffs on demand (issue 60,
round 22).

a. ``lesmc verify FRAMES --detector box.toml`` prices a box-list detector's detections
   when a model first reads them, through the one pricer both kinds share
   (lesmc/perception/file_pricing.py): on a tiny video (a spot moving past a static one)
   and a box-list network made here (exported to ONNX), the payoffs priced on demand
   equal those ``lesmc perceive --detector box.toml -o`` prices up front (1e-5), and
   fewer detections are priced than exist. A detection priced alone, or its frame's
   boxes no longer the perceived ones, are checked on the pricer itself.
b. ``lesmc campaign --detector spot.toml --payoffs certified`` bounds only the
   detections its models can hide: their ``payoff_lower`` equal those
   ``lesmc perceive --detector spot.toml --certify`` computes up front for every
   detection (1e-5), and fewer are bounded than exist. A box detector is refused first
   (attack-only), before anything is perceived.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from cli_run import lesmc
from spot_detector import SPEC, H, W, write_spot_detector
from test_campaign_detector import _frames
from torch import nn

pytest.importorskip("onnx")

S = 8  #: one box per S x S cell
LEVEL = 0.15  #: a cell's mean brightness (in [0, 1]) above which its box is a detection
WINDOW = "6..6:2..2"  #: the campaigns' one window, 6..8 (the spec's)


class SpotBoxes(nn.Module):
    """(B, 1, 64, 96) -> (B, 96, 5): per 8x8 cell a 12x12 box on the cell's centre shifted
    by a tanh of its brightness, scored by the cell's mean brightness − :data:`LEVEL`."""

    def __init__(self) -> None:
        super().__init__()
        self.mean = nn.Conv2d(1, 2, S, stride=S)
        with torch.no_grad():
            self.mean.weight[:] = 1.0 / (S * S)
            self.mean.weight[1] *= torch.linspace(-1.0, 1.0, S)[None, :]  # brightness' tilt
            self.mean.bias[:] = torch.tensor([-LEVEL, 0.0])
        ys, xs = torch.meshgrid(torch.arange(H // S), torch.arange(W // S), indexing="ij")
        self.register_buffer("cx", ((xs + 0.5) * S).float().reshape(1, -1))
        self.register_buffer("cy", ((ys + 0.5) * S).float().reshape(1, -1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        o = self.mean(x).reshape(-1, 2, (H // S) * (W // S))  # no Shape node
        cx = self.cx + 2.0 * torch.tanh(4.0 * o[:, 1])
        cy = self.cy + 0.0 * cx  # (B, N): no Expand, which lesmc's ONNX reader lacks
        rows = [cx - 6.0, cy - 6.0, cx + 6.0, cy + 6.0, o[:, 0]]
        return torch.stack(rows, dim=2)


def _box_network(d: Path) -> Path:
    with warnings.catch_warnings():  # TorchScript's exporter: seconds, not dynamo's minute
        warnings.simplefilter("ignore")
        torch.onnx.export(
            SpotBoxes().eval(), (torch.rand(2, 1, H, W),), d / "box.onnx", dynamo=False,
            input_names=["x"], dynamic_axes={"x": {0: "batch"}},
        )  # fmt: skip
    toml = d / "box.toml"
    toml.write_text('kind = "boxes"\nnetwork = "box.onnx"\nthreshold = 0.0\nscore = "raw"\n')
    return toml


def _ok(r: Any) -> None:
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr, r.stderr
    assert r.returncode in (0, 1), r.stdout + r.stderr


def _pays(scene: dict[str, Any], key: str = "payoff") -> list[Any]:
    return [x.get(key) for f in scene["frames"] for x in f["detections"]]


def _same(got: Any, want: Any) -> bool:
    if isinstance(got, str) or isinstance(want, str):
        return bool(got == want)
    return abs(float(got) - float(want)) <= 1e-5


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    d = tmp_path_factory.mktemp("boxlazy")
    video = _frames(d, 0)
    (d / "p.spec").write_text(SPEC)
    return {
        "dir": d,
        "video": video,
        "box": _box_network(d),
        "spot": write_spot_detector(d, dynamo=False),
    }


@pytest.fixture(scope="module")
def boxes(made: dict[str, Any]) -> dict[str, Any]:
    d = made["dir"]
    up = lesmc("perceive", str(made["video"]), "--detector", str(made["box"]), "-o",
               str(d / "up.json"))  # fmt: skip
    lazy = lesmc(
        "verify", str(made["video"]), "--detector", str(made["box"]), "--target", "10,30@0",
        "--spec", str(d / "p.spec"), "--design", "single", "--out", str(d / "lazy"),
    )  # fmt: skip
    return {"up": up, "lazy": lazy}


def test_box_payoffs_priced_on_demand_equal_the_up_front_ones(
    made: dict[str, Any], boxes: dict[str, Any]
) -> None:
    assert boxes["up"].returncode == 0, boxes["up"].stderr
    _ok(boxes["lazy"])
    d = made["dir"]
    up = json.loads((d / "up.json").read_text())
    lazy = json.loads((d / "lazy" / "scene.json").read_text())
    assert lazy["meta"]["detector_file"]["kind"] == "boxes"
    where = [(x["x"], x["y"]) for f in lazy["frames"] for x in f["detections"]]
    assert where == pytest.approx([(x["x"], x["y"]) for f in up["frames"] for x in f["detections"]])
    every, pays = _pays(up), _pays(lazy)
    assert "unpriced" not in every
    priced = [(p, q) for p, q in zip(pays, every, strict=True) if p != "unpriced"]
    assert 0 < len(priced) < len(pays), (len(priced), len(pays))
    assert any(isinstance(p, float) for p, _ in priced)  # some detection could be hidden
    for p, q in priced:
        assert _same(p, q), (p, q)
    facts = json.loads((d / "lazy" / "results.json").read_text())["perception"]["detections"]
    assert facts["priced"] == len(priced) and facts["detections"] == len(pays)


def _box_pricing(made: dict[str, Any]) -> Any:
    from lesmc.experiment.detector_verify import file_pricing
    from lesmc.video.reader import open_frames

    frames = open_frames(str(made["video"]), 1, check=False)
    return file_pricing(str(made["box"]), frames)


def test_a_box_priced_alone_gets_its_up_front_payoff(
    made: dict[str, Any], boxes: dict[str, Any]
) -> None:
    assert boxes["up"].returncode == 0, boxes["up"].stderr
    up = json.loads((made["dir"] / "up.json").read_text())
    how = _box_pricing(made)
    k, fr = next((k, f) for k, f in enumerate(up["frames"]) if len(f["detections"]) >= 2)
    pos = np.array([(x["x"], x["y"]) for x in fr["detections"]])
    last = len(pos) - 1
    (got,) = how.price(k, pos, np.array([last]))
    want = fr["detections"][last]["payoff"]
    assert _same("unattackable" if np.isinf(got) else got, want)


def test_boxes_no_longer_the_perceived_ones_are_an_error(made: dict[str, Any]) -> None:
    from lesmc.common.errors import UsageError

    how = _box_pricing(made)
    with pytest.raises(UsageError, match="other boxes"):
        how.price(0, np.array([[1.0, 1.0]]), np.array([0]))


def test_a_campaign_certifies_on_demand_what_perceive_certifies_up_front(
    made: dict[str, Any],
) -> None:
    d = made["dir"]
    up = lesmc("perceive", str(made["video"]), "--detector", str(made["spot"]), "-o",
               str(d / "cert.json"), "--certify")  # fmt: skip
    assert up.returncode == 0, up.stderr
    (d / "targets.txt").write_text("video0 10,30@0\n")
    r = lesmc(
        "campaign", str(made["video"]), "--detector", str(made["spot"]), "--out",
        str(d / "camp"), "--workers", "0", "--spec", str(d / "p.spec"), "--windows", WINDOW,
        "--targets", str(d / "targets.txt"), "--design", "single", "--payoffs", "certified",
    )  # fmt: skip
    _ok(r)
    every = json.loads((d / "cert.json").read_text())
    scene = json.loads((d / "camp" / "scenes" / "video0.json").read_text())
    assert _pays(scene) == pytest.approx(_pays(every), rel=1e-6)  # the same detections
    want, got = _pays(every, "payoff_lower"), _pays(scene, "payoff_lower")
    assert None not in want
    bounded = [(g, w) for g, w in zip(got, want, strict=True) if g is not None]
    assert 0 < len(bounded) < len(got), (len(bounded), len(got))
    for g, w in bounded:
        assert _same(g, w), (g, w)
    cert = scene["meta"]["certified"]
    assert (cert["detections"], cert["of"]) == (len(bounded), len(got))
    assert f"certifying {len(bounded)} of {len(got)} detections" in r.stderr


def test_a_campaign_refuses_a_box_detectors_bounds_before_perceiving(
    made: dict[str, Any],
) -> None:
    d = made["dir"]
    (d / "targets.txt").write_text("video0 10,30@0\n")
    r = lesmc(
        "campaign", str(made["video"]), "--detector", str(made["box"]), "--out",
        str(d / "boxcamp"), "--workers", "0", "--spec", str(d / "p.spec"), "--windows",
        WINDOW, "--targets", str(d / "targets.txt"), "--design", "single", "--payoffs",
        "interval",
    )  # fmt: skip
    assert r.returncode == 2, r.stdout + r.stderr
    assert "Traceback" not in r.stderr
    assert f"{made['box']}:1:1: kind: box-list detectors are attack-only" in r.stderr
    assert "--payoffs certified|interval" in r.stderr
    assert not (d / "boxcamp" / "scenes" / "video0.json").exists()
