"""Detector files: how the user's whole-frame network's outputs become detections.

A detector file (TOML, or JSON by its ``.json`` suffix) names a network file
(``.onnx`` or ``.pt2``, opened by lesmc/perception/network_file.py) and declares how
its output is decoded (docs/detectors.md). :data:`FIELDS` declares every key
once: :func:`read_detector_file` validates by it, and docs/detectors.md's table
is :func:`fields_table`'s text.

Every mistake is an :class:`InputError` at the key's line of the detector file
(``det.toml:4:1: stride: ...``), or naming the network file for what is wrong
inside the network; the CLI exits 2.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lesmc.common.errors import InputError, Location, clipped
from lesmc.common.fields import is_finite, is_int, show
from lesmc.common.files import read_json, read_text, read_toml
from lesmc.common.locations import error_at_keys, key_locations

if TYPE_CHECKING:
    from lesmc.perception.graphs import UserNet

#: The kinds of detector this version decodes (the issue's ``windows`` is not on this path:
#: the window pair is given with --detector/--locator network files).
KINDS = ("heatmap", "boxes")
#: Keys that only one kind reads.
ONLY_FOR = {
    "stride": "heatmap", "nms_radius": "heatmap", "iou_nms": "boxes", "box": "heatmap",
    "size": "heatmap",
}  # fmt: skip
#: What ``size`` may declare: the heatmap's output channels 1 and 2 hold each cell's
#: width and height (input pixels).
SIZES = ("wh",)
#: The output channels a heatmap network with ``size = "wh"`` must have at least: the
#: score map, widths, heights.
SIZE_CHANNELS = 3
#: Largest stride and NMS radius a file may declare (cells; pixels for the stride).
MAX_STRIDE = 1024
MAX_RADIUS = 64
#: Largest magnitude of a scale bound or threshold.
MAX_VALUE = 1e6
#: The side of the square inputs a network of any size is first probed on (pixels; rounded
#: up to a multiple of the stride).
PROBE_SIDE = 64


@dataclass(frozen=True)
class Field:
    """One key of a detector file: whether it must be given, its default, what it may
    hold (``values``, in words for the table and messages) and what it means."""

    name: str
    required: bool
    default: Any
    values: str
    meaning: str
    ok: Callable[[Any], bool]


def _one_of(*names: str) -> Callable[[Any], bool]:
    return lambda v: v in names


def _scale_ok(v: Any) -> bool:
    return (
        isinstance(v, list)
        and len(v) == 2
        and all(is_finite(x) and abs(x) <= MAX_VALUE for x in v)
        and v[0] != v[1]
    )


def _box_ok(v: Any) -> bool:
    """[w, h] within the limits, and a box at every position a scene allows (not 1e-300)."""
    from lesmc.scene.io import MAX_COORD, box_problem

    return (
        isinstance(v, list)
        and len(v) == 2
        and all(is_finite(x) and 0 < x <= MAX_VALUE for x in v)
        and box_problem(MAX_COORD, MAX_COORD, float(v[0]), float(v[1])) is None
    )


def _network_ok(v: Any) -> bool:
    return isinstance(v, str) and v.endswith((".onnx", ".pt2"))


FIELDS: tuple[Field, ...] = (
    Field(
        "kind", True, None, '"heatmap" or "boxes"',
        "How the network's output becomes detections (docs/detectors.md, \"Decoding\").",
        _one_of(*KINDS),
    ),
    Field(
        "network", True, None, "a path ending in .onnx or .pt2",
        "The network file, relative to the detector file's directory: input (B, C, H, W) "
        "floats, dynamic batch B; output (B, 1, H/stride, W/stride) or (B, H/stride, "
        "W/stride) for a heatmap ((B, K, H/stride, W/stride), K >= 3, with size = \"wh\"), "
        "(B, N, 5) rows [x1, y1, x2, y2, score] for boxes.",
        _network_ok,
    ),
    Field(
        "channels", False, "gray", '"gray" or "rgb"',
        "What a frame becomes: C = 1 (grey levels, OpenCV's luma weights) or C = 3 "
        "(red, green, blue in that order).",
        _one_of("gray", "rgb"),
    ),
    Field(
        "scale", False, [0.0, 1.0], f"[lo, hi], finite, lo ≠ hi, each within ±{MAX_VALUE:g}",
        "Pixel value v in 0..255 becomes lo + (hi − lo) · v / 255: the network's input units.",
        _scale_ok,
    ),
    Field(
        "stride", False, None, f"an integer in 1..{MAX_STRIDE} dividing H and W",
        "heatmap (required there): one output cell covers stride × stride input pixels.",
        lambda v: is_int(v) and 1 <= v <= MAX_STRIDE,
    ),
    Field(
        "threshold", True, None, f"a finite number within ±{MAX_VALUE:g}",
        "A detection's score must be ≥ threshold.",
        lambda v: is_finite(v) and abs(v) <= MAX_VALUE,
    ),
    Field(
        "score", False, "raw", '"raw" or "sigmoid"',
        "How an output cell becomes a score: itself, or 1 / (1 + e^−cell).",
        _one_of("raw", "sigmoid"),
    ),
    Field(
        "nms_radius", False, 1, f"an integer in 0..{MAX_RADIUS}",
        "heatmap: r, a detection is a cell ≥ every cell of the (2r+1) × (2r+1) square "
        "around it.",
        lambda v: is_int(v) and 0 <= v <= MAX_RADIUS,
    ),
    Field(
        "iou_nms", False, 0.5, "a number in 0..1",
        "boxes: a box is dropped when its IoU with a box of higher score (or of equal "
        "score, earlier) that is kept is > iou_nms.",
        lambda v: is_finite(v) and 0.0 <= v <= 1.0,
    ),
    Field(
        "box", False, None,
        f"[w, h], two finite numbers > 0, each at most {MAX_VALUE:g} (and wide enough to "
        "stay a box at the largest position a scene allows: at least about 1e-8)",
        "heatmap: the box (width, height in input pixels) centred on every detection and "
        "injection candidate (for a heatmap without size outputs; not with size); "
        "neither given: they are points, which a design that reads boxes (sort) refuses.",
        _box_ok,
    ),
    Field(
        "size", False, None, '"wh"',
        "heatmap: output channel 0 is the score map, channels 1 and 2 hold each cell's "
        "width and height in input pixels; a detection's box is the (w, h) at its peak "
        "cell, centred on it (docs/detectors.md, \"Sizes\"). Not with box.",
        _one_of(*SIZES),
    ),
    Field(
        "output", False, None, "a string",
        "The name of the network's output, checked against the file (ONNX: the graph's "
        "output; .pt2: the exported program's); not given: not checked.",
        lambda v: isinstance(v, str) and 0 < len(v) <= 200,
    ),
    Field(
        "comment", False, None, "a string", "A note for people; not read.",
        lambda v: isinstance(v, str),
    ),
)  # fmt: skip

_BY_NAME = {f.name: f for f in FIELDS}


@dataclass(frozen=True)
class DetectorFile:
    """A validated detector file; ``network`` resolved against the file's directory."""

    path: str
    kind: str
    network: str
    channels: str
    scale: tuple[float, float]
    stride: int  #: heatmap; 0 for boxes
    threshold: float
    score: str
    nms_radius: int  #: heatmap; 0 for boxes
    output: str | None
    iou_nms: float  #: boxes
    #: where each key is in the file (for errors found once the network is read)
    where: dict[str, Location]
    #: heatmap: the declared box (w, h) of every detection and candidate; None: points
    box: tuple[float, float] | None = None
    #: heatmap: ``"wh"``, each detection's box from output channels 1, 2; None: no size
    #: outputs (the declared ``box``, or points)
    size: str | None = None

    @property
    def n_channels(self) -> int:
        """C, the network input's channels."""
        return 3 if self.channels == "rgb" else 1

    def at(self, key: str) -> Location:
        """The location of ``key`` in the file (the file itself when not given)."""
        return self.where.get(key, Location(self.path))

    def describe(self) -> str:
        """The detector in words, for logs and a scene's ``meta.detector``."""
        if self.kind == "boxes":
            return (
                f"the user's boxes detector file {self.path} (network {self.network}, "
                f"{self.channels}, {self.score} score >= {self.threshold:g}, iou_nms "
                f"{self.iou_nms:g})"
            )
        return (
            f"the user's {self.kind} detector file {self.path} (network {self.network}, "
            f"{self.channels}, stride {self.stride}, {self.score} score >= {self.threshold:g}, "
            f"nms_radius {self.nms_radius}{self._box_words()})"
        )

    def _box_words(self) -> str:
        if self.size is not None:
            return f", size {self.size} from output channels 1, 2"
        return "" if self.box is None else f", box {self.box[0]:g}x{self.box[1]:g}"

    def to_meta(self) -> dict[str, Any]:
        """What a scene's ``meta.detector_file`` records: the file and its network, each with
        the sha256 of its bytes (which networks made the scene), and the decoding."""
        from lesmc.common.files import file_sha256

        out: dict[str, Any] = {
            "path": self.path,
            "sha256": file_sha256(self.path),
            "kind": self.kind,
            "network": self.network,
            "network_sha256": file_sha256(self.network),
            "channels": self.channels,
            "scale": list(self.scale),
            "threshold": self.threshold,
            "score": self.score,
        }
        if self.kind == "boxes":
            return out | {"iou_nms": self.iou_nms}
        out |= {"stride": self.stride, "nms_radius": self.nms_radius}
        if self.size is not None:
            out["size"] = self.size
        return out if self.box is None else out | {"box": list(self.box)}


