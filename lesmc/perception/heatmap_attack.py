"""Payoffs of hiding a heatmap detection (docs/detectors.md, "Payoffs").

A detection at cell (i, j) is hidden when every cell of the (2r+1) x (2r+1)
square around it (r = ``nms_radius``) scores below the threshold: then no
detection of the decoded frame lies in that square. The attack
(lesmc/perception/attacks.py: DeepFool or the PGD minimum-norm search, on the
margin ``max over the square of the raw output − the threshold's raw value``)
perturbs only the crop of the frame that the square's receptive field covers;
the network still runs on the whole frame (a network read from a file has one
input size). Each perturbation is checked by decoding the perturbed frame
(:func:`~lesmc.perception.heatmap.decode`): one that leaves a detection in the
square is not a payoff, and the detection is unattackable.

The payoff is the L2 norm of the perturbation in the network's input units
(``scale`` of the detector file), computed from the float32 array
``--save-attacks`` writes.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
from torch import nn

from lesmc.perception.attack_settings import AttackConfig
from lesmc.perception.attacks import payoffs
from lesmc.perception.detector_file import LoadedDetector
from lesmc.perception.heatmap import HeatmapDetections, decode

#: The attack drives the square's raw outputs this far (relative) below the threshold, so
#: that another runtime's rounding (onnxruntime's) decodes the perturbed frame alike.
SLACK = 1e-5
#: Random inputs whose gradients find a cell's receptive field.
FIELD_PROBES = 4


@dataclass(frozen=True)
class ReceptiveField:
    """A cell's receptive field, relative to the cell's top-left input pixel
    (row · stride, col · stride): rows y0..y1, columns x0..x1 (inclusive)."""

    y0: int
    y1: int
    x0: int
    x1: int


def receptive_field(det: LoadedDetector) -> ReceptiveField:
    """The input pixels the centre cell's output depends on: where its gradient is not 0
    on any of :data:`FIELD_PROBES` random inputs in the network's units. A fully
    convolutional network's field is the same for every cell away from the edges."""
    lo, hi = det.spec.scale
    g = torch.Generator().manual_seed(0)
    x = lo + (hi - lo) * torch.rand(FIELD_PROBES, *det.net.in_shape, generator=g)
    x.requires_grad_(True)
    rows, cols = det.cells
    ci, cj = rows // 2, cols // 2
    out = det.net.module(x).reshape(FIELD_PROBES, rows, cols)
    (grad,) = torch.autograd.grad(out[:, ci, cj].sum(), x)
    ys, xs = np.nonzero(grad.abs().sum(dim=(0, 1)).numpy())
    s = det.spec.stride
    if not len(ys):  # a constant output: the cell's own pixels
        return ReceptiveField(0, s - 1, 0, s - 1)
    return ReceptiveField(
        int(ys.min()) - ci * s,
        int(ys.max()) - ci * s,
        int(xs.min()) - cj * s,
        int(xs.max()) - cj * s,
    )


class _Hide(nn.Module):
    """The margin of one detection as two "logits" ``[0, m]`` of a crop in [0, 1] units:
    ``m`` = the largest raw output of the square − the threshold's raw value, > 0 while
    some cell of the square is a detection's (attacks.margin with t = 0)."""

    def __init__(
        self, det: LoadedDetector, frame: torch.Tensor, box: tuple[int, int, int, int],
        square: tuple[int, int, int, int], raw_threshold: float,
    ) -> None:  # fmt: skip
        super().__init__()
        self.det, self.frame, self.box, self.square = det, frame, box, square
        self.t = raw_threshold

    def full(self, crop_u: torch.Tensor) -> torch.Tensor:
        """The whole input with the crop (in [0, 1] units) put in."""
        lo, hi = self.det.spec.scale
        y0, y1, x0, x1 = self.box
        x = self.frame.expand(len(crop_u), -1, -1, -1).clone()
        x[:, :, y0:y1, x0:x1] = lo + (hi - lo) * crop_u
        return x

    def forward(self, crop_u: torch.Tensor) -> torch.Tensor:
        rows, cols = self.det.cells
        out = self.det.net.module(self.full(crop_u)).reshape(len(crop_u), rows, cols)
        i0, i1, j0, j1 = self.square
        m = out[:, i0:i1, j0:j1].flatten(1).amax(dim=1) - self.t
        return torch.stack([torch.zeros_like(m), m], dim=1)


