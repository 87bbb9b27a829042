"""The attacker's actions, in one registry: name, summary, and which designs take it
(docs/language.md, "Attack actions"; issue 61).

A spec's ``attack window L..U allow A, B`` names the actions the attacker may take at
the window's steps; without ``allow`` it may hide only (:data:`DEFAULT`, the paper's
threat model, section 3.1). The parser checks the names against this registry (an
unknown one is a located error), binding checks that the design takes them
(lesmc/language/semantics.py), the multi-target unfolder applies them
(lesmc/unfold/multi.py), and :func:`docs_table` is the table of docs/language.md.
Adding an action is one :func:`register` call at the end of this file, and its
semantics in the unfolders. The checks of a spec's attack clauses live here too: an
``allow`` list against the registry (:func:`allow_problem`) and an ``inject grid``
within its limits (:func:`grid_problem`); the parser reports what they find at
``FILE:LINE:COL``.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import dataclass

from lesmc.common.numbers import MAX_PAYOFF
from lesmc.language.properties import InjectGrid


@dataclass(frozen=True)
class AttackAction:
    """One registered action: its name in ``allow``, a summary for tables and help, and
    the trackers (lesmc/designs/registry.py's ``tracker`` names) that take it so far
    (``trackers``; None: every design)."""

    name: str
    summary: str
    trackers: frozenset[str] | None = None

    def taken_by(self, tracker: str) -> bool:
        """The tracker ``tracker`` (``single``, ``joint``, ``sort``, ``gnn``) takes it."""
        return self.trackers is None or tracker in self.trackers


_ACTIONS: dict[str, AttackAction] = {}

#: The actions of a spec without ``allow``.
DEFAULT = ("hide",)

#: The most points an ``inject grid`` may have.
MAX_GRID_POINTS = 1000


def register(action: AttackAction) -> None:
    """Declare an action (its name must be new)."""
    if action.name in _ACTIONS:
        raise ValueError(f"attack action {action.name!r} is registered already")
    _ACTIONS[action.name] = action


def names() -> tuple[str, ...]:
    """The registered actions' names, in registration order."""
    return tuple(_ACTIONS)


def get(name: str) -> AttackAction:
    """The action called ``name`` (KeyError: none)."""
    return _ACTIONS[name]


def spelled() -> str:
    """The actions' names as a message lists them: ``hide or inject``."""
    quoted = [f"'{n}'" for n in names()]
    return quoted[0] if len(quoted) == 1 else ", ".join(quoted[:-1]) + " or " + quoted[-1]


def needs_action(word: str | None) -> str:
    """The message for ``allow`` followed by the keyword ``word`` (None: by nothing)."""
    what = f"'{word}' is a keyword, not an action" if word else "no action follows"
    return f"allow needs an action ({spelled()}): {what}"


def allow_problem(
    listed: Sequence[str], keywords: Collection[str], shown: Sequence[str]
) -> tuple[int, str] | None:
    """The first problem of ``allow A, B`` listing ``listed``: the index of the name at
    fault and the message (a keyword of the language, ``keywords``; an action not
    registered; one allowed twice); None: each is registered and named once. ``shown``:
    each name as a message quotes it (clipped)."""
    for i, name in enumerate(listed):
        if name not in _ACTIONS and name in keywords:
            return i, needs_action(name)
        if name not in _ACTIONS:
            return i, f"unknown attack action '{shown[i]}': allow takes {spelled()}"
        if name in listed[:i]:
            return i, f"attack action '{name}' is allowed twice"
    return None


def grid_problem(grid: InjectGrid, written: Sequence[str]) -> tuple[int, str] | None:
    """The first problem of ``inject grid D within R payoff P``: the index of the number at
    fault (0: D, 1: R, 2: P) and the message; D > 0 px, R >= 0 px, 0 <= P <= MAX_PAYOFF
    (lesmc/common/numbers.py, a scene's prices' cap: sums of payoffs stay finite), at most
    :data:`MAX_GRID_POINTS` points (too many: at D). ``written``: D, R and P as the spec
    wrote them (clipped). None: a grid within its limits."""
    d, r, p = written
    checks = (
        (grid.spacing > 0, f"the grid spacing must be positive (px), got {d}"),
        (grid.radius >= 0, f"the grid radius must be at least 0 (px), got {r}"),
        (grid.payoff >= 0, f"an inject payoff must be at least 0, got {p}"),
        (
            grid.payoff <= MAX_PAYOFF,
            f"an inject payoff must be at most {MAX_PAYOFF:g} (a scene's largest payoff), got {p}",
        ),
    )
    for i, (ok, message) in enumerate(checks):
        if not ok:
            return min(i, 2), message
    side = 2 * (grid.radius / grid.spacing) + 1  # the square's points, before counting:
    bound = side * side  # a float product (inf when huge); ** would raise OverflowError
    if bound > 4 * MAX_GRID_POINTS or len(grid.offsets()) > MAX_GRID_POINTS:
        return 0, (
            f"the grid has more than {MAX_GRID_POINTS} points: widen its spacing or "
            "narrow its radius"
        )
    return None


def docs_table() -> str:
    """The Markdown table of docs/language.md, "Attack actions"."""
    rows = ["| action | what the attacker does | designs |", "|---|---|---|"]
    for a in _ACTIONS.values():
        designs = "every design" if a.trackers is None else ", ".join(sorted(a.trackers))
        rows.append(f"| `{a.name}` | {a.summary} | {designs} |")
    return "\n".join(rows) + "\n"


register(
    AttackAction(
        "hide",
        "hides any of the frame's attackable detections, at the sum of their payoffs "
        "(the paper's threat model)",
    )
)
register(
    AttackAction(
        "inject",
        "adds any of the frame's injection candidates (scene format 3), at the sum of "
        "their payoffs (on single only the nearest visible one matters; on joint every "
        "injected one is a detection for every track: docs/semantics.md)",
        trackers=frozenset({"single", "joint", "sort", "gnn"}),
    )
)
