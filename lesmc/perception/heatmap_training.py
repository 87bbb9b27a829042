"""Training a small heatmap detector on synthetic WAMI video (``lesmc train --kind heatmap``).

The network is fully convolutional: grey frame in (values 0..1), one raw score per
4 x 4 cell out (stride 4); the detector file reads it with ``score = "sigmoid"``.
Its target is a Gaussian blob (sd 1 cell) at every visible vehicle of the frame's
truth (``lesmc synth``), moving or not: one frame shows no motion. It learns on whole
frames of the training videos with a focal binary cross-entropy, and is validated on
a held-out video: a detection (``peaks`` of lesmc/perception/heatmap.py) is a true
positive when it matches a visible vehicle one to one within ``radius`` pixels.

Everything is seeded: the same seeds give the same weights (on one machine).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from lesmc.perception.heatmap import cell_positions, peaks
from lesmc.perception.quality import truth_frame, visible_counts
from lesmc.video.synth import SynthConfig, frames

Progress = Callable[[str, int, int], None]

STRIDE = 4
SD_CELLS = 1.0  #: the target blob's sd, in cells
NMS_RADIUS = 2


@dataclass(frozen=True)
class HeatmapTrainConfig:
    """Videos, steps and seeds of a heatmap training run."""

    train_seeds: tuple[int, ...] = (101, 102)
    val_seed: int = 103
    frames: int = 16
    width: int = 384
    height: int = 384
    epochs: int = 150
    batch: int = 8
    lr: float = 3e-3
    seed: int = 0
    threshold: float = 0.5
    radius: float = 4.0


@dataclass(frozen=True)
class HeatmapValidation:
    """Held-out detection metrics."""

    frames: int
    vehicles: int
    detections: int
    true_positives: int

    @property
    def recall(self) -> float:
        """True positives over visible vehicles."""
        return self.true_positives / max(1, self.vehicles)

    @property
    def precision(self) -> float:
        """True positives over detections."""
        return self.true_positives / max(1, self.detections)


def heatmap_net() -> nn.Sequential:
    """The network: 4 convolutions, stride 4, 1 raw score channel (about 6k weights)."""
    return nn.Sequential(
        nn.Conv2d(1, 12, 5, stride=2, padding=2),
        nn.ReLU(),
        nn.Conv2d(12, 24, 3, stride=2, padding=1),
        nn.ReLU(),
        nn.Conv2d(24, 16, 3, padding=1),
        nn.ReLU(),
        nn.Conv2d(16, 1, 1),
    )


def visible_vehicles(vehicles: list[dict[str, Any]]) -> np.ndarray:
    """(n, 2) the positions of the frame's vehicles that are not occluded."""
    tf = truth_frame(vehicles)
    out: np.ndarray = tf.positions[~tf.occluded]
    return out