def raw_threshold(det: LoadedDetector) -> float:
    """The threshold on the network's raw output (the sigmoid's inverse for ``sigmoid``)."""
    t = det.spec.threshold
    if det.spec.score != "sigmoid":
        return t
    if t <= 0.0:
        return -math.inf
    if t >= 1.0:
        return math.inf
    return math.log(t / (1.0 - t))


def price_frame(
    det: LoadedDetector,
    frame: np.ndarray,
    fd: HeatmapDetections,
    cfg: AttackConfig,
    save: Callable[[int, np.ndarray], None] | None = None,
    field: ReceptiveField | None = None,
) -> np.ndarray:
    """Each detection of ``fd`` (frame input ``frame``, (1, C, H, W)): its payoff, ``inf``
    when the attack finds no perturbation that hides it. ``save(K, delta)`` gets each
    hiding perturbation (float32 (1, C, H, W), input units); ``field``: the network's
    :func:`receptive_field`, if known."""
    field = field or receptive_field(det)
    base = torch.from_numpy(frame)
    lo, hi = det.spec.scale
    out = np.full(len(fd.cells), np.inf)
    t = raw_threshold(det)
    if not math.isfinite(t):  # nothing is ever a detection, or everything always is
        return out
    for k, (i, j) in enumerate(fd.cells):
        square, box = _square_and_box(det, int(i), int(j), field)
        y0, y1, x0, x1 = box
        hide = _Hide(det, base, box, square, t - SLACK * max(1.0, abs(t)))
        crop_u = ((frame[:, :, y0:y1, x0:x1] - lo) / (hi - lo)).astype(np.float32)
        res = payoffs(hide, crop_u, 0.5, replace(cfg, norm="l2"))
        if not bool(res.flipped[0]):
            continue
        delta = np.zeros_like(frame)
        delta[:, :, y0:y1, x0:x1] = np.float32(hi - lo) * res.perturbation
        if _hidden(det, frame + delta, fd.index, square):
            out[k] = float(np.sqrt((delta.astype(np.float64) ** 2).sum()))
            if save is not None:
                save(k, delta)
    return out


def _square_and_box(
    det: LoadedDetector, i: int, j: int, f: ReceptiveField
) -> tuple[tuple[int, int, int, int], tuple[int, int, int, int]]:
    """The cells of detection (i, j)'s square (row and column ranges, end exclusive) and
    the input crop its receptive fields cover, cut at the frame's edges."""
    r, s = det.spec.nms_radius, det.spec.stride
    rows, cols = det.cells
    i0, i1, j0, j1 = max(0, i - r), min(rows, i + r + 1), max(0, j - r), min(cols, j + r + 1)
    y0, y1 = max(0, i0 * s + f.y0), min(det.height, (i1 - 1) * s + f.y1 + 1)
    x0, x1 = max(0, j0 * s + f.x0), min(det.width, (j1 - 1) * s + f.x1 + 1)
    return (i0, i1, j0, j1), (y0, y1, x0, x1)


def _hidden(
    det: LoadedDetector, x: np.ndarray, index: int, square: tuple[int, int, int, int]
) -> bool:
    """Decoding the perturbed frame ``x`` leaves no detection in ``square``."""
    with torch.no_grad():
        y = det.net.module(torch.from_numpy(np.ascontiguousarray(x, np.float32)))
    got = decode(y.reshape(det.cells).double().numpy(), det, index).cells
    i0, i1, j0, j1 = square
    inside = (got[:, 0] >= i0) & (got[:, 0] < i1) & (got[:, 1] >= j0) & (got[:, 1] < j1)
    return not bool(inside.any())


def saver(directory: str, index: int) -> Callable[[int, np.ndarray], None]:
    """``save(K, delta)`` writing ``DIR/FRAME_K.npy`` (frame ``index``), atomically."""
    import io

    from lesmc.common.files import atomic_write_bytes

    def save(k: int, delta: np.ndarray) -> None:
        buf = io.BytesIO()
        np.save(buf, delta.astype(np.float32), allow_pickle=False)
        atomic_write_bytes(Path(directory) / f"{index}_{k}.npy", buf.getvalue())

    return save
