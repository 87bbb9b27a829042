"""Budgets of the verbs that unfold models (``build``, ``verify``): when to stop, what to say.

A budget (lesmc/common/budget.py) is checked before each batch of states while
a model unfolds and between chunks while it is written. Memory is checked
against what the next steps will need, not only what is held: the model's
arrays may double when they grow, freezing copies them, and writing a .lts
builds one Python object per state and transition (:data:`SAVE_BYTES_PER_ITEM`,
measured with ``benchmarks/bench_unfold.py``'s dense scene: about 360 bytes).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING

from lesmc.common.errors import BudgetError, escape_control

if TYPE_CHECKING:
    from lesmc.common.budget import Budget
    from lesmc.model.arrays import ArrayModel
    from lesmc.model.growing import GrowingModel

#: Bytes that writing a .lts needs per state and per transition (with a margin).
SAVE_BYTES_PER_ITEM = 600


def reserve_bytes(model: GrowingModel | ArrayModel | None) -> int:
    """Memory still to be allocated before ``model`` is written out."""
    if model is None:
        return 0
    items = model.n_states + model.n_transitions
    growing = getattr(model, "capacity_bytes", None)
    copies = growing() + model.nbytes() if growing is not None else 0  # growth, then freeze
    return copies + SAVE_BYTES_PER_ITEM * items


def stop_if_spent(budget: Budget, model: GrowingModel | ArrayModel | None, stage: str) -> None:
    """Raise :class:`BudgetError` (exit 3, nothing written) once ``budget`` is spent."""
    states = 0 if model is None else model.n_states
    reason = budget.exceeded(states, reserve_bytes(model))
    if reason is None:
        return
    from lesmc.common.budget import resident_bytes, show_size

    spent = time.monotonic() - budget.started
    held = show_size(resident_bytes())
    raise BudgetError(
        f"{budget.describe(reason)} ran out while {stage} ({states} states, {spent:.1f} s, "
        f"{held} in use); nothing was written"
    )


def write_model(model: ArrayModel, output: str, budget: Budget) -> None:
    """Write ``model`` as a .lts (atomically), checking ``budget`` between chunks."""
    from lesmc.common.files import write_json
    from lesmc.model.lts_binary import is_binary, save_lts_npz
    from lesmc.model.lts_format import lts_document

    if is_binary(output):  # arrays as they are: one write, nothing to chunk
        stop_if_spent(budget, None, f"writing {escape_control(str(Path(output)))}")
        save_lts_npz(model, output)
        return
    doc = lts_document(model)
    stop_if_spent(budget, None, f"writing {escape_control(str(Path(output)))}")
    write_json(output, doc, on_chunk=lambda: stop_if_spent(budget, None, f"writing {output}"))
