"""Stuck neurons: a hidden unit of N_dr or N_lp that outputs a constant (paper section 9.2).

The paper's future work asks for resilience to failures "in the perception unit (a
neuron that does not function)". A fault ``neuron detector[L, U] = c`` makes unit U
of hidden layer L (0-based: the layers followed by a ReLU, in order) output ``c``
for every input; ``= max`` takes the largest value that unit reaches on the windows
the fault-free network scores in this video (:class:`UnitMaxima`). In a convolution
the unit is a channel: the filter fails at every position.

The faulty network is an ordinary network (:func:`with_stuck_units`): the unit's
weights are zero and its bias is ``c``, so its pre-activation is ``c`` and, as
``c >= 0``, its ReLU outputs ``c`` exactly. Detection, the attacks and the certified
bounds (certify.py reads the same layers) then all run on the faulty network, with
no special case anywhere.
"""

from __future__ import annotations

import copy
import itertools
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch
from torch import nn

from lesmc.perception.cnn import Nets

NetName = Literal["detector", "locator"]


def hidden_layers(module: nn.Module) -> list[tuple[nn.Conv2d | nn.Linear, nn.ReLU]]:
    """The hidden layers of one of lesmc's networks, in order: each convolution or
    linear layer followed by a ReLU, with that ReLU. Empty for a network loaded from a
    graph file (``--detector``/``--locator``), whose layers are not modules."""
    seqs = [getattr(module, n, None) for n in ("features", "head", "body")]
    mods = [m for s in seqs if isinstance(s, nn.Sequential) for m in s]
    mods = [m for m in mods if not isinstance(m, nn.Flatten)]
    return [
        (a, b)
        for a, b in itertools.pairwise(mods)
        if isinstance(a, (nn.Conv2d, nn.Linear)) and isinstance(b, nn.ReLU)
    ]


def layer_sizes(module: nn.Module) -> list[int]:
    """The number of units (channels of a convolution) of each hidden layer."""
    return [
        a.out_channels if isinstance(a, nn.Conv2d) else a.out_features
        for a, _ in hidden_layers(module)
    ]


def network(nets: Nets, name: NetName) -> nn.Module:
    """N_dr for ``detector``, N_lp for ``locator``."""
    return nets.dr if name == "detector" else nets.lp


@dataclass(frozen=True)
class StuckUnit:
    """Unit ``unit`` of hidden layer ``layer`` of ``net`` outputs ``value`` (>= 0)."""

    net: NetName
    layer: int
    unit: int
    value: float


def with_stuck_units(nets: Nets, stuck: Sequence[StuckUnit]) -> Nets:
    """A copy of ``nets`` in which every unit of ``stuck`` outputs its value."""
    faulty = Nets(copy.deepcopy(nets.dr), copy.deepcopy(nets.lp), nets.settings)
    for s in stuck:
        stick(network(faulty, s.net), s.layer, s.unit, s.value)
    return faulty


def stick(module: nn.Module, layer: int, unit: int, value: float) -> None:
    """Make unit ``unit`` of hidden layer ``layer`` of ``module`` output ``value`` (>= 0),
    in place: its weights are zero and its bias is the value, so ReLU(value) = value."""
    if not value >= 0:
        raise ValueError(f"a stuck unit's value must be at least 0, got {value}")
    affine, _ = hidden_layers(module)[layer]
    if affine.bias is None:
        raise ValueError(f"hidden layer {layer} has no bias: its unit cannot be stuck")
    with torch.no_grad():
        affine.weight[unit] = 0.0
        affine.bias[unit] = value


class UnitMaxima:
    """The largest value of every hidden unit of N_dr and N_lp over the windows they
    score while :meth:`recording` (the detector records its fault-free scoring only,
    never an attack's perturbed windows)."""

    def __init__(self, nets: Nets) -> None:
        self.nets = nets
        self.maxima: dict[str, list[np.ndarray]] = {
            name: [np.full(n, -np.inf, np.float32) for n in layer_sizes(network(nets, name))]
            for name in ("detector", "locator")
        }

    @contextmanager
    def recording(self) -> Iterator[None]:
        """Every hidden ReLU's output folded into the maxima while the block runs."""
        handles = []
        for name in ("detector", "locator"):
            layers = hidden_layers(network(self.nets, name))
            for (_, relu), best in zip(layers, self.maxima[name], strict=True):
                handles.append(relu.register_forward_hook(_folding_into(best)))
        try:
            yield
        finally:
            for h in handles:
                h.remove()


def _folding_into(
    best: np.ndarray,
) -> Callable[[nn.Module, tuple[object, ...], torch.Tensor], None]:
    """A forward hook folding a ReLU's per-unit largest output into ``best``."""

    def hook(_mod: nn.Module, _inp: tuple[object, ...], out: torch.Tensor) -> None:
        if len(out):
            dims = [d for d in range(out.dim()) if d != 1]
            np.maximum(best, out.detach().amax(dim=dims).float().numpy(), out=best)

    return hook