def fields_table() -> str:
    """docs/detectors.md's table of keys, made from :data:`FIELDS`."""
    rows = ["| key | required | default | values | meaning |", "| --- | --- | --- | --- | --- |"]
    for f in FIELDS:
        default = "" if f.default is None else _toml(f.default)
        rows.append(
            f"| `{f.name}` | {'yes' if f.required else 'no'} | {default} | {f.values} | "
            f"{f.meaning} |"
        )
    return "\n".join(rows) + "\n"


def _toml(v: Any) -> str:
    if isinstance(v, str):
        return f'`"{v}"`'
    if isinstance(v, list):
        return "`[" + ", ".join(str(x) for x in v) + "]`"
    return f"`{v}`"


def is_detector_file(path: str) -> bool:
    """Whether ``--detector PATH`` names a detector file (TOML or JSON), not a network."""
    return path.endswith((".toml", ".json"))


def read_detector_file(path: str | Path) -> DetectorFile:
    """A detector file read and validated (the network is not read: :func:`load_detector`)."""
    p = str(path)
    is_json = p.endswith(".json")
    data = read_json(p) if is_json else read_toml(p)
    where = key_locations(p, read_text(p), is_json)
    if not isinstance(data, dict):
        raise InputError(
            "a detector file must be an object of keys (docs/detectors.md)", Location(p)
        )
    problems: list[tuple[str, str]] = []
    for key in data:
        if key not in _BY_NAME:
            known = ", ".join(f.name for f in FIELDS)
            problems.append((key, f"unknown key (the keys: {known})"))
    for f in FIELDS:
        if f.name not in data:
            if f.required:
                problems.append((f.name, f"is missing: {f.values}"))
        elif not f.ok(data[f.name]):
            problems.append((f.name, _bad(f, data[f.name])))
    problems += _kind_keys(data)
    if problems:
        raise _located(p, where, problems)
    v = {f.name: data.get(f.name, f.default) for f in FIELDS}
    network = _resolve(p, v["network"], where)
    lo, hi = (float(x) for x in v["scale"])
    heat = v["kind"] == "heatmap"
    return DetectorFile(
        p, v["kind"], network, v["channels"], (lo, hi), int(v["stride"]) if heat else 0,
        float(v["threshold"]), v["score"], int(v["nms_radius"]) if heat else 0, v["output"],
        float(v["iou_nms"]), where,
        None if v["box"] is None or not heat else (float(v["box"][0]), float(v["box"][1])),
        v["size"] if heat else None,
    )  # fmt: skip


