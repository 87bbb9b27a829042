"""Parse property files (grammars/lesmc.lark) into :class:`Property` objects.

Syntax errors and file-local meaning errors (missing or repeated clauses,
non-finite thresholds, steps beyond :data:`MAX_STEP`, duplicate names) are
raised as :class:`SpecError` with ``FILE:LINE:COL``; checks that need a model
live in :mod:`.semantics`. Lines are counted at ``\n`` only, as lark does
(:func:`lesmc.common.errors.split_lines`); a leading byte-order mark is skipped.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from lark import Tree, UnexpectedInput

from lesmc.common.errors import Location, SpecError, source_line
from lesmc.common.fields import MAX_STEP
from lesmc.common.files import read_text
from lesmc.language import actions, measures, monitors
from lesmc.language.lark_parser import TABLES, lalr_parser, tables_source
from lesmc.language.properties import (
    Constraint,
    Fault,
    FaultSet,
    InjectGrid,
    Measure,
    Monitor,
    Pos,
    Property,
    SpecFile,
    StepRef,
)
from lesmc.language.syntax_errors import clip, keywords, syntax_error

#: Most faults that may strike at once (``budget``): every combination is a check of its own.
MAX_FAULT_BUDGET = 4

_REQUIRED = {
    "window": "'attack window L..U'",
    "objective": "'minimize MEASURE'",
    "constraint": "'subject to MEASURE > NUMBER'",
    "verdict": "'holds if optimum > NUMBER'",
}


def parse_spec(text: str, path: str = "<spec>", need_properties: bool = True) -> SpecFile:
    """Parse the text of a property file; raise :class:`SpecError` on any problem.

    The file may also hold one ``faults { ... }`` block (docs/language.md, "Faults");
    ``need_properties=False`` admits a file of faults alone (``--faults FILE``)."""
    text = text.removeprefix("\ufeff")
    try:
        tree = lalr_parser().parse(text)
    except UnexpectedInput as exc:
        raise syntax_error(exc, text, path) from None
    builder = _Builder(text, path)
    nodes: list[Any] = tree.children
    props = tuple(builder.property(node) for node in nodes if node.data == "property")
    blocks = [node for node in nodes if node.data == "faults_block"]
    if len(blocks) > 1:
        raise builder.error(
            f"a file holds at most one faults block (the first is at line {blocks[0].meta.line})",
            _pos(blocks[1]),
        )
    faults = builder.faults(blocks[0]) if blocks else None
    seen: dict[str, Property] = {}
    for prop in props:
        if prop.name in seen:
            first = seen[prop.name].pos.line
            raise builder.error(
                f"duplicate property name '{prop.name}' (first at line {first})", prop.pos
            )
        seen[prop.name] = prop
    if not props and (need_properties or faults is None):
        what = "no property" if need_properties else "neither a property nor a faults block"
        raise SpecError(f"the file defines {what}", Location(path, 1, 1, source_line(text, 1)))
    return SpecFile(path=path, text=text, properties=props, faults=faults)


def load_spec(path: str | Path) -> SpecFile:
    """Read and parse a property file."""
    return parse_spec(read_text(path, SpecError), str(path))


def load_faults(path: str | Path) -> FaultSet:
    """Read the ``faults { ... }`` block of a file (``--faults FILE``): the file's only
    content besides comments, or one block of a spec file."""
    spec = parse_spec(read_text(path, SpecError), str(path), need_properties=False)
    if spec.faults is None:
        raise SpecError(
            "the file has no faults block (faults { budget N  fault NAME: ... })",
            Location(str(path), 1, 1, source_line(spec.text, 1)),
        )
    return spec.faults


def _num_text(node: Tree[Any]) -> str:
    """A number as the spec wrote it (clipped)."""
    return clip(str(node.children[0]))


class _Builder:
    """Turns the parse tree of one property into a :class:`Property`."""

    def __init__(self, text: str, path: str) -> None:
        self.text = text
        self.path = path

    def error(self, message: str, pos: Pos) -> SpecError:
        return SpecError(
            message, Location(self.path, pos.line, pos.column, source_line(self.text, pos.line))
        )

    def property(self, node: Tree[Any]) -> Property:
        name_tok: Any = node.children[0]
        prop_pos = Pos(node.meta.line, node.meta.column)
        fields: dict[str, Any] = {}
        clause_pos: dict[str, Pos] = {}
        for clause in node.children[1:]:
            key, value = self.clause(clause)
            pos = Pos(clause.meta.line, clause.meta.column)
            if key in fields:
                raise self.error(
                    f"property '{name_tok}' repeats its {key} clause "
                    f"(first at line {clause_pos[key].line})",
                    pos,
                )
            fields[key] = value
            clause_pos[key] = pos
            for allow in _allow_of(clause):
                fields["actions"] = self.allowed(allow.children[0])
                clause_pos["allow"] = _pos(allow)
        for key, shown in _REQUIRED.items():
            if key not in fields:
                raise self.error(f"property '{name_tok}' lacks {shown}", prop_pos)
        holds_op, threshold = fields["verdict"]
        lo, hi, radius = fields["window"]
        return Property(
            name=str(name_tok),
            window=(lo, hi),
            radius=radius,
            objective=fields["objective"],
            constraint=fields["constraint"],
            holds_op=holds_op,
            threshold=threshold,
            end=fields.get("end"),
            norm=fields.get("norm", 2.0),
            components=fields.get("on"),
            monitor=fields.get("monitor"),
            pos=prop_pos,
            clause_pos=clause_pos,
            actions=fields.get("actions", actions.DEFAULT),
            grid=fields.get("grid"),
        )

    def clause(self, node: Tree[Any]) -> tuple[str, Any]:
        kind = node.data
        ch: list[Any] = node.children
        if kind == "window":
            within = [c for c in ch[2:] if not _is_allow(c)]
            return "window", (self.whole(ch[0]), self.step(ch[1]), self.radius(within))
        if kind == "inject_grid":
            return "grid", self.grid(ch)
        if kind == "objective":
            return "objective", self.measure(ch[0])
        if kind == "constraint":
            measure = self.measure(ch[0])
            value = self.number(ch[2], "constraint threshold")
            return "constraint", Constraint(measure, str(ch[1]), value, _pos(node))  # type: ignore[arg-type]
        if kind == "verdict":
            return "verdict", (str(ch[0]), self.number(ch[1], "verdict threshold"))
        if kind == "end_clause":
            return "end", self.whole(ch[0])
        if kind == "norm_clause":
            return "norm", math.inf if str(ch[0]) == "inf" else float(str(ch[0]))
        if kind == "on_clause":
            return "on", self.names(ch[0])
        if kind == "monitor_clause":
            return "monitor", self.monitor(node)
        raise AssertionError(f"unhandled clause {kind}")  # pragma: no cover

    def monitor(self, node: Tree[Any]) -> Monitor:
        """A ``monitor`` clause: its kind from the registry (lesmc/language/monitors.py), the
        kind's parameter inside its domain, the window, components and ``except original``."""
        what = node.children[0]
        kind, param, param_pos = "tau_rise", None, _pos(node)
        if what.data == "monitor_kind":
            kind = str(what.children[0])
            if kind not in monitors.names():
                raise self.error(
                    f"unknown monitor '{clip(kind)}'; the monitors are "
                    f"{', '.join(monitors.names())} (or 'uncertainty', the tau_rise monitor)",
                    _pos(what),
                )
            if len(what.children) > 1 and what.children[1] is not None:
                param_pos = _pos(what.children[1])
                param = self.number(what.children[1], f"{kind} monitor's parameter")
        declared = monitors.get(kind)
        names: tuple[str, ...] | None = None
        window = 1
        excuse = False
        for item in node.children[1:]:
            if not isinstance(item, Tree):
                continue
            if item.data == "name_list":
                if declared.reads != "tau":
                    raise self.error(
                        f"the {kind} monitor reads no components of the state; "
                        "'on' belongs to the tau_rise and trace monitors",
                        _pos(item),
                    )
                names = self.names(item)
            elif item.data == "number":
                if what.data != "monitor_uncertainty":
                    raise self.error(
                        f"'tolerance' belongs to 'monitor uncertainty'; write the {kind} "
                        f"monitor's {declared.parameter} after its name",
                        _pos(item),
                    )
                param, param_pos = self.number(item, "monitor tolerance"), _pos(item)
            elif item.data == "monitor_window":
                if not declared.windowed:
                    raise self.error(f"the {kind} monitor takes no window", _pos(item))
                window = self.whole(item.children[0])
                if window < 1:
                    raise self.error("the monitor's window must be at least 1 step", _pos(item))
            elif item.data == "except_original":
                excuse = True
        param = self.monitor_parameter(declared, param, param_pos, _pos(what))
        return Monitor(names, param, _pos(node), excuse, kind, window)

    def monitor_parameter(
        self, declared: monitors.MonitorKind, param: float | None, at: Pos, kind_at: Pos
    ) -> float:
        """The monitor's parameter (its default when none is written) inside its domain
        (:func:`lesmc.language.monitors.resolve`), else an error at the number or the kind."""
        try:
            return monitors.resolve(declared.name, param)[1]
        except ValueError as exc:
            raise self.error(str(exc), kind_at if param is None else at) from None

    def faults(self, node: Tree[Any]) -> FaultSet:
        """A ``faults { ... }`` block: its budget (default 1) and its named faults."""
        budget: int | None = None
        faults: list[Fault] = []
        for item in node.children:
            if item.data == "budget_clause":
                if budget is not None:
                    raise self.error("the faults block repeats its budget", _pos(item))
                value = self.number(item.children[0], "fault budget")
                if value < 0 or value != int(value) or value > MAX_FAULT_BUDGET:
                    raise self.error(
                        f"the fault budget must be a whole number in 0..{MAX_FAULT_BUDGET}, "
                        f"got {clip(str(item.children[0].children[0]))}",
                        _pos(item.children[0]),
                    )
                budget = int(value)
                continue
            fault = self.fault(item)
            if any(f.name == fault.name for f in faults):
                raise self.error(f"fault '{fault.name}' is declared twice", fault.pos)
            faults.append(fault)
        if not faults:
            raise self.error("the faults block declares no fault", _pos(node))
        return FaultSet(
            1 if budget is None else budget, tuple(faults), self.path, self.text, _pos(node)
        )

    def fault(self, node: Tree[Any]) -> Fault:
        """``fault NAME: F[i, j] * c`` (or ``= c``), or ``fault NAME: outage K``, then
        optionally ``from A..B``: the activation steps."""
        name_tok, kind = node.children[0], node.children[1]
        pos = _tok_pos(name_tok)
        steps = None
        if len(node.children) > 2:
            ch = node.children[2].children
            lo, hi = self.whole(ch[0]), self.step(ch[1])
            if lo < 1 or (hi is not None and hi < lo):
                raise self.error(
                    f"activation steps {lo}..{clip(str(ch[1].children[0]))} must satisfy "
                    "1 <= from <= to",
                    _pos(node.children[2]),
                )
            steps = (lo, hi)
        if kind.data == "outage_fault":
            length = self.whole(kind.children[0])
            if length < 1:
                raise self.error("an outage lasts at least 1 step", _pos(kind))
            return Fault(str(name_tok), "outage", length=length, steps=steps, pos=pos)
        if kind.data == "neuron_fault":
            return self.neuron(str(name_tok), kind, steps, pos)
        matrix, row, col, op, value = kind.children
        return Fault(
            str(name_tok),
            "matrix",
            matrix=str(matrix),
            row=self.index(row),
            col=self.index(col),
            op=str(op),  # type: ignore[arg-type]
            value=self.number(value, "fault value"),
            steps=steps,
            pos=pos,
        )

    def neuron(
        self, name: str, node: Tree[Any], steps: tuple[int, StepRef] | None, pos: Pos
    ) -> Fault:
        """``neuron detector[L, U] = c`` (or ``= max``): hidden unit U of layer L stuck."""
        net, layer, unit, value = node.children
        at_max = isinstance(value, Tree) and value.data == "stuck_max"
        stuck = 0.0 if at_max else self.number(value, "stuck value")
        if stuck < 0:
            raise self.error(
                f"a stuck unit's value must be at least 0 (its ReLU never outputs less), "
                f"got {stuck:g}",
                _pos(value),
            )
        return Fault(
            name,
            "neuron",
            net=str(net),
            row=self.whole(layer),
            col=self.whole(unit),
            op="=",
            value=stuck,
            at_max=at_max,
            steps=steps,
            pos=pos,
        )

    def index(self, node: Tree[Any]) -> int | str:
        """A matrix index: a number, or a component name (resolved against the tracker)."""
        tok: Any = node.children[0]
        return self.whole(tok) if tok.type == "INT" else str(tok)

    def allowed(self, node: Tree[Any]) -> tuple[str, ...]:
        """``allow A, B``: the attacker's actions, each registered and named once
        (lesmc/language/actions.py, :func:`~lesmc.language.actions.allow_problem`)."""
        toks: list[Any] = node.children
        listed = [str(tok) for tok in toks]
        problem = actions.allow_problem(listed, keywords(), [clip(n) for n in listed])
        if problem is not None:
            i, message = problem
            raise self.error(message, _tok_pos(toks[i]))
        return tuple(listed)

    def names(self, node: Tree[Any]) -> tuple[str, ...]:
        names: list[str] = []
        toks: list[Any] = node.children
        for tok in toks:
            if str(tok) in names:
                raise self.error(f"component '{tok}' is named twice", Pos(tok.line, tok.column))
            names.append(str(tok))
        return tuple(names)

    def measure(self, node: Tree[Any]) -> Measure:
        """The measure of one grammar rule, read by the measure the registry declares for
        it (lesmc/language/measures/): its tokens (suffix or name) and its steps."""
        pos = _pos(node)
        ch: list[Any] = node.children
        tokens = [str(c) for c in ch if not isinstance(c, Tree)]
        steps = [self.step(c) for c in ch if isinstance(c, Tree)]
        lo, hi = steps if len(steps) == 2 else (None, None)
        if lo is not None and hi is not None and lo > hi:
            raise self.error(f"empty step range {lo}..{hi}", pos)
        declared = measures.by_rule(str(node.data), tokens[0] if tokens else None)
        try:
            got = declared.parse(str(node.data), tokens, steps)
        except measures.MeasureError as exc:
            raise self.error(str(exc), pos) from None
        return Measure(got.kind, got.aggregate, got.lo, got.hi, pos=pos)  # type: ignore[arg-type]

    def step(self, node: Tree[Any]) -> StepRef:
        tok: Any = node.children[0]
        return None if tok.type == "END" else self.whole(tok)

    def whole(self, tok: Any) -> int:
        """A step number: ASCII digits, at most :data:`MAX_STEP` (checked before ``int()``)."""
        digits = str(tok)
        if not (digits.isascii() and digits.isdigit()):  # the grammar admits only 0-9
            raise self.error(
                f"a step must be written with digits 0-9, got '{clip(digits)}'", _tok_pos(tok)
            )
        significant = digits.lstrip("0") or "0"  # int() refuses over 4300 digits
        if len(significant) > len(str(MAX_STEP)) or int(significant) > MAX_STEP:
            raise self.error(
                f"step {clip(digits)} is too large (steps are at most {MAX_STEP})", _tok_pos(tok)
            )
        return int(significant)

    def grid(self, ch: list[Any]) -> InjectGrid:
        """``inject grid D within R payoff P``, within the grid's limits
        (lesmc/language/actions.py, :func:`~lesmc.language.actions.grid_problem`)."""
        what = ("grid spacing", "grid radius", "grid payoff")
        grid = InjectGrid(*(self.number(ch[i], what[i]) for i in range(3)))
        problem = actions.grid_problem(grid, [_num_text(ch[i]) for i in range(3)])
        if problem is not None:
            i, message = problem
            raise self.error(message, _tok_pos(ch[i].children[0]))
        return grid

    def radius(self, rest: list[Any]) -> float | None:
        """``within R`` of the attack window: R px, positive; None without the clause."""
        if not rest:
            return None
        r = self.number(rest[0], "attack radius")
        if r <= 0:
            tok = rest[0].children[0]
            raise self.error(
                f"the attack radius must be positive (px around the target's reference), "
                f"got {clip(str(tok))}",
                _tok_pos(tok),
            )
        return r

    def number(self, node: Tree[Any], what: str) -> float:
        tok: Any = node.children[0]
        shown = clip(str(tok))
        if not str(tok).isascii():  # the grammar admits only 0-9
            raise self.error(
                f"the {what} must be written with digits 0-9, got {shown}", _tok_pos(tok)
            )
        value = float(tok)
        if not math.isfinite(value):
            raise self.error(f"the {what} must be finite, got {shown}", _tok_pos(tok))
        return value


def _pos(node: Tree[Any]) -> Pos:
    return Pos(node.meta.line, node.meta.column)


def _tok_pos(tok: Any) -> Pos:
    return Pos(tok.line, tok.column)


if __name__ == "__main__":  # regenerate lark_tables.py after editing the grammar
    TABLES.write_text(tables_source(), encoding="utf-8")
    print(f"wrote {TABLES}")


def _is_allow(node: Any) -> bool:
    """The window's ``allow A, B`` clause (beside its ``within R``)."""
    return isinstance(node, Tree) and node.data == "allow"


def _allow_of(clause: Tree[Any]) -> list[Tree[Any]]:
    """The ``allow`` clause of an attack window (none for other clauses)."""
    if clause.data != "window":
        return []
    return [c for c in clause.children[2:] if _is_allow(c)]
