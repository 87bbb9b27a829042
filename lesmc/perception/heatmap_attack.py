"""Payoffs of hiding a heatmap detection (docs/detectors.md, "Payoffs").

A detection at cell (i, j) is hidden when every cell of the (2r+1) x (2r+1)
square around it (r = ``nms_radius``) scores below the threshold: then no
detection of the decoded frame lies in that square. The attack
(lesmc/perception/attacks.py: DeepFool or the PGD minimum-norm search, on the
margin ``max over the square of the raw output − the threshold's raw value``)
perturbs only the crop of the frame that the square's receptive fields cover,
and runs the network on that crop alone when its operations make a
:class:`~lesmc.perception.heatmap_crop.ConvNet` (detections whose crops have one
shape in one batch); otherwise the network runs on the whole frame at each step.
Each perturbation is checked by decoding the whole perturbed frame through the
network file (:func:`_validate`): one that leaves a detection in the square is
not a payoff, and the detection is unattackable.

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
from lesmc.perception.graphs import Unsupported
from lesmc.perception.heatmap import HeatmapDetections, decode
from lesmc.perception.heatmap_crop import ConvNet, conv_net, same_cells

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


@dataclass(frozen=True)
class Pricing:
    """How one detector's detections are priced: on crops through its :class:`ConvNet`
    when its operations make one, else on the whole frame; ``field``: a cell's
    :class:`ReceptiveField`, from the ConvNet's layers or measured (:func:`receptive_field`)
    (``why``: the node that made no ConvNet)."""

    det: LoadedDetector
    cfg: AttackConfig
    conv: ConvNet | None
    field: ReceptiveField
    why: str = ""


def pricing(det: LoadedDetector, cfg: AttackConfig) -> Pricing:
    """The pricing of ``det``'s detections with the attack settings ``cfg``."""
    try:
        conv = conv_net(det)
    except Unsupported as exc:
        return Pricing(det, cfg, None, receptive_field(det), str(exc))
    lo, hi = conv.reads(0, 0)  # cell 0's pixels: its field relative to its top-left pixel
    return Pricing(det, cfg, conv, ReceptiveField(lo, hi, lo, hi))


def price_frame(
    p: Pricing,
    frame: np.ndarray,
    fd: HeatmapDetections,
    save: Callable[[int, np.ndarray], None] | None = None,
) -> np.ndarray:
    """Each detection of ``fd`` (frame input ``frame``, (1, C, H, W)): its payoff, ``inf``
    when the attack finds no perturbation that hides it. ``save(K, delta)`` gets each
    hiding perturbation (float32 (1, C, H, W), input units)."""
    det = p.det
    out = np.full(len(fd.cells), np.inf)
    t = raw_threshold(det)
    if not math.isfinite(t) or not len(fd.cells):  # nothing is ever a detection, or all is
        return out
    t_hide = t - SLACK * max(1.0, abs(t))
    found: list[Found] = []
    on_frame = list(range(len(fd.cells)))
    if p.conv is not None:
        on_frame = _price_crops(p, p.conv, frame, fd, t_hide, found)
    for k in on_frame:
        _price_on_frame(p, frame, fd, k, t_hide, found)
    _validate(p, frame, fd, found, out, save)
    return out


@dataclass(frozen=True)
class Found:
    """An attack's perturbation ``delta`` (1, C, H, W) of detection ``k``, nonzero only in
    the crop ``box`` (y0, y1, x0, x1; None: a whole-frame attack's, geometry unknown)."""

    k: int
    delta: np.ndarray
    box: tuple[int, int, int, int] | None