def _kind_keys(data: dict[str, Any]) -> list[tuple[str, str]]:
    """Keys another kind reads, and a heatmap's missing stride (once the kind is valid)."""
    kind = data.get("kind")
    if kind not in KINDS:
        return []
    out = [
        (key, f'applies to kind = "{only}", not "{kind}"')
        for key, only in ONLY_FOR.items()
        if key in data and only != kind
    ]
    if kind == "heatmap" and "stride" not in data:
        out.append(("stride", f"is missing: {_BY_NAME['stride'].values}"))
    if kind == "heatmap" and "size" in data and "box" in data:
        out.append((
            "size", "and box exclude each other: size reads each detection's box from the "
            "network's outputs, box declares one for all (give one of them)",
        ))  # fmt: skip
    return out


def _bad(f: Field, got: Any) -> str:
    if f.name == "kind" and got == "windows":
        return (
            'must be "heatmap" or "boxes", got "windows" (give the window classifier\'s '
            "network files to --detector and --locator)"
        )
    return f"must be {f.values}, got {show(got)}"


def _resolve(path: str, network: str, where: dict[str, Location]) -> str:
    """The network's path, relative to the detector file's directory; it must be a file."""
    p = Path(network)
    full = p if p.is_absolute() else Path(path).parent / p
    if full.is_dir():
        raise _located(
            path,
            where,
            [("network", f"{clipped(str(full), 200)} is a directory, not a network file")],
        )
    if not full.is_file():
        raise _located(path, where, [("network", f"no such file: {clipped(str(full), 200)}")])
    return str(full)


