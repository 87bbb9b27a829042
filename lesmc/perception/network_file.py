"""A user's network file (``--detector``, ``--locator``, a detector file's network),
opened by its suffix: ``.pt2`` by lesmc/perception/pt2_graph.py, ``.onnx`` by
lesmc/perception/onnx_graph.py (docs/cnn.md, "Your own networks")."""

from __future__ import annotations

from pathlib import Path

from lesmc.common.errors import InputError, Location
from lesmc.perception.graphs import UserNet
from lesmc.perception.onnx_graph import from_onnx
from lesmc.perception.pt2_graph import from_pt2


def load_network(path: str | Path) -> UserNet:
    """A ``.pt2`` or ``.onnx`` network file (by its suffix)."""
    p = str(path)
    if not Path(p).is_file():
        raise InputError("no such network file", Location(p))
    if p.endswith(".pt2"):
        return from_pt2(p)
    if p.endswith(".onnx"):
        return from_onnx(p)
    raise InputError(
        "a network file must be a torch.export archive (.pt2) or ONNX (.onnx)", Location(p)
    )
