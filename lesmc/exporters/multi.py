"""A multi-target model's property as an MDP (DRN, PRISM): the writers the export registry
(formats.py) calls for a :class:`~lesmc.model.multi.MultiModel`.

The MDP is the single-target export's (lesmc/exporters/drn.py ``prefix_tree``, whose
writers these call): a state is a model state with the constraint's value so far (the
identity measure ``switches`` or ``lost``, or a ``dist`` measure), each transition of the
model is an action whose reward (model ``payoff``) is its objective contribution (the
cheapest hiding's payoff, its count of hidden detections, 1 per attacked frame for
``count.frames``: lesmc/engines/multi.py ``measure_values``, the engine's own numbers), and
every path end whose constraint holds moves to the absorbing state labelled ``violated``.
Then Storm's ``Rmin=? [F "violated"]`` is lesmc's optimum (+inf: no attack).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from lesmc.common.errors import UsageError
from lesmc.common.files import atomic_open
from lesmc.engines.multi import bind_model, measure_values
from lesmc.exporters.drn import drn_text
from lesmc.exporters.prism import prism_text
from lesmc.exporters.request import MDP_MAX_PREFIXES, Request, chosen_property
from lesmc.language.semantics import BoundProperty
from lesmc.model.kernel import COMPARE, aggregate
from lesmc.model.multi import MultiModel


class MultiSpace:
    """What ``prefix_tree`` reads of a property's search space, for a multi-target model:
    the root, each transition's objective and constraint contributions, the leaves (the
    model's last step) and the constraint's test. The objective's value at step 0 is the
    reward of the move to ``violated`` (the tail), so that each path's rewards add up to
    the engine's objective."""

    def __init__(self, model: MultiModel, bp: BoundProperty) -> None:
        self.model, self.bp = model, bp
        self.root = 0
        self.root_con, self.c_con = measure_values(model, bp.constraint, bp.components, bp.norm)
        self.root_obj, self.c_obj = measure_values(model, bp.objective, bp.components, bp.norm)
        self.obj_max = bp.objective.aggregate == "max"
        self.con_max = bp.constraint.aggregate == "max"
        self._order = np.argsort(model.src, kind="stable")
        self._ptr = np.searchsorted(model.src[self._order], np.arange(model.n_states + 1))

    agg = staticmethod(aggregate)

    def is_leaf(self, q: int) -> bool:
        """A path ends at the model's last step."""
        return bool(self.model.step[q] == self.model.end)

    def tail(self, q: int) -> tuple[float, float]:
        """What a leaf adds: the objective's step-0 value, nothing to the constraint."""
        return self.root_obj, -np.inf if self.con_max else 0.0

    def violates(self, con: float) -> bool:
        """The constraint holds for this value (an attack that succeeds)."""
        return bool(COMPARE[self.bp.op](con, self.bp.bound))

    def successors(self, q: int) -> np.ndarray:
        """The transitions out of state ``q``."""
        out: np.ndarray = self._order[self._ptr[q] : self._ptr[q + 1]]
        return out


def write_drn(model: Any, path: str | Path, request: Request) -> dict[str, object]:
    """The DRN writer of a multi-target model (lesmc/exporters/formats.py)."""
    return _write(model, path, request, "drn", drn_text)


def write_prism(model: Any, path: str | Path, request: Request) -> dict[str, object]:
    """The PRISM writer of a multi-target model (lesmc/exporters/formats.py)."""
    return _write(model, path, request, "prism", prism_text)


def multi_property(model: MultiModel, request: Request, fmt: str) -> BoundProperty:
    """The one property of the request's spec an MDP export states, bound to ``model``
    (located errors: a property the engine does not answer, or one the model was not
    built for)."""
    spec = request.spec
    if spec is None:
        raise UsageError(f"--format {fmt} exports a property: give --spec (and --property)")
    return bind_model(model, spec, chosen_property(spec.properties, spec.path, request.prop))


def _write(
    model: Any, path: str | Path, request: Request, fmt: str, text: Any
) -> dict[str, object]:
    assert isinstance(model, MultiModel)
    bp = multi_property(model, request, fmt)
    out, facts = text(
        model, MultiSpace(model, bp), bp, request.max_nodes or MDP_MAX_PREFIXES, request.strict
    )
    with atomic_open(path) as fh:
        fh.write(out)
    return dict(facts)
