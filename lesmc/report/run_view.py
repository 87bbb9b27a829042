"""What the verification report's parts share (lesmc/report/html.py and the modules it draws
with): :class:`RunView`, the accessors over one design run of a results document; a
result's verdict words, CSS class and optimum cell; the payoff words of a document.
"""

from __future__ import annotations

import math

import numpy as np

from lesmc.engines.result import verdict_words
from lesmc.report.text import optimum_cell
from lesmc.results.document import ATTACK_PAYOFF
from lesmc.results.read import ResultsDoc, RunDoc
from lesmc.results.result_doc import Num, ResultDoc


def number(x: Num | None) -> float:
    """A number of the results file ("inf" strings, None) as a float."""
    if x is None:
        return math.nan
    if isinstance(x, str):
        return float(x)  # "inf", "-inf"
    return float(x)


def verdict_of(r: ResultDoc) -> str:
    """A result's verdict word and why (lesmc.engines.result.verdict_words)."""
    replay = None if r.replay is None else r.replay.status
    return verdict_words(r.verdict, r.vacuous, list(r.original_alarms or []), replay)


def status_class(r: ResultDoc) -> str:
    """The CSS class of a result's verdict word: one colour per word."""
    return css_tag(r.status)


def optimum_text(r: ResultDoc) -> str:
    """A result's optimum cell: the value, or its bounds when the search stopped early."""
    known = r.stats.stopped == "finished" and r.optimum != "unknown"
    opt = None if r.optimum == "unknown" else number(r.optimum)
    lower, upper = r.bounds
    return optimum_cell(opt, known, number(lower), number(upper), r.payoffs == "interval")


def css_tag(name: str) -> str:
    """``name`` as a CSS class or HTML id: each character not a letter or digit becomes ``-``."""
    return "".join(ch if ch.isalnum() else "-" for ch in name)


class RunView:
    """Accessors over one run of the results document."""

    def __init__(self, run: RunDoc) -> None:
        self.d = run
        self.name: str = run.label
        self.tag = css_tag(run.design)
        self.paths = run.paths
        self.by_no = {p.no: p for p in self.paths}
        self.states = run.states
        self.props = run.properties
        self.results = run.results
        self.window = run.window
        self.comps = run.model.components
        self.original: int | None = run.original
        self.cex: tuple[int | None, ...] = run.counterexamples
        self.wit: tuple[int | None, ...] = run.witnesses

    def s(self, no: int) -> np.ndarray:
        """The state vectors of path ``no``, step by step (one row a step)."""
        return np.array([self.states[q].s for q in self.by_no[no].states], float)

    def tau(self, no: int) -> np.ndarray:
        """The covariance trace τ of path ``no``, step by step."""
        return np.array([number(self.states[q].tau) for q in self.by_no[no].states])

    def end(self) -> int:
        """The model's last step."""
        return self.d.model.end

    def deviations(self, i: int, role: str) -> np.ndarray:
        """Property ``i``'s dist.at(k), k = 0..end, of its counterexample or witness as the
        check computed them (inf after a halt); the original track's are 0 (Eq. 4)."""
        if role == "original":
            return np.zeros(self.end() + 1)
        r = self.results[i]
        path = r.counterexample if role == "counterexample" else r.witness
        return np.array([number(x) for x in path or ()])

    def adversarial(self, i: int) -> int:
        """Listed tracks that break property ``i`` and that its monitor does not flag."""
        return sum(
            j.admissible and j.violates and not j.alarms for j in (p.judged[i] for p in self.paths)
        )

    def cex_role(self, i: int) -> str:
        """The role of property ``i``'s cheapest path that breaks the system (results'
        ``counterexample``): ``counterexample`` when its objective fails ``holds if``, else
        ``cheapest`` (the property holds: the cheapest such attack costs too much)."""
        r = self.results[i]
        cex = r.is_counterexample
        if cex is None:  # a results file from before lesmc said which
            cex = r.verdict != "holds"
        return "counterexample" if cex else "cheapest"

    def roles(self) -> dict[int, list[tuple[str, int | None]]]:
        """Path number -> (role, property index) pairs: original first, then per property."""
        out: dict[int, list[tuple[str, int | None]]] = {}
        if self.original is not None:
            out.setdefault(self.original, []).append(("original", None))
        for i in range(len(self.props)):
            if self.wit[i] is not None:
                out.setdefault(self.wit[i], []).append(("witness", i))  # type: ignore[arg-type]
            if self.cex[i] is not None:
                out.setdefault(self.cex[i], []).append((self.cex_role(i), i))  # type: ignore[arg-type]
        return out

    def role_text(self, no: int) -> list[str]:
        """Path ``no``'s roles as the tables name them (``P1 counterexample``)."""
        return [
            r if i is None else f"{self.props[i].name} {ROLE_WORDS.get(r, r)}"
            for r, i in self.roles().get(no, [])
        ]


#: A role as tables and legends name it after the property's name.
ROLE_WORDS = {"witness": "ρ*", "cheapest": "cheapest path (holds: not a counterexample)"}


def payoff_words(doc: ResultsDoc) -> str:
    """Where the detections' payoffs came from, in words: the results' ``meta`` says
    (``payoff source``, lesmc/results/document.py); a results file written before it did
    is read as the attack on N_dr when its payoff unit names N_dr."""
    meta = doc.meta
    source = meta.get("payoff source")
    if isinstance(source, str) and source:
        return source
    if "N_dr" in str(meta.get("payoff unit", "")):
        return ATTACK_PAYOFF
    return "as the scene or model gives them (it does not say where they came from)"