def _price_crops(
    p: Pricing,
    conv: ConvNet,
    frame: np.ndarray,
    fd: HeatmapDetections,
    t: float,
    found: list[Found],
) -> list[int]:
    """The attack on each detection's crop (module docstring), detections whose crops
    have one shape attacked as one batch; adds to ``found``. The detections whose crop does
    not compute the whole frame's cells (none, for a fully convolutional network)."""
    det = p.det
    lo, hi = det.spec.scale
    with torch.no_grad():
        full = det.net.module(torch.from_numpy(frame)).reshape(det.cells)
    scale = float(full.abs().max())
    s = conv.stride
    groups: dict[tuple[int, ...], list[tuple[int, tuple[int, int, int, int]]]] = {}
    for k, (i, j) in enumerate(fd.cells):
        i0, i1, j0, j1 = _square(det, int(i), int(j))
        y0, y1 = conv.crop(i0, i1 - 1, det.height)
        x0, x1 = conv.crop(j0, j1 - 1, det.width)
        key = (y1 - y0, x1 - x0, i0 - y0 // s, i1 - y0 // s, j0 - x0 // s, j1 - x0 // s)
        groups.setdefault(key, []).append((k, (y0, y1, x0, x1)))
    rest: list[int] = []
    for (_h, _w, a0, a1, b0, b1), items in groups.items():
        crops = np.stack([frame[0, :, y0:y1, x0:x1] for _, (y0, y1, x0, x1) in items])
        with torch.no_grad():
            got = conv(torch.from_numpy(crops))[:, a0:a1, b0:b1]
        want = torch.stack([full[y0 // s + a0 : y0 // s + a1, x0 // s + b0 : x0 // s + b1]
                            for _, (y0, _y1, x0, _x1) in items])  # fmt: skip
        exact = same_cells(got, want, scale).numpy()
        rest += [k for (k, _), ok in zip(items, exact, strict=True) if not ok]
        kept = [it for it, ok in zip(items, exact, strict=True) if ok]
        if not kept:
            continue
        crop_u = ((crops[exact] - lo) / (hi - lo)).astype(np.float32)
        hide = _CropHide(conv, (a0, a1, b0, b1), t, (lo, hi))
        res = payoffs(hide, crop_u, 0.5, replace(p.cfg, norm="l2"))
        for n, (k, (y0, y1, x0, x1)) in enumerate(kept):
            if not bool(res.flipped[n]):
                continue
            delta = np.zeros_like(frame)
            delta[0, :, y0:y1, x0:x1] = np.float32(hi - lo) * res.perturbation[n]
            found.append(Found(k, delta, (y0, y1, x0, x1)))
    return rest


def _price_on_frame(
    p: Pricing,
    frame: np.ndarray,
    fd: HeatmapDetections,
    k: int,
    t: float,
    found: list[Found],
) -> None:
    """Detection ``k``'s attack with the network run on the whole frame at each step, the
    crop of its measured receptive field perturbed; adds to ``found``."""
    det = p.det
    lo, hi = det.spec.scale
    i, j = (int(v) for v in fd.cells[k])
    square, box = _square_and_box(det, i, j, p.field)
    y0, y1, x0, x1 = box
    hide = _Hide(det, torch.from_numpy(frame), box, square, t)
    crop_u = ((frame[:, :, y0:y1, x0:x1] - lo) / (hi - lo)).astype(np.float32)
    res = payoffs(hide, crop_u, 0.5, replace(p.cfg, norm="l2"))
    if not bool(res.flipped[0]):
        return
    delta = np.zeros_like(frame)
    delta[:, :, y0:y1, x0:x1] = np.float32(hi - lo) * res.perturbation
    found.append(Found(k, delta, None))


def _validate(
    p: Pricing,
    frame: np.ndarray,
    fd: HeatmapDetections,
    found: list[Found],
    out: np.ndarray,
    save: Callable[[int, np.ndarray], None] | None,
) -> None:
    """A perturbation's norm is its detection's payoff when decoding the whole perturbed
    frame shows no detection in the detection's square (else the detection stays
    unattackable). Perturbations that cannot touch each other's decoding
    (:func:`_apart`) are added into one frame and decoded together: each square then
    decodes exactly as with its own perturbation alone."""
    for group in _apart(p, fd, found):
        x = frame + sum((f.delta for f in group), np.zeros_like(frame))
        got = _decoded_cells(p.det, x, fd.index)
        for f in group:
            i0, i1, j0, j1 = _square(p.det, *(int(v) for v in fd.cells[f.k]))
            inside = (got[:, 0] >= i0) & (got[:, 0] < i1) & (got[:, 1] >= j0) & (got[:, 1] < j1)
            if inside.any():
                continue
            out[f.k] = float(np.sqrt((f.delta.astype(np.float64) ** 2).sum()))
            if save is not None:
                save(f.k, f.delta)


def _apart(p: Pricing, fd: HeatmapDetections, found: list[Found]) -> list[list[Found]]:
    """``found`` in groups (greedily, in order) whose members cannot change what another
    member's square decodes to: the cells a perturbation's crop reaches (those whose
    receptive field meets it) stay outside the cells another's square reads (the square
    widened by ``nms_radius``, the neighbours its cells are compared with), both ways. A
    whole-frame attack's perturbation is a group of its own."""
    if p.conv is None:
        return [[f] for f in found]
    conv, r = p.conv, p.det.spec.nms_radius
    lo0, hi0 = conv.reads(0, 0)
    s = conv.stride
    groups: list[list[tuple[Found, tuple[int, ...], tuple[int, ...]]]] = []
    alone: list[list[Found]] = []
    for f in found:
        if f.box is None:
            alone.append([f])
            continue
        y0, y1, x0, x1 = f.box
        reach = (-((hi0 - y0) // s), (y1 - 1 - lo0) // s, -((hi0 - x0) // s), (x1 - 1 - lo0) // s)
        i, j = (int(v) for v in fd.cells[f.k])
        reads = (i - 2 * r, i + 2 * r, j - 2 * r, j + 2 * r)
        for g in groups:
            if all(not _meet(reach, b) and not _meet(a, reads) for _, a, b in g):
                g.append((f, reach, reads))
                break
        else:
            groups.append([(f, reach, reads)])
    return [[f for f, _, _ in g] for g in groups] + alone


def _meet(a: tuple[int, ...], b: tuple[int, ...]) -> bool:
    """Whether cell ranges ``a`` and ``b`` (row0, row1, col0, col1, inclusive) overlap."""
    return a[0] <= b[1] and b[0] <= a[1] and a[2] <= b[3] and b[2] <= a[3]


class _CropHide(nn.Module):
    """:class:`_Hide` on a crop run through the :class:`ConvNet` alone: the margin of the
    square's cells ``(a0, a1, b0, b1)`` of the crop's output."""

    def __init__(
        self, conv: ConvNet, square: tuple[int, int, int, int], raw_threshold: float,
        scale: tuple[float, float],
    ) -> None:  # fmt: skip
        super().__init__()
        self.conv, self.square, self.t, self.scale = conv, square, raw_threshold, scale

    def forward(self, crop_u: torch.Tensor) -> torch.Tensor:
        lo, hi = self.scale
        a0, a1, b0, b1 = self.square
        out = self.conv(lo + (hi - lo) * crop_u)[:, a0:a1, b0:b1]
        m = out.flatten(1).amax(dim=1) - self.t
        return torch.stack([torch.zeros_like(m), m], dim=1)


def _square(det: LoadedDetector, i: int, j: int) -> tuple[int, int, int, int]:
    """Detection (i, j)'s square: its rows and columns of cells, end exclusive, cut at the
    map's edges."""
    r = det.spec.nms_radius
    rows, cols = det.cells
    return max(0, i - r), min(rows, i + r + 1), max(0, j - r), min(cols, j + r + 1)


def _square_and_box(
    det: LoadedDetector, i: int, j: int, f: ReceptiveField
) -> tuple[tuple[int, int, int, int], tuple[int, int, int, int]]:
    """The cells of detection (i, j)'s square (row and column ranges, end exclusive) and
    the input crop its receptive fields cover, cut at the frame's edges."""
    s = det.spec.stride
    i0, i1, j0, j1 = _square(det, i, j)
    y0, y1 = max(0, i0 * s + f.y0), min(det.height, (i1 - 1) * s + f.y1 + 1)
    x0, x1 = max(0, j0 * s + f.x0), min(det.width, (j1 - 1) * s + f.x1 + 1)
    return (i0, i1, j0, j1), (y0, y1, x0, x1)


def _decoded_cells(det: LoadedDetector, x: np.ndarray, index: int) -> np.ndarray:
    """(n, 2) the detections' cells when the whole frame ``x`` is decoded."""
    with torch.no_grad():
        y = det.net.module(torch.from_numpy(np.ascontiguousarray(x, np.float32)))
    return decode(y.reshape(det.cells).double().numpy(), det, index).cells


def saver(directory: str, index: int) -> Callable[[int, np.ndarray], None]:
    """``save(K, delta)`` writing ``DIR/FRAME_K.npy`` (frame ``index``), atomically."""
    import io

    from lesmc.common.files import atomic_write_bytes

    def save(k: int, delta: np.ndarray) -> None:
        buf = io.BytesIO()
        np.save(buf, delta.astype(np.float32), allow_pickle=False)
        atomic_write_bytes(Path(directory) / f"{index}_{k}.npy", buf.getvalue())

    return save
