"""The user's detector networks: ``.pt2`` (torch.export) and ``.onnx`` files.

A network file replaces one of the shipped CNNs (``--detector`` for N_dr,
``--locator`` for N_lp). lesmc feeds it the windows it feeds its own (docs/cnn.md):

* detector: (B, m+1, 21, 21) in [0, 1] -> (B, 2) logits, index 1 = vehicle;
* locator: (B, m+1, 45, 45) in [0, 1] -> (B, 15, 15) map of vehicle centres in [0, 1].

What a network is to lesmc (:class:`UserNet`) and the checks every file passes before
the video: the shape of its windows (:func:`check_network`), a probe batch that must
run and answer in finite numbers (:func:`probe`), weights without NaN or infinity
(:func:`refuse_nonfinite`), and, for certified bounds, a chain that computes the
network's own margin (:func:`same_margin`).

Two views of a file are built:

* a torch module for the forward pass and its gradients (DeepFool, PGD): the
  exported program itself for ``.pt2`` (lesmc/perception/pt2_graph.py); for
  ``.onnx`` a small interpreter of the graph in torch (lesmc/perception/onnx_graph.py,
  ``OnnxNet``);
* for certified bounds (detectors only), the network as a sequence of
  :class:`~lesmc.perception.net_ops.Op` s (lesmc/perception/net_ops.py), which
  :func:`~lesmc.perception.ops_to_chain.chain_of_ops` turns into the ``Chain`` of the
  bound propagation (certify.py). A node it cannot express is reported by name.

``load_network``, which opens a file by its suffix, is lesmc/perception/network_file.py.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import torch
from torch import nn

from lesmc.common.errors import InputError, Location, clipped, exception_line
from lesmc.perception.chain import margin_of
from lesmc.perception.net_ops import Op, Unsupported
from lesmc.perception.ops_to_chain import chain_of_ops

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
