"""The tiny heatmap detector file the detector-file tests share (issue 60): a hand-set
two-layer network on H x W frames, exported to ONNX as spot.onnx beside its spot.toml
(tests/test_detector_replay.py, tests/test_campaign_detector.py and the tests that reuse
their videos)."""

from __future__ import annotations

import warnings
from pathlib import Path

import torch
from torch import nn

#: The frames' size: the network is exported for it (only its batch is dynamic).
H, W = 64, 96
#: The property the tests check on the spots: a cheap hiding attack at steps 6..8 breaks it.
SPEC = """property hide_cheap {
    attack window 6..8
    minimize payoff
    subject to dist.max(0..end) > 5
    holds if optimum > 10
    on x, y
}
"""


def write_spot_detector(d: Path, dynamo: bool = False) -> Path:
    """Brightness above a level, blurred: a heatmap of stride 4 (raw scores >= 0), written
    to ``d``/spot.onnx; its detector file ``d``/spot.toml (returned). Exported by torch's
    TorchScript exporter unless ``dynamo``: the same operators (Conv, Relu, Conv) and the
    same outputs bit for bit, seconds faster (tests/test_user_networks.py covers
    networks from the dynamo exporter)."""
    net = nn.Sequential(
        nn.Conv2d(1, 2, 5, stride=2, padding=2), nn.ReLU(),
        nn.Conv2d(2, 1, 3, stride=2, padding=1),
    )  # fmt: skip
    with torch.no_grad():
        g = torch.ones(5, 5) / 25
        net[0].weight[:] = torch.stack([g, -g])[:, None]
        net[0].bias[:] = torch.tensor([-0.2, 0.3])
        net[2].weight.zero_()
        net[2].weight[0, 0] = torch.tensor([[1.0, 2, 1], [2, 4, 2], [1, 2, 1]]) / 4
        net[2].bias[:] = torch.tensor([-0.3])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if not dynamo:
            torch.onnx.export(
                net.eval(), (torch.rand(2, 1, H, W),), d / "spot.onnx", dynamo=False,
                input_names=["x"], dynamic_axes={"x": {0: "batch"}},
            )  # fmt: skip
        else:
            torch.onnx.export(
                net.eval(), (torch.rand(2, 1, H, W),), d / "spot.onnx", dynamo=True,
                dynamic_shapes=({0: torch.export.Dim("batch")},), external_data=False,
            )  # fmt: skip
    toml = d / "spot.toml"
    toml.write_text(
        'kind = "heatmap"\nnetwork = "spot.onnx"\nstride = 4\nthreshold = 0.0\n'
        'score = "raw"\nnms_radius = 2\n'
    )
    return toml


def write_spot_frames(d: Path, faint_below: int) -> Path:
    """12 frames in ``d/frames``: a bright spot moving past a static one (the spots of
    tests/test_detector_replay.py) and a faint spot (grey 90) ``faint_below`` px below the
    moving one: an injection candidate of the spot network."""
    import cv2
    import numpy as np

    fr = d / "frames"
    fr.mkdir()
    for k in range(12):
        img = np.full((H, W), 20, np.uint8)
        x, y = 10 + 6 * k + 0.15 * k * k, 30 + 0.1 * k * k
        cv2.circle(img, (round(x), round(y)), 3, 230, -1)
        cv2.circle(img, (60, 44), 3, 230, -1)
        cv2.circle(img, (round(x), round(y + faint_below)), 3, 90, -1)
        cv2.imwrite(str(fr / f"f{k:02d}.png"), cv2.GaussianBlur(img, (5, 5), 1.0))
    return fr
