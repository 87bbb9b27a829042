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

Injection (issue 61; docs/detectors.md, "Injection candidates") is the same attack
the other way (``towards="inject"``) on a local maximum below the threshold at cell
(i, j): its margin is the cell's raw output − the larger of the threshold's raw
value and the square's other cells (each a little raised, :data:`SLACK`), > 0 once
the cell decodes as a detection; same crop, same settings, same validation by
decoding the perturbed frame, which must then hold a detection at (i, j).
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
from lesmc.perception.attacks import Towards, payoffs
from lesmc.perception.detector_file import LoadedDetector
from lesmc.perception.heatmap import HeatmapDetections, decode
from lesmc.perception.heatmap_crop import ConvNet, conv_net, same_cells
from lesmc.perception.net_ops import Unsupported

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
    out = det.score_maps(det.net.module(x))
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


def _margin(
    out: torch.Tensor, t: float, cell: tuple[int, int] | None, slack: float
) -> torch.Tensor:
    """(B,) the margin of a square's (B, h, w) raw cells: hiding (``cell`` None), the
    largest cell − ``t``, > 0 while some cell is a detection's; injecting at ``cell`` (its
    place in the square), the cell − max(``t``, every other cell + ``slack``), > 0 once it
    is one."""
    if cell is None:
        return out.flatten(1).amax(dim=1) - t
    ci, cj = cell
    mask = torch.zeros(out.shape[1:], dtype=torch.bool)
    mask[ci, cj] = True
    others = torch.where(mask, torch.full_like(out, -math.inf), out).flatten(1).amax(dim=1)
    return out[:, ci, cj] - torch.clamp(others + slack, min=t)


class _Hide(nn.Module):
    """The margin of one detection (or candidate: ``cell``, :func:`_margin`) as two
    "logits" ``[0, m]`` of a crop in [0, 1] units: ``m`` = the largest raw output of the
    square − the threshold's raw value, > 0 while some cell of the square is a
    detection's (attacks.margin with t = 0)."""

    def __init__(
        self, det: LoadedDetector, frame: torch.Tensor, box: tuple[int, int, int, int],
        square: tuple[int, int, int, int], raw_threshold: float,
        cell: tuple[int, int] | None = None, slack: float = 0.0,
    ) -> None:  # fmt: skip
        super().__init__()
        self.det, self.frame, self.box, self.square = det, frame, box, square
        self.t, self.cell, self.slack = raw_threshold, cell, slack

    def full(self, crop_u: torch.Tensor) -> torch.Tensor:
        """The whole input with the crop (in [0, 1] units) put in."""
        lo, hi = self.det.spec.scale
        y0, y1, x0, x1 = self.box
        x = self.frame.expand(len(crop_u), -1, -1, -1).clone()
        x[:, :, y0:y1, x0:x1] = lo + (hi - lo) * crop_u
        return x

    def forward(self, crop_u: torch.Tensor) -> torch.Tensor:
        out = self.det.score_maps(self.det.net.module(self.full(crop_u)))
        i0, i1, j0, j1 = self.square
        m = _margin(out[:, i0:i1, j0:j1], self.t, self.cell, self.slack)
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
    return price_cells(p, frame, fd.cells, fd.index, save)


def price_cells(
    p: Pricing,
    frame: np.ndarray,
    cells: np.ndarray,
    index: int,
    save: Callable[[int, np.ndarray], None] | None = None,
) -> np.ndarray:
    """:func:`price_frame` of some of frame ``index``'s detections, their (n, 2) ``cells``
    (row, col): what ``lesmc verify`` prices on demand (lesmc/experiment/detector_verify.py).
    Each detection's attack and validation are its own (crops of one shape share a batch),
    so a detection priced with others of its frame gets its payoff up to float32 rounding."""
    return _price(p, frame, cells, index, "hide", save)


