"""The user's detector networks: ``.pt2`` (torch.export) and ``.onnx`` files.

A network file replaces one of the shipped CNNs (``--detector`` for N_dr,
``--locator`` for N_lp). lesmc feeds it the windows it feeds its own (docs/cnn.md):

* detector: (B, m+1, 21, 21) in [0, 1] -> (B, 2) logits, index 1 = vehicle;
* locator: (B, m+1, 45, 45) in [0, 1] -> (B, 15, 15) map of vehicle centres in [0, 1].

Two views of a file are built:

* a torch module for the forward pass and its gradients (DeepFool, PGD): the
  exported program itself for ``.pt2``; for ``.onnx`` a small interpreter of the
  graph in torch (lesmc/perception/onnx_graph.py, ``OnnxNet``);
* for certified bounds (detectors only), the network as a sequence of
  :class:`Op` s, which :func:`chain_of_ops` turns into the ``Chain`` of the bound
  propagation (certify.py). A node it cannot express is reported by name.

Why not the libraries: ``torch.export.load`` unpickles parts of the archive
(its docstring says so), and lesmc never unpickles a file, so :func:`load_pt2`
reads the archive itself, refusing any pickled payload, and hands the parsed
graph and raw weights to torch's deserializer.

The ``.onnx`` reader is lesmc/perception/onnx_graph.py (on this module's :class:`Op` s
and :class:`UserNet`); ``load_network``, which opens a file by its suffix, is
lesmc/perception/network_file.py.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import torch
from torch import nn

from lesmc.common.errors import InputError, Location, clipped, exception_line
from lesmc.perception.chain import Chain, Conv, Dense, margin_of


@dataclass(frozen=True)
class Op:
    """One step of a network as the bound propagation sees it.

    ``kind``: ``center`` (x − mean over C, H, W), ``conv`` (weight, bias, stride,
    padding), ``relu``, ``flatten``, ``linear`` (weight, bias), ``affine``
    (y = scale·x + shift, scale and shift broadcast per channel or scalar),
    ``avgpool`` (kernel, stride). ``node`` and ``op`` name it in the file.
    """

    kind: str
    node: str
    op: str
    params: dict[str, Any] = field(default_factory=dict)


class Unsupported(Exception):
    """A node the bound propagation cannot express: certification is refused, attacks work."""

    def __init__(self, node: str, op: str, why: str = "") -> None:
        super().__init__(f"node '{node}': {op} is not supported by certified bounds{why}")
        self.node, self.op = node, op


#: ``UserNet.in_shape``'s height and width for an ONNX network exported with dynamic H and W
#: (a fully convolutional detector reads frames of any size; docs/detectors.md).
ANY_SIZE = 0


@dataclass
class UserNet:
    """A network loaded from a file: its module, input shape, and its certification view."""

    path: str
    module: nn.Module
    in_shape: tuple[int, int, int]  #: (C, H, W); H = W = ANY_SIZE: dynamic in the file
    ops: list[Op] | Unsupported
    #: the name of its output in the file (ONNX: the graph's; .pt2: the exported program's)
    output: str = ""

    def certifiable_ops(self) -> list[Op]:
        """The ops, or :class:`Unsupported` naming the node that has none."""
        if isinstance(self.ops, Unsupported):
            raise self.ops
        return self.ops

    def chain(self, t: float) -> Any:
        """The detector as the bound propagation sees it (margin threshold ``t``), checked
        against its own forward pass; an unsupported node is an InputError naming it."""
        try:
            chain = chain_of_ops(self.certifiable_ops(), self.in_shape, t)
        except Unsupported as exc:
            raise InputError(
                f"{exc}; payoffs from attacks still work (drop --certify, or --payoffs attack)",
                Location(self.path),
            ) from None
        same_margin(self, chain, t)
        return chain


def same_margin(net: UserNet, chain: Any, t: float) -> None:
    """The chain must compute the network's own margin (a guard against a reading of the
    file's graph that differs from its forward pass): on 64 random windows, to float32
    rounding."""
    x = torch.rand(64, *net.in_shape, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        logits = net.module(x)
        want = logits[:, 1] - logits[:, 0] - t
    got = margin_of(chain, x)
    if not torch.allclose(got, want, rtol=1e-3, atol=1e-3 * float(want.abs().max()) + 1e-4):
        raise InputError(
            "certified bounds: lesmc's reading of the network's graph does not compute its "
            f"forward pass (largest difference {float((got - want).abs().max()):.3g}); "
            "payoffs from attacks still work",
            Location(net.path),
        )


def check_network(net: UserNet, role: str, channels: int, size: int, out: tuple[int, ...]) -> None:
    """The network must take lesmc's windows for its role and answer each with ``out``
    (detector (2,) logits, locator (15, 15) maps), in finite numbers: :func:`probe`."""
    want = (channels, size, size)
    if net.in_shape != want:
        c, h, w = net.in_shape
        size_text = "any height and width" if h == ANY_SIZE else f"{h}x{w}"
        raise InputError(
            f"the {role} takes inputs of {c} channels of {size_text}; lesmc's {role} windows "
            f"are {channels} channels (the m = {channels - 1} previous frames and the current "
            f"one) of {size}x{size} (docs/own-system.md)",
            Location(net.path),
        )
    probe(net, role, out)


#: Windows in the probe batch: more than one, so a batch fixed at 1 inside the graph fails.
PROBE_BATCH = 3


def probe(net: UserNet, role: str, out: tuple[int, ...]) -> None:
    """Run the network once on :data:`PROBE_BATCH` random windows before the video: it
    must run, give one ``out``-shaped answer per window, and finite numbers (a NaN or
    infinite answer would silently accept or reject every window)."""
    x = torch.rand(PROBE_BATCH, *net.in_shape, generator=torch.Generator().manual_seed(0))
    where = Location(net.path)
    y = answer(net, x, role)
    want = (PROBE_BATCH, *out)
    if not isinstance(y, torch.Tensor) or tuple(y.shape) != want:
        got = tuple(y.shape) if isinstance(y, torch.Tensor) else type(y).__name__
        shape = ", ".join(["B", *map(str, out)])
        meaning = {
            "detector": "two logits, index 1 = vehicle",
            "locator": "a map of vehicle centres",
        }
        raise InputError(
            f"the {role} must answer a batch of B windows with ({shape}): "
            f"{meaning.get(role, '')}; on {PROBE_BATCH} windows it gave {got} "
            "(docs/own-system.md)",
            where,
        )
    refuse_nonfinite_answer(net, y, role)


def answer(net: UserNet, x: torch.Tensor, role: str) -> Any:
    """The network's answer to the probe batch ``x``; whatever the graph raises (a reshape
    to a fixed batch, ...) is an InputError naming the file."""
    try:
        with torch.no_grad():
            return net.module(x)
    except InputError:
        raise
    except Exception as exc:
        raise InputError(
            f"the {role} fails on a batch of {len(x)} inputs: {exception_line(exc)}",
            Location(net.path),
        ) from None


def refuse_nonfinite_answer(net: UserNet, y: torch.Tensor, role: str) -> None:
    """A NaN or infinite answer to the probe batch is an InputError naming the file."""
    bad = int((~torch.isfinite(y)).sum())
    if bad:
        raise InputError(
            f"the {role} gives NaN or infinite outputs ({bad} of {y.numel()} on "
            f"{PROBE_BATCH} random inputs)",
            Location(net.path),
        )


def refuse_nonfinite(tensors: Iterable[tuple[str, torch.Tensor]], path: str) -> None:
    """A weight or constant holding NaN or infinity makes every answer NaN or infinite:
    refused, named."""
    for name, t in tensors:
        if isinstance(t, torch.Tensor) and t.is_floating_point():
            bad = int((~torch.isfinite(t)).sum())
            if bad:
                raise InputError(
                    f"weight '{clipped(name, 80)}' holds {bad} NaN or infinite value"
                    f"{'s' if bad > 1 else ''} (of {t.numel()})",
                    Location(path),
                )


#: What lesmc asks of a batch dimension (.pt2 and .onnx alike).
DYNAMIC_BATCH = "export with dynamic_shapes=({0: torch.export.Dim('batch')},) (docs/own-system.md)"


# ---------------------------------------------------------------- .pt2


def load_pt2(path: str) -> Any:
    """An ExportedProgram read without unpickling: every weight and constant must be a
    raw tensor payload (torch.export.save writes them so), the sample inputs are skipped."""
    pkg: Any = importlib.import_module("torch.export.pt2_archive._package")
    from torch._export.serde import schema
    from torch._export.serde.serialize import ExportedProgramDeserializer, _bytes_to_dataclass

    try:
        reader = pkg.PT2ArchiveReader(path)
        names = reader.get_file_names()
    except Exception as exc:  # torch raises RuntimeError for a bad zip, OSError, ...
        raise InputError(f"not a torch.export archive ({exc})", Location(path)) from None
    models = [
        n[len(pkg.MODELS_DIR) : -len(".json")]
        for n in names
        if n.startswith(pkg.MODELS_DIR) and n.endswith(".json")
    ]
    if len(models) != 1:
        raise InputError(f"expected one exported program, found {len(models)}", Location(path))
    name = models[0]
    for legacy in (f"{pkg.WEIGHTS_DIR}{name}.pt", f"{pkg.CONSTANTS_DIR}{name}.pt"):
        if legacy in names:
            raise InputError("a legacy (pickled) archive: export it again", Location(path))
    for fmt in (pkg.WEIGHTS_CONFIG_FILENAME_FORMAT, pkg.CONSTANTS_CONFIG_FILENAME_FORMAT):
        config = pkg._load_payload_config(reader, fmt.format(name))
        for fqn, meta in config.config.items():
            raw = meta.path_name.startswith(
                (pkg.WEIGHT_FILENAME_PREFIX, pkg.TENSOR_CONSTANT_FILENAME_PREFIX)
            )
            if meta.use_pickle or not raw:
                raise InputError(
                    f"'{fqn}' is stored pickled; lesmc never unpickles a file (export plain "
                    "tensors)",
                    Location(path),
                )
    try:
        program = _bytes_to_dataclass(
            schema.ExportedProgram, reader.read_bytes(pkg.MODELS_FILENAME_FORMAT.format(name))
        )
        state = pkg._load_state_dict(reader, name)
        constants = pkg._load_constants(reader, name)
        return ExportedProgramDeserializer().deserialize(program, state, constants, None)
    except InputError:
        raise
    except Exception as exc:
        raise InputError(f"cannot read the exported program ({exc})", Location(path)) from None


def from_pt2(path: str) -> UserNet:
    """A ``.pt2`` file (``torch.export``) as a :class:`UserNet`: its module and its ops for
    the certified bounds (lesmc/perception/network_file.py opens a file by its suffix)."""
    ep = load_pt2(path)
    sig = ep.graph_signature
    if len(sig.user_inputs) != 1:
        raise InputError(
            f"the network must take one input (the window), it takes {len(sig.user_inputs)}",
            Location(path),
        )
    node = next(n for n in ep.graph.nodes if n.op == "placeholder" and n.name == sig.user_inputs[0])
    shape = tuple(node.meta["val"].shape)
    if len(shape) != 4 or not all(isinstance(d, int) for d in shape[1:]):
        raise InputError(f"the input must be (batch, C, H, W), got {shape}", Location(path))
    if isinstance(shape[0], int):
        raise InputError(
            f"the batch dimension is fixed at {shape[0]}: {DYNAMIC_BATCH}", Location(path)
        )
    refuse_nonfinite([*ep.state_dict.items(), *ep.constants.items()], path)
    module = ep.module()
    try:
        ops: list[Op] | Unsupported = _fx_ops(ep)
    except Unsupported as exc:
        ops = exc
    out = sig.user_outputs[0] if len(sig.user_outputs) == 1 else ""
    return UserNet(path, _Frozen(module, path), (shape[1], shape[2], shape[3]), ops, out)


class _Frozen(nn.Module):
    """A loaded module whose weights are constants (no gradients for them); an error of
    its forward pass is an InputError naming the file and the batch's shape."""

    def __init__(self, inner: nn.Module, path: str) -> None:
        super().__init__()
        self.inner = inner
        self.path = path
        for p in inner.parameters():
            p.requires_grad_(False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        try:
            out: torch.Tensor = self.inner(x)
        except Exception as exc:  # the exported program's guards and shape errors
            raise InputError(
                f"the network fails on inputs of shape {tuple(x.shape)}: {exception_line(exc)}",
                Location(self.path),
            ) from None
        return out


def _fx_ops(ep: Any) -> list[Op]:
    """The ops of an exported program's graph (aten operations, one data path)."""
    sig = ep.graph_signature
    tensors: dict[str, torch.Tensor] = {}
    for ph, fqn in sig.inputs_to_parameters.items():
        tensors[ph] = ep.state_dict[fqn].detach()
    for ph, fqn in sig.inputs_to_buffers.items():
        tensors[ph] = (
            ep.state_dict.get(fqn) if fqn in ep.state_dict else ep.constants[fqn]
        ).detach()
    for ph, fqn in sig.inputs_to_lifted_tensor_constants.items():
        tensors[ph] = ep.constants[fqn].detach()
    data = sig.user_inputs[0]
    ops: list[Op] = []
    mean_of: str | None = None
    for n in ep.graph.nodes:
        if n.op in ("placeholder", "output"):
            continue
        name, target = n.name, str(n.target).removeprefix("aten.")
        args = list(n.args)
        srcs = [a.name for a in args if hasattr(a, "name") and a.name not in tensors]
        if target == "mean.dim" and srcs == [data] and list(args[1]) in ([1, 2, 3], [-3, -2, -1]):
            mean_of = name
            continue
        if target == "sub.Tensor" and mean_of is not None and srcs == [data, mean_of] and not ops:
            ops.append(Op("center", name, target))
        elif len(srcs) != 1 or srcs[0] != data:
            raise Unsupported(name, target, " (not on a single data path)")
        else:
            ops.append(_fx_op(name, target, args, tensors))
        data = name
    return ops


def _const(a: Any, tensors: dict[str, torch.Tensor]) -> torch.Tensor | None:
    if hasattr(a, "name"):
        return tensors.get(a.name)
    if isinstance(a, int | float):
        return torch.tensor(float(a))
    return None


def _fx_op(name: str, target: str, args: list[Any], tensors: dict[str, torch.Tensor]) -> Op:
    def t(i: int) -> torch.Tensor | None:
        return _const(args[i], tensors) if len(args) > i and args[i] is not None else None

    def ints(i: int, default: list[int]) -> list[int]:
        v = args[i] if len(args) > i else default
        return [v, v] if isinstance(v, int) else list(v)

    if target in ("relu.default", "relu_.default"):
        return Op("relu", name, target)
    if target == "conv2d.default":
        w = t(1)
        assert w is not None
        b = t(2)
        if (len(args) > 5 and ints(5, [1, 1]) != [1, 1]) or (len(args) > 6 and args[6] != 1):
            raise Unsupported(name, target, " with dilation or groups")
        return conv_op(name, target, w, b, ints(3, [1, 1]), ints(4, [0, 0]))
    if target == "linear.default":
        w, b = t(1), t(2)
        assert w is not None
        return Op(
            "linear",
            name,
            target,
            {"weight": w, "bias": b if b is not None else torch.zeros(w.shape[0])},
        )
    if target == "flatten.using_ints" and list(args[1:]) in ([1], [1, -1], [1, 3]):
        return Op("flatten", name, target)
    if target in ("view.default", "reshape.default") and len(args[1]) == 2:
        return Op("flatten", name, target)  # (batch, features): checked against the forward pass
    if target in ("add.Tensor", "sub.Tensor", "mul.Tensor", "div.Tensor"):
        c = t(1)
        if c is None:
            raise Unsupported(name, target, " with a non-constant operand")
        return arith_op(name, target, target.split(".")[0], c)
    if target in ("_native_batch_norm_legit_no_training.default", "batch_norm.default"):
        return batchnorm_op(name, target, t(1), t(2), t(3), t(4), float(args[-1]))
    if target == "avg_pool2d.default":
        return avgpool_op(name, target, ints(1, [1, 1]), ints(2, ints(1, [1, 1])), ints(3, [0, 0]))
    if target == "getitem" or target.endswith("getitem"):
        return Op("identity", name, target)
    if target in ("contiguous.default", "clone.default"):  # a copy, perhaps in another layout
        return Op("identity", name, target)
    raise Unsupported(name, target.split(".")[0])


def conv_op(
    name: str, op: str, w: torch.Tensor, b: torch.Tensor | None, stride: list[int], pad: list[int]
) -> Op:
    """A convolution's op (square kernel, stride and padding only; no bias: zeros), as
    both readers (``.pt2`` here, ``.onnx`` in onnx_graph.py) build it."""
    if w.shape[2] != w.shape[3] or stride[0] != stride[1] or pad[0] != pad[1]:
        raise Unsupported(name, op, " with non-square kernels, strides or padding")
    bias = b if b is not None else torch.zeros(w.shape[0])
    return Op("conv", name, op, {"weight": w, "bias": bias, "stride": stride[0], "padding": pad[0]})


def arith_op(name: str, op: str, how: str, c: torch.Tensor) -> Op:
    """x + c, x − c, x·c or x / c: an affine op (whether c fits is checked when folding);
    both readers build it."""
    c = c.float()
    one, zero = torch.ones_like(c), torch.zeros_like(c)
    scale, shift = {
        "add": (one, c),
        "sub": (one, -c),
        "mul": (c, zero),
        "div": (1.0 / c, zero),
    }[how]
    return Op("affine", name, op, {"scale": scale, "shift": shift})


def batchnorm_op(name: str, op: str, gamma: Any, beta: Any, mean: Any, var: Any, eps: float) -> Op:
    """An inference batch norm as the affine op it is (running statistics needed; no
    ``gamma``/``beta``: 1/0), as both readers build it."""
    if mean is None or var is None:
        raise Unsupported(name, op, " without running statistics")
    g = gamma if gamma is not None else torch.ones_like(mean)
    bt = beta if beta is not None else torch.zeros_like(mean)
    scale = g / torch.sqrt(var + eps)
    return Op(
        "affine",
        name,
        op,
        {"scale": scale[:, None, None], "shift": (bt - mean * scale)[:, None, None]},
    )


def avgpool_op(name: str, op: str, k: list[int], s: list[int], pad: list[int]) -> Op:
    """An average pool's op (square kernel and stride, no padding), as both readers build it."""
    if k[0] != k[1] or s[0] != s[1] or pad != [0, 0]:
        raise Unsupported(name, op, " with non-square kernels or padding")
    return Op("avgpool", name, op, {"kernel": k[0], "stride": s[0]})


# ---------------------------------------------------------------- ops -> Chain


def chain_of_ops(ops: list[Op], in_shape: tuple[int, int, int], t: float) -> Any:
    """The certify.py ``Chain`` of a detector given as ops, with margin ``logit_1 − logit_0 − t``.

    Linear steps between ReLUs are composed exactly: an ``affine`` after a layer
    scales and shifts that layer's outputs, one at the input or after a ReLU is
    moved into the next layer (if that is a convolution, only when it has no
    padding: zero padding does not commute with a shift); an ``avgpool`` is a
    convolution of its own, composed with the layer before it, or with the next
    one when it follows a ReLU.
    """
    built = Layers(channels=in_shape[0], hw=in_shape[1])
    for i, op in enumerate(ops):
        if op.kind == "center" and i != 0:
            raise Unsupported(op.node, op.op, " (mean subtraction only first)")
        built.add(op)
    if built.pending:
        raise Unsupported(
            built.pending[0].node, built.pending[0].op, " (after the last linear layer)"
        )
    layers, relu_after = built.layers, built.relu_after
    last = layers[-1] if layers else None
    if not isinstance(last, Dense) or last.weight.shape[0] != 2 or relu_after[-1]:
        raise Unsupported(
            ops[-1].node if ops else "-",
            ops[-1].op if ops else "-",
            " (a detector must end in a linear layer with two logits)",
        )
    if not all(relu_after[:-1]):
        bad = ops[-1]
        raise Unsupported(
            bad.node, bad.op, " (every layer but the last must be followed by a ReLU)"
        )
    w, b = last.weight, last.bias
    layers[-1] = Dense((w[1] - w[0])[None], (b[1] - b[0] - t)[None])
    return Chain(in_shape, built.subtract_mean, tuple(layers))


@dataclass
class Layers:
    """The chain's layers as ops arrive: linear ops wait in ``pending`` for the next layer
    when no layer without its ReLU precedes them (:func:`chain_of_ops`; heatmap_crop.py
    builds a crop's chain with it too)."""

    channels: int
    hw: int
    layers: list[Any] = field(default_factory=list)
    relu_after: list[bool] = field(default_factory=list)
    pending: list[Op] = field(default_factory=list)
    subtract_mean: bool = False
    flat: bool = False

    def add(self, op: Op) -> None:
        if op.kind == "identity":
            return
        if op.kind == "center":
            self.subtract_mean = True
        elif op.kind == "relu":
            if not self.layers or self.relu_after[-1] or self.pending:
                raise Unsupported(
                    op.node, op.op, " (a ReLU must follow a convolution or a linear layer)"
                )
            self.relu_after[-1] = True
        elif op.kind == "flatten":
            self.flat = True
        elif op.kind in ("affine", "avgpool"):
            if self.layers and not self.relu_after[-1] and not self.pending:
                self.layers[-1], self.hw = _fold_after(self.layers[-1], op, self.hw)
            else:
                self.pending.append(op)
        elif op.kind == "conv":
            self._conv(op)
        elif op.kind == "linear":
            self._linear(op)
        else:
            raise Unsupported(op.node, op.op)

    def _conv(self, op: Op) -> None:
        if self.flat:
            raise Unsupported(op.node, op.op, " after a flatten")
        w, b, s, p = (op.params[k] for k in ("weight", "bias", "stride", "padding"))
        w, b, s, p, hw_in = _fold_before_conv(self.pending, w.float(), b.float(), s, p, self.hw, op)
        out = (hw_in + 2 * p - w.shape[2]) // s + 1
        self._append(Conv(w, b, s, p, hw_in, out))
        self.hw, self.channels = out, w.shape[0]

    def _linear(self, op: Op) -> None:
        w, b = op.params["weight"].float(), op.params["bias"].float()
        w, b = _fold_before_linear(self.pending, w, b, self.channels, self.hw, op)
        self._append(Dense(w, b))
        self.flat = True

    def _append(self, layer: Any) -> None:
        self.layers.append(layer)
        self.relu_after.append(False)
        self.pending = []


def _pool_as_conv(channels: int, k: int) -> torch.Tensor:
    w = torch.zeros(channels, channels, k, k)
    for c in range(channels):
        w[c, c] = 1.0 / (k * k)
    return w


def _compose(w1: torch.Tensor, s1: int, w2: torch.Tensor, s2: int) -> torch.Tensor:
    """The kernel of conv2 (no padding, stride s2) after conv1 (stride s1), no biases."""
    o2, _, k2, _ = w2.shape
    _, c1, k1, _ = w1.shape
    k = k1 + (k2 - 1) * s1
    out = torch.zeros(o2, c1, k, k, dtype=torch.float64)
    a, b = w1.double(), w2.double()
    for u in range(k2):
        for v in range(k2):
            # conv2 tap (u, v) reads conv1's output at offset (u, v)·s1
            out[:, :, u * s1 : u * s1 + k1, v * s1 : v * s1 + k1] += torch.einsum(
                "om,mi...->oi...", b[:, :, u, v], a
            )
    return out.float()


def _fold_after(layer: Any, op: Op, hw: int) -> tuple[Any, int]:
    """``op`` applied to ``layer``'s output, composed into the layer."""
    if op.kind == "affine":
        scale, shift = op.params["scale"].float(), op.params["shift"].float()
        n = layer.weight.shape[0]
        sc, sh = _per_output(scale, n, op), _per_output(shift, n, op)
        shape = (-1,) + (1,) * (layer.weight.dim() - 1)
        w = layer.weight * sc.reshape(shape)
        b = layer.bias * sc + sh
        if isinstance(layer, Conv):
            return Conv(w, b, layer.stride, layer.padding, layer.in_hw, layer.out_hw), hw
        return Dense(w, b), hw
    if not isinstance(layer, Conv):
        raise Unsupported(op.node, op.op, " after a linear layer")
    k, s = op.params["kernel"], op.params["stride"]
    w = _compose(layer.weight, layer.stride, _pool_as_conv(layer.weight.shape[0], k), s)
    out = (layer.out_hw - k) // s + 1
    return Conv(w, layer.bias.clone(), layer.stride * s, layer.padding, layer.in_hw, out), out


def _per_output(v: torch.Tensor, n: int, op: Op) -> torch.Tensor:
    flat = v.reshape(-1)
    if flat.numel() == 1:
        return flat.expand(n).clone()
    if flat.numel() == n:
        return flat.clone()
    raise Unsupported(op.node, op.op, f" (a constant of {flat.numel()} values for {n} channels)")


def _fold_before_conv(
    pending: list[Op], w: torch.Tensor, b: torch.Tensor, s: int, p: int, hw: int, conv: Op
) -> tuple[torch.Tensor, torch.Tensor, int, int, int]:
    """Linear ops between a ReLU (or the input) and a convolution, moved into it."""
    for op in reversed(pending):
        if p:
            raise Unsupported(op.node, op.op, f" before the padded convolution '{conv.node}'")
        if op.kind == "affine":
            c = w.shape[1]
            sc, sh = (
                _per_output(op.params["scale"].float(), c, op),
                _per_output(op.params["shift"].float(), c, op),
            )
            b = b + (w * sh[None, :, None, None]).sum(dim=(1, 2, 3))
            w = w * sc[None, :, None, None]
        else:  # avgpool before a convolution without padding
            k, ps = op.params["kernel"], op.params["stride"]
            w = _compose(_pool_as_conv(w.shape[1], k), ps, w, s)
            s = ps * s
    return w, b, s, p, hw


def _fold_before_linear(
    pending: list[Op], w: torch.Tensor, b: torch.Tensor, channels: int, hw: int, lin: Op
) -> tuple[torch.Tensor, torch.Tensor]:
    """Linear ops between a ReLU (or the input) and a linear layer, moved into it."""
    for op in reversed(pending):
        if op.kind == "affine":
            n = w.shape[1]
            sc = op.params["scale"].float()
            sh = op.params["shift"].float()
            per = n // max(channels, 1) if sc.numel() == channels and channels > 1 else 1
            sc_full = (
                sc.reshape(-1).repeat_interleave(per)
                if sc.numel() > 1
                else sc.reshape(-1).expand(n)
            )
            sh_full = (
                sh.reshape(-1).repeat_interleave(per)
                if sh.numel() > 1
                else sh.reshape(-1).expand(n)
            )
            if sc_full.numel() != n or sh_full.numel() != n:
                raise Unsupported(op.node, op.op, f" before the linear layer '{lin.node}'")
            b = b + w @ sh_full
            w = w * sc_full[None, :]
        else:
            k, s = op.params["kernel"], op.params["stride"]
            out = (hw - k) // s + 1
            if w.shape[1] != channels * out * out:
                raise Unsupported(op.node, op.op, f" before the linear layer '{lin.node}'")
            pool = torch.zeros(channels * out * out, channels * hw * hw)
            for c in range(channels):
                for y in range(out):
                    for x in range(out):
                        row = (c * out + y) * out + x
                        for dy in range(k):
                            for dx in range(k):
                                pool[row, (c * hw + y * s + dy) * hw + x * s + dx] = 1.0 / (k * k)
            w = w @ pool
            hw = out
    return w, b
