"""The model of a multi-target design as arrays (built by lesmc/unfold/multi.py; checked by
lesmc/engines/multi.py): its states, one level per step, and its transitions, each with
the cheapest way to force it (docs/trackers.md, "The multi-target model").

State i is at step ``step[i]``; it holds the target's track id ``tid[i]`` (identity.NONE:
none), whether the target's reference exists there (``ref[i]``) and ``last[i]``, the
target's track id at the last step up to it at which it existed. States are numbered
level by level, so every transition goes from a lower index to a higher one.

Transition t goes from ``src[t]`` to ``dst[t]``. Of the attacker's options that yield it
(detections hidden and, under ``allow inject``, candidates injected), ``payoff[t]`` is
the least sum of payoffs (``by_payoff[t]``: the indices of one such option into the
step's ``names``, detections first, then candidates) and ``count[t]`` the fewest
detections hidden and candidates injected (``by_count[t]``); ``count[t]`` is 0 when the
unattacked outcome yields it.

For the ``dist`` measures, state i holds ``box[i]``, the box of the track whose id is the
target's (``target``: its track's id on the unattacked run; nan where no track has it),
and ``gone[i]``, whether that track was deleted (a deleted track counts as halted);
``refbox[k]`` is the target's reference box at step k (nan: none there).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lesmc.model.kernel import deviation

#: The components of a multi-target design's ``dist`` measures (``on`` names them): a box's
#: centre x, y and its width and height.
COMPONENTS = ("x", "y", "w", "h")


@dataclass(frozen=True)
class MultiModel:
    """A multi-target design's model (see the module's docstring)."""

    step: np.ndarray
    tid: np.ndarray
    ref: np.ndarray
    last: np.ndarray
    src: np.ndarray
    dst: np.ndarray
    payoff: np.ndarray
    count: np.ndarray
    by_payoff: tuple[tuple[int, ...], ...]
    by_count: tuple[tuple[int, ...], ...]
    #: per step: its frame's number and its detections' ids (``FRAME:K`` names)
    frames: tuple[int, ...]
    names: tuple[tuple[str, ...], ...]
    end: int
    window: tuple[int, int]
    box: np.ndarray
    gone: np.ndarray
    refbox: np.ndarray
    target: int
    #: per step: how many of its ``names`` are detections; the rest are its injection
    #: candidates (an index j >= detections[k] in ``by_payoff``/``by_count`` is injected)
    detections: tuple[int, ...] = ()
    #: what it was built for (lesmc/pipeline/multi.py ``build_for``; its file's header,
    #: docs/lts-format.md "Multi-target models"): design, tracker, reference, radius,
    #: actions, the scene's last step, the window's first unpriced detection
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def n_states(self) -> int:
        return int(self.step.shape[0])

    @property
    def n_transitions(self) -> int:
        return int(self.src.shape[0])

    def deviations(self, components: tuple[int, ...], norm: float) -> np.ndarray:
        """Each state's ``dist.at``: Eq. 4 between the box of the track with the target's
        id and the reference box at its step, on ``components`` (indices into
        :data:`COMPONENTS`); +inf where that track was deleted (halted), 0 where it or the
        reference does not exist (nothing to compare)."""
        diff = _xywh(self.box) - _xywh(self.refbox[self.step])
        d = deviation(diff[:, list(components)], norm)
        out: np.ndarray = np.where(self.gone, np.inf, np.where(np.isnan(d), 0.0, d))
        return out


def _xywh(b: np.ndarray) -> np.ndarray:
    """Boxes (n, 4) [x1, y1, x2, y2] as (n, 4) centre x, y, width, height."""
    w, h = b[:, 2] - b[:, 0], b[:, 3] - b[:, 1]
    return np.stack([b[:, 0] + w / 2.0, b[:, 1] + h / 2.0, w, h], axis=1)
