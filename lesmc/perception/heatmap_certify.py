"""Certified lower bounds on a heatmap detection's payoff (docs/detectors.md, "Certified
lower bounds").

A detection at cell (i, j) is not hidden while its own cell scores ``>= threshold``
(hidden means every cell of its square scores below). So a radius within which the
peak cell's raw output stays above the threshold's raw value, for every δ of that L2
norm (network input units), is a lower bound on every hiding perturbation's norm, the
attacks' included (they also clip pixels to the scale's range: a subset of the ball).
Sound, and conservative: a neighbour's rise, or the cell dropping below a neighbour,
is not counted as a way to keep the detection.

The bound propagation (certify.py's CROWN search) runs on the peak cell's crop: a
square of ``side`` pixels (the receptive field rounded up to whole cells) that holds
every pixel the cell reads, placed on whole cells and inside the frame
(heatmap_crop.py), so the cell's output there is the whole frame's and no pixel
outside it moves the cell. The network must be a :class:`ConvNet`; another
operation is refused with its node's name.
"""

from __future__ import annotations

import numpy as np
import torch

from lesmc.common.errors import InputError, Location
from lesmc.perception.certify import CertifyConfig, certified_radius
from lesmc.perception.chain import margin_of
from lesmc.perception.detector_file import LoadedDetector
from lesmc.perception.heatmap import HeatmapDetections
from lesmc.perception.heatmap_crop import ConvNet, conv_net, peak_chain, same_cells
from lesmc.perception.net_ops import Unsupported


def certifiable(det: LoadedDetector) -> ConvNet:
    """``det``'s network as a :class:`ConvNet`, or an InputError naming the node that
    certified bounds cannot express."""
    try:
        return conv_net(det)
    except Unsupported as exc:
        raise InputError(
            f"{exc}; certified bounds on a heatmap detector need a fully convolutional "
            "network of convolutions and ReLUs (batch norms, scalings and average pools are "
            "folded in); payoffs from attacks still work (drop --certify)",
            Location(det.net.path),
        ) from None


def crop_side(det: LoadedDetector, conv: ConvNet) -> int:
    """The side of a peak cell's square crop: its receptive field rounded up to whole cells,
    plus a cell (a cell's field does not start on a cell's edge)."""
    s = conv.stride
    side = -(-(conv.field() + s - 1) // s) * s
    if side > min(det.height, det.width):
        raise InputError(
            f"certified bounds need a square crop of {side}x{side} pixels (the receptive "
            f"field, {conv.field()} pixels, on whole cells); the frames are "
            f"{det.width}x{det.height}",
            Location(det.net.path),
        )
    return side


def certify_frame(
    det: LoadedDetector,
    frame: np.ndarray,
    fd: HeatmapDetections,
    upper: np.ndarray | None,
    t: float,
    cfg: CertifyConfig | None = None,
    conv: ConvNet | None = None,
) -> np.ndarray:
    """(n,) each detection's certified lower bound (L2, network input units): its peak
    cell's raw output stays ``> t`` within it. ``upper``: the payoffs found (they steer the
    search, and bound the result: the lower bound is at most the payoff)."""
    return certify_cells(det, frame, fd.cells, upper, t, cfg, conv)


def certify_cells(
    det: LoadedDetector,
    frame: np.ndarray,
    cells: np.ndarray,
    upper: np.ndarray | None,
    t: float,
    cfg: CertifyConfig | None = None,
    conv: ConvNet | None = None,
) -> np.ndarray:
    """:func:`certify_frame` of some of a frame's detections, their (n, 2) ``cells`` (row,
    col): what ``lesmc campaign`` certifies on demand (lesmc/perception/file_pricing.py).
    Each detection's bound is its own (crops of one peak place share a batch)."""
    conv = conv or certifiable(det)
    out = np.zeros(len(cells))
    if not len(cells):
        return out
    side, s = crop_side(det, conv), conv.stride
    with torch.no_grad():
        full = det.score_maps(det.net.module(torch.from_numpy(frame)))[0]
    groups: dict[tuple[int, int], list[tuple[int, int, int]]] = {}
    for k, (i, j) in enumerate(cells):
        y0 = _start(conv.reads(int(i), int(i))[0], s, det.height - side)
        x0 = _start(conv.reads(int(j), int(j))[0], s, det.width - side)
        groups.setdefault((int(i) - y0 // s, int(j) - x0 // s), []).append((k, y0, x0))
    for (pi, pj), items in groups.items():
        chain = peak_chain(conv, side, pi, pj, t)
        crops = np.stack([frame[0, :, y0 : y0 + side, x0 : x0 + side] for _, y0, x0 in items])
        ks = [k for k, _, _ in items]
        want = torch.tensor([float(full[int(cells[k][0]), int(cells[k][1])]) for k in ks])
        with torch.no_grad():
            got = margin_of(chain, torch.from_numpy(crops)) + t
        if not bool(same_cells(got[:, None], want[:, None], float(full.abs().max())).all()):
            raise InputError(
                "certified bounds: lesmc's reading of the network's graph does not compute "
                "its heatmap on a crop (largest difference "
                f"{float((got - want).abs().max()):.3g}); payoffs from attacks still work",
                Location(det.net.path),
            )
        up = None if upper is None else np.asarray(upper, float)[ks]
        r = certified_radius(chain, crops, up, cfg)
        out[ks] = r if up is None else np.minimum(r, up)
    return out


def _start(lo: int, stride: int, last: int) -> int:
    """Where a crop starts on one axis: on a whole cell at or before the first pixel ``lo``
    the cell reads (0 if that is outside the frame), and no later than ``last``."""
    return min(max(0, lo // stride * stride), last)