def _located(path: str, where: dict[str, Location], problems: list[tuple[str, str]]) -> InputError:
    """One error listing each ``(key, message)`` at the key's line (the file's name when the
    key is not in it, as for a missing key)."""
    return error_at_keys(path, where, problems)


def located(spec: DetectorFile, key: str, message: str) -> InputError:
    """An error at ``key``'s line of the detector file ``spec``."""
    return _located(spec.path, spec.where, [(key, message)])


# ---------------------------------------------------------------- the network


@dataclass
class LoadedDetector:
    """A detector file with its network, checked against each other."""

    spec: DetectorFile
    net: UserNet
    #: the network file reads any height and width (ONNX exported with dynamic H, W): ``net``
    #: is given the frames' size by :func:`sized`
    any_size: bool = False

    @property
    def height(self) -> int:
        return self.net.in_shape[1]

    @property
    def width(self) -> int:
        return self.net.in_shape[2]

    @property
    def cells(self) -> tuple[int, int]:
        """(rows, cols) of the heatmap."""
        return self.height // self.spec.stride, self.width // self.spec.stride

    def maps(self, y: Any) -> Any:
        """A heatmap network's output ``y`` (a tensor or array, (B, 1, rows, cols), (B, rows,
        cols) or, with ``size = "wh"``, (B, K, rows, cols)) as (B, K, rows, cols): channel
        0 the raw score map; with ``size``, channels 1 and 2 each cell's width and height."""
        rows, cols = self.cells
        return y.reshape(y.shape[0], -1, rows, cols)

    def score_maps(self, y: Any) -> Any:
        """(B, rows, cols): the raw score maps of a heatmap network's output ``y``
        (:meth:`maps`' channel 0; what decoding, pricing and certifying read)."""
        return self.maps(y)[:, 0]


