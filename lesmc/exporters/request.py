"""What a writer of the export registry (formats.py) is asked for, and what it shares.

The writers (graphs.py, lts_json.py, drn.py, prism.py) import this module, never the
registry that names them, so that the registry can import a writer when it writes
without an import cycle.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from lesmc.language.properties import chosen_property

if TYPE_CHECKING:
    from lesmc.language.properties import SpecFile
    from lesmc.model.arrays import ArrayModel

__all__ = ["DOT_MAX_NODES", "MDP_MAX_PREFIXES", "Request", "Writer", "chosen_property"]

#: The most states a DOT file may have by default: Graphviz lays out a few thousand readably.
DOT_MAX_NODES = 5000
#: The most path prefixes (MDP states) a property's MDP may unfold by default.
MDP_MAX_PREFIXES = 200_000


@dataclass(frozen=True)
class Request:
    """What a writer is asked for besides the model and the file (each format uses
    what it supports; the command line refuses the rest)."""

    spec: SpecFile | None = None
    prop: str | None = None
    strict: bool = False
    roles: Mapping[str, Sequence[int]] | None = None
    max_nodes: int | None = None


#: A writer: writes the model to the path, returns facts for ``lesmc export --json``.
Writer = Callable[["ArrayModel", "str | Path", Request], dict[str, object]]
