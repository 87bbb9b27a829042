"""The attacker's actions, in one registry: name, summary, and which designs take it
(docs/language.md, "Attack actions"; issue 61).

A spec's ``attack window L..U allow A, B`` names the actions the attacker may take at
the window's steps; without ``allow`` it may hide only (:data:`DEFAULT`, the paper's
threat model, section 3.1). The parser checks the names against this registry (an
unknown one is a located error), binding checks that the design takes them
(lesmc/language/semantics.py), the multi-target unfolder applies them
(lesmc/unfold/multi.py), and :func:`docs_table` is the table of docs/language.md.
Adding an action is one :func:`register` call at the end of this file, and its
semantics in the unfolders.
"""

from __future__ import annotations

from dataclasses import dataclass


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
