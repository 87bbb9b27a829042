"""The ``.pt2`` reader: a ``torch.export`` archive read without unpickling.

``torch.export.load`` unpickles parts of the archive (its docstring says so), and
lesmc never unpickles a file, so :func:`load_pt2` reads the archive itself, refusing
any pickled payload, and hands the parsed graph and raw weights to torch's
deserializer. :func:`from_pt2` makes it a :class:`~lesmc.perception.graphs.UserNet`:
the exported program's module (weights frozen, its errors named by file), and its
aten operations as :class:`~lesmc.perception.net_ops.Op` s for the certified bounds.
A file is opened by its suffix in lesmc/perception/network_file.py.
"""

from __future__ import annotations

import importlib
from typing import Any

import torch
from torch import nn

from lesmc.common.errors import InputError, Location, exception_line
from lesmc.perception.graphs import DYNAMIC_BATCH, UserNet, refuse_nonfinite
from lesmc.perception.net_ops import Op, Unsupported, arith_op, avgpool_op, batchnorm_op, conv_op


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