def price_candidates(
    p: Pricing,
    frame: np.ndarray,
    fd: HeatmapDetections,
    save: Callable[[int, np.ndarray], None] | None = None,
) -> np.ndarray:
    """Each injection candidate of ``fd`` (``fd.cand_cells``): the price of injecting it,
    the norm of the smallest perturbation found after which the decoded frame has a
    detection at its cell; ``inf`` when none is found. ``save(i, delta)`` gets the
    perturbation of candidate ``i`` (its place in ``fd.cand_cells``)."""
    return _price(p, frame, fd.cand_cells, fd.index, "inject", save)


def _price(
    p: Pricing,
    frame: np.ndarray,
    cells: np.ndarray,
    index: int,
    towards: Towards,
    save: Callable[[int, np.ndarray], None] | None,
) -> np.ndarray:
    """:func:`price_frame` (``towards="hide"``) or :func:`price_candidates` (``"inject"``)
    of the (n, 2) ``cells`` of frame ``index``."""
    det = p.det
    out = np.full(len(cells), np.inf)
    t = raw_threshold(det)
    if not math.isfinite(t) or not len(cells):  # nothing is ever a detection, or all is
        return out
    slack = SLACK * max(1.0, abs(t))
    aim = _Aim(t - slack if towards == "hide" else t + slack, towards, slack)
    found: list[Found] = []
    on_frame = list(range(len(cells)))
    if p.conv is not None:
        on_frame = _price_crops(p, p.conv, frame, cells, aim, found)
    for k in on_frame:
        _price_on_frame(p, frame, cells, k, aim, found)
    _validate(p, frame, cells, index, towards, found, out, save)
    return out


@dataclass(frozen=True)
class _Aim:
    """What an attack aims at: the raw threshold ``t`` it drives the margin past (lowered
    by the slack to hide, raised to inject), its direction, and the slack."""

    t: float
    towards: Towards
    slack: float

    def cell(self, i: int, j: int, square: tuple[int, int, int, int]) -> tuple[int, int] | None:
        """Cell (i, j)'s place in its ``square`` when injecting (None when hiding)."""
        return None if self.towards == "hide" else (i - square[0], j - square[2])


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
    cells: np.ndarray,
    aim: _Aim,
    found: list[Found],
) -> list[int]:
    """The attack on each detection's crop (module docstring), detections whose crops
    have one shape attacked as one batch; adds to ``found``. The detections whose crop does
    not compute the whole frame's cells (none, for a fully convolutional network)."""
    det = p.det
    lo, hi = det.spec.scale
    with torch.no_grad():
        full = det.score_maps(det.net.module(torch.from_numpy(frame)))[0]
    scale = float(full.abs().max())
    s = conv.stride
    groups: dict[tuple[int, ...], list[tuple[int, tuple[int, int, int, int]]]] = {}
    for k, (i, j) in enumerate(cells):
        i0, i1, j0, j1 = _square(det, int(i), int(j))
        y0, y1 = conv.crop(i0, i1 - 1, det.height)
        x0, x1 = conv.crop(j0, j1 - 1, det.width)
        at = aim.cell(int(i), int(j), (i0, i1, j0, j1)) or ()
        key = (y1 - y0, x1 - x0, i0 - y0 // s, i1 - y0 // s, j0 - x0 // s, j1 - x0 // s, *at)
        groups.setdefault(key, []).append((k, (y0, y1, x0, x1)))
    rest: list[int] = []
    for (_h, _w, a0, a1, b0, b1, *rel), items in groups.items():
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
        cell = (rel[0], rel[1]) if rel else None
        hide = _CropHide(conv, (a0, a1, b0, b1), aim.t, (lo, hi), cell, aim.slack)
        res = payoffs(hide, crop_u, 0.5, replace(p.cfg, norm="l2"), aim.towards)
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
    cells: np.ndarray,
    k: int,
    aim: _Aim,
    found: list[Found],
) -> None:
    """Detection ``k``'s attack with the network run on the whole frame at each step, the
    crop of its measured receptive field perturbed; adds to ``found``."""
    det = p.det
    lo, hi = det.spec.scale
    i, j = (int(v) for v in cells[k])
    square, box = _square_and_box(det, i, j, p.field)
    y0, y1, x0, x1 = box
    cell = aim.cell(i, j, square)
    hide = _Hide(det, torch.from_numpy(frame), box, square, aim.t, cell, aim.slack)
    crop_u = ((frame[:, :, y0:y1, x0:x1] - lo) / (hi - lo)).astype(np.float32)
    res = payoffs(hide, crop_u, 0.5, replace(p.cfg, norm="l2"), aim.towards)
    if not bool(res.flipped[0]):
        return
    delta = np.zeros_like(frame)
    delta[:, :, y0:y1, x0:x1] = np.float32(hi - lo) * res.perturbation
    found.append(Found(k, delta, None))