def target(xy: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """(rows, cols) the maximum of a Gaussian blob (peak 1) at each position, in cells."""
    out = np.zeros((rows, cols), np.float32)
    cy = (np.arange(rows) + 0.5) * STRIDE
    cx = (np.arange(cols) + 0.5) * STRIDE
    for x, y in xy:
        g = np.exp(
            -(((cy[:, None] - y) ** 2 + (cx[None, :] - x) ** 2) / (2 * (SD_CELLS * STRIDE) ** 2))
        )
        np.maximum(out, g.astype(np.float32), out=out)
    return out


def video(cfg: HeatmapTrainConfig, seed: int) -> tuple[np.ndarray, list[np.ndarray]]:
    """One synthetic video: (n, H, W) uint8 frames and each frame's visible vehicles."""
    imgs, pos = [], []
    synth = SynthConfig(frames=cfg.frames, width=cfg.width, height=cfg.height, seed=seed)
    for img, ft in frames(synth):
        imgs.append(np.asarray(img, np.uint8))
        pos.append(visible_vehicles(ft.vehicles))
    return np.stack(imgs), pos


def _focal(logits: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """CenterNet's penalty-reduced focal loss, per vehicle (alpha 2, beta 4)."""
    p = torch.sigmoid(logits).clamp(1e-4, 1 - 1e-4)
    pos = (y > 0.99).float()
    lp = -torch.log(p) * (1 - p) ** 2 * pos
    ln = -torch.log(1 - p) * p**2 * (1 - y) ** 4 * (1 - pos)
    return (lp.sum() + ln.sum()) / pos.sum().clamp(min=1.0)


def _peak_targets(xy: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """The blob map with each vehicle's own cell set to exactly 1 (the focal loss's positives)."""
    y = target(xy, rows, cols)
    for x0, y0 in xy:
        i, j = int(y0 // STRIDE), int(x0 // STRIDE)
        if 0 <= i < rows and 0 <= j < cols:
            y[i, j] = 1.0
    return y


def fit(cfg: HeatmapTrainConfig, progress: Progress | None = None) -> nn.Sequential:
    """Train the network on the training videos (seeded)."""
    torch.manual_seed(cfg.seed)
    gen = torch.Generator().manual_seed(cfg.seed)
    rows, cols = cfg.height // STRIDE, cfg.width // STRIDE
    xs: list[np.ndarray] = []
    ys: list[np.ndarray] = []
    for i, s in enumerate(cfg.train_seeds):
        if progress:
            progress("rendering", i, len(cfg.train_seeds))
        imgs, pos = video(cfg, s)
        xs.append(imgs)
        ys.extend(_peak_targets(p, rows, cols) for p in pos)
    x = torch.from_numpy(np.concatenate(xs)).float().div_(255.0)[:, None]
    y = torch.from_numpy(np.stack(ys))[:, None]
    net = heatmap_net()
    last = net[-1]
    assert isinstance(last, nn.Conv2d) and last.bias is not None
    with torch.no_grad():
        last.bias.fill_(-2.2)  # start near score 0.1: the map is mostly background
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    for epoch in range(cfg.epochs):
        if progress:
            progress("training", epoch, cfg.epochs)
        order = torch.randperm(len(x), generator=gen)
        for b in range(0, len(x), cfg.batch):
            idx = order[b : b + cfg.batch]
            xb, yb = x[idx], y[idx]
            if torch.rand((), generator=gen) < 0.5:  # flips keep the roads' directions balanced
                xb, yb = xb.flip(3), yb.flip(3)
            opt.zero_grad()
            loss = _focal(net(xb), yb)
            loss.backward()  # type: ignore[no-untyped-call]
            opt.step()
    return net.eval()


def validate(net: nn.Module, cfg: HeatmapTrainConfig) -> HeatmapValidation:
    """Recall and precision of the decoded detections on the held-out video."""
    imgs, pos = video(cfg, cfg.val_seed)
    with torch.no_grad():
        raw = net(torch.from_numpy(imgs).float().div_(255.0)[:, None])[:, 0].numpy()

    def pairs() -> Iterator[tuple[np.ndarray, np.ndarray]]:
        for r, truth in zip(raw, pos, strict=True):
            score = 1.0 / (1.0 + np.exp(-r.astype(np.float64)))
            yield cell_positions(peaks(score, cfg.threshold, NMS_RADIUS), STRIDE), truth

    got = visible_counts(pairs(), cfg.radius)
    return HeatmapValidation(len(imgs), got.vehicles, got.detections, got.true_positives)


def export(net: nn.Module, cfg: HeatmapTrainConfig, out_dir: Path, history: str) -> list[Path]:
    """Write ``heatmap.onnx`` (dynamic batch, height and width; weights inside) and
    ``heatmap.toml``."""
    import json
    import warnings

    out_dir.mkdir(parents=True, exist_ok=True)
    onnx_path, toml_path = out_dir / "heatmap.onnx", out_dir / "heatmap.toml"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            net,
            (torch.zeros(2, 1, cfg.height, cfg.width),),
            str(onnx_path),
            input_names=["frame"],
            output_names=["heatmap"],
            dynamo=True,
            # any batch, and any height and width (multiples of the stride): a fully
            # convolutional network reads frames of every size (docs/detectors.md)
            dynamic_shapes=(
                {
                    0: torch.export.Dim("batch"),
                    2: torch.export.Dim("height", min=STRIDE),
                    3: torch.export.Dim("width", min=STRIDE),
                },
            ),
            external_data=False,
        )
    toml_path.write_text(
        'kind = "heatmap"\n'
        'network = "heatmap.onnx"\n'
        'channels = "gray"\n'
        "scale = [0.0, 1.0]\n"
        f"stride = {STRIDE}\n"
        f"threshold = {cfg.threshold}\n"
        'score = "sigmoid"\n'
        f"nms_radius = {NMS_RADIUS}\n"
        'output = "heatmap"\n'
        f"comment = {json.dumps(history)}\n"
    )
    return [toml_path, onnx_path]