def load_detector(path: str | Path) -> LoadedDetector:
    """A detector file and its network, each checked against the other before any frame:
    the channels, the stride dividing the input, the output's name and shape (a batch of
    :data:`~lesmc.perception.graphs.PROBE_BATCH` random inputs must give one finite
    heatmap each)."""
    spec = read_detector_file(path)  # its fields first: the reader needs no torch
    from lesmc.perception.graphs import ANY_SIZE
    from lesmc.perception.network_file import load_network

    net = load_network(spec.network)
    any_size = net.in_shape[1] == ANY_SIZE
    if any_size:  # checked on a probe size now, on the frames' later (sized)
        side = PROBE_SIDE if spec.kind == "boxes" else -(-PROBE_SIDE // spec.stride) * spec.stride
        net = replace(net, in_shape=(net.in_shape[0], side, side))
    c, h, w = net.in_shape
    if c != spec.n_channels:
        raise located(
            spec, "channels",
            f'"{spec.channels}" makes {spec.n_channels}-channel inputs; the network '
            f"{spec.network} takes {c} channels",
        )  # fmt: skip
    if spec.kind == "heatmap" and (h % spec.stride or w % spec.stride):
        raise located(
            spec, "stride",
            f"{spec.stride} does not divide the network's input, {w}x{h} (width x height)",
        )  # fmt: skip
    if spec.output is not None and spec.output != net.output:
        raise located(
            spec, "output",
            f"the network {spec.network} has no output '{clipped(spec.output, 80)}'; its "
            f"output is '{clipped(net.output, 80)}'",
        )  # fmt: skip
    det = LoadedDetector(spec, net, any_size)
    _probe(det)
    return det


def sized(det: LoadedDetector, width: int, height: int, where: Location) -> LoadedDetector:
    """``det`` reading ``width`` x ``height`` inputs (its network reads any size): the stride
    must divide them (an error at ``where``, the frames, naming the detector file's
    ``stride`` line) and the network must answer them as the file says."""
    if not det.any_size or (width, height) == (det.width, det.height):
        return det
    spec = det.spec
    if spec.kind == "heatmap" and (height % spec.stride or width % spec.stride):
        at = spec.at("stride")
        raise InputError(
            f"the frames are {width}x{height} (width x height); stride {spec.stride} "
            f"({at.path}:{at.line}) does not divide them: the heatmap's cells would not cover "
            "the frame",
            where,
        )
    net = replace(det.net, in_shape=(det.net.in_shape[0], height, width))
    out = LoadedDetector(spec, net, any_size=True)
    _probe(out)
    return out


def _probe(det: LoadedDetector) -> None:
    """The network on :data:`PROBE_BATCH` random inputs in its units: one finite heatmap
    of (H/stride, W/stride) cells each, or (boxes) one finite (N, 5) list of rows each."""
    import torch

    from lesmc.perception.graphs import PROBE_BATCH, answer

    lo, hi = det.spec.scale
    g = torch.Generator().manual_seed(0)
    x = lo + (hi - lo) * torch.rand(PROBE_BATCH, *det.net.in_shape, generator=g)
    y = answer(det.net, x, f"{det.spec.kind} detector")
    shape = tuple(y.shape)
    if det.spec.kind == "boxes":
        if len(shape) != 3 or shape[0] != PROBE_BATCH or shape[2] != 5:
            raise InputError(
                f"the boxes detector must answer a batch of B inputs of {det.width}x"
                f"{det.height} with (B, N, 5) rows [x1, y1, x2, y2, score] ({det.spec.path}); "
                f"on {PROBE_BATCH} inputs it gave {shape}",
                Location(det.net.path),
            )
        return
    rows, cols = det.cells
    if det.spec.size is not None:
        _probe_sizes(det, shape)
    elif shape not in ((PROBE_BATCH, 1, rows, cols), (PROBE_BATCH, rows, cols)):
        more = len(shape) == 4 and shape[0] == PROBE_BATCH and shape[2:] == (rows, cols)
        raise InputError(
            f"the heatmap detector must answer a batch of B inputs of {det.width}x{det.height} "
            f"with (B, 1, {rows}, {cols}) or (B, {rows}, {cols}) cells (stride "
            f"{det.spec.stride}, {det.spec.path}); on {PROBE_BATCH} inputs it gave {shape}"
            + (' (if channels 1, 2 hold widths and heights, declare size = "wh")' if more else ""),
            Location(det.net.path),
        )


def _probe_sizes(det: LoadedDetector, shape: tuple[int, ...]) -> None:
    """A heatmap network with ``size = "wh"`` must answer (B, K, rows, cols), K >=
    :data:`SIZE_CHANNELS` (an error at the file's ``size`` line naming the shape)."""
    from lesmc.perception.graphs import PROBE_BATCH

    rows, cols = det.cells
    ok = len(shape) == 4 and shape[0] == PROBE_BATCH and shape[2:] == (rows, cols)
    if not ok or shape[1] < SIZE_CHANNELS:
        raise located(
            det.spec, "size",
            f'"{det.spec.size}" reads widths and heights from output channels 1 and 2: the '
            f"network {det.spec.network} must answer a batch of B inputs of {det.width}x"
            f"{det.height} with (B, K, {rows}, {cols}) cells, K >= {SIZE_CHANNELS} (channel 0 "
            f"the score map; stride {det.spec.stride}); on {PROBE_BATCH} inputs it gave {shape}",
        )  # fmt: skip


def score_of(raw: Any, how: str) -> Any:
    """An output cell's score (``score`` of the detector file), in float64."""
    import numpy as np

    x = np.asarray(raw, dtype=np.float64)
    if how == "sigmoid":
        with np.errstate(over="ignore"):
            return 1.0 / (1.0 + np.exp(-x))
    return x