def _validate(
    p: Pricing,
    frame: np.ndarray,
    cells: np.ndarray,
    index: int,
    towards: Towards,
    found: list[Found],
    out: np.ndarray,
    save: Callable[[int, np.ndarray], None] | None,
) -> None:
    """A perturbation's norm is its detection's payoff when decoding the whole perturbed
    frame shows no detection in the detection's square (else the detection stays
    unattackable); a candidate's (``towards="inject"``), when it shows a detection at the
    candidate's cell. Perturbations that cannot touch each other's decoding
    (:func:`_apart`) are added into one frame and decoded together: each square then
    decodes exactly as with its own perturbation alone."""
    for group in _apart(p, cells, found):
        x = frame + sum((f.delta for f in group), np.zeros_like(frame))
        got = _decoded_cells(p.det, x, index)
        for f in group:
            i, j = (int(v) for v in cells[f.k])
            if towards == "inject":
                if not ((got[:, 0] == i) & (got[:, 1] == j)).any():
                    continue
            else:
                i0, i1, j0, j1 = _square(p.det, i, j)
                inside = (got[:, 0] >= i0) & (got[:, 0] < i1) & (got[:, 1] >= j0)
                if (inside & (got[:, 1] < j1)).any():
                    continue
            out[f.k] = float(np.sqrt((f.delta.astype(np.float64) ** 2).sum()))
            if save is not None:
                save(f.k, f.delta)


def _apart(p: Pricing, cells: np.ndarray, found: list[Found]) -> list[list[Found]]:
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
        i, j = (int(v) for v in cells[f.k])
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
        scale: tuple[float, float], cell: tuple[int, int] | None = None, slack: float = 0.0,
    ) -> None:  # fmt: skip
        super().__init__()
        self.conv, self.square, self.t, self.scale = conv, square, raw_threshold, scale
        self.cell, self.slack = cell, slack

    def forward(self, crop_u: torch.Tensor) -> torch.Tensor:
        lo, hi = self.scale
        a0, a1, b0, b1 = self.square
        out = self.conv(lo + (hi - lo) * crop_u)[:, a0:a1, b0:b1]
        m = _margin(out, self.t, self.cell, self.slack)
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
    return decode(det.score_maps(y)[0].double().numpy(), det, index).cells


def saver(
    directory: str, index: int, keys: np.ndarray | None = None
) -> Callable[[int, np.ndarray], None]:
    """``save(K, delta)`` writing ``DIR/FRAME_K.npy`` (frame ``index``), atomically; with
    ``keys`` (injection candidates' K, :func:`price_candidates`), ``save(i, delta)``
    writing candidate ``i``'s ``DIR/FRAME_cK.npy``, K = ``keys[i]``."""
    import io

    from lesmc.common.files import atomic_write_bytes

    def save(k: int, delta: np.ndarray) -> None:
        buf = io.BytesIO()
        np.save(buf, delta.astype(np.float32), allow_pickle=False)
        name = f"{k}" if keys is None else f"c{int(keys[k])}"
        atomic_write_bytes(Path(directory) / f"{index}_{name}.npy", buf.getvalue())

    return save
