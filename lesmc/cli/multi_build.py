"""``lesmc build SCENE --design sort|gnn -o MODEL.npz``: the model of a multi-target design,
unfolded for one attack window (``--window``, or ``--spec``'s property: its window, end,
``within R`` and ``allow``) and written as a ``lesmc-multi-npz`` file
(lesmc/model/multi_format.py; docs/lts-format.md, "Multi-target models"), which
``lesmc check MODEL SPEC`` and ``lesmc export MODEL`` (its MDP formats) read.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

from lesmc.cli.documents import build_document, emit, given, say
from lesmc.common.errors import Location, UsageError, escape_control, source_line
from lesmc.common.files import file_sha256
from lesmc.engines.multi import BuildKey
from lesmc.language.actions import DEFAULT as DEFAULT_ACTIONS
from lesmc.model.lts_binary import is_binary
from lesmc.model.multi import MultiModel
from lesmc.scene import Scene

if TYPE_CHECKING:
    from lesmc.common.budget import Budget


def build_multi_model(
    sc: Scene,
    scene: str,
    window: tuple[int, int] | None,
    end: int | None,
    spec_path: str | None,
    prop: str | None,
    output: str,
    max_states: int | None,
    as_json: bool,
    budget: Budget,
) -> None:
    """Build and write the model of ``sc``'s multi-target design (``lesmc build``'s
    arguments) within ``budget``'s time (past it a BudgetError, exit 3, nothing written);
    the options its unfolding does not read are refused."""
    from lesmc.cli.options import arm_budget
    from lesmc.model.multi_format import save_multi
    from lesmc.pipeline.multi import build_within, preload

    if given("max_memory"):
        raise UsageError(
            "--max-memory with a multi-target design: not supported yet (its unfolding is "
            "bounded by --max-states and --timeout)"
        )
    if not is_binary(output):
        raise UsageError(
            f"-o {escape_control(output)}: a multi-target model is written in the binary form "
            "only (-o NAME.npz); its JSON .lts form is not supported yet"
        )
    loaded = time.monotonic()
    key = _key(sc, window, end, spec_path, prop)
    preload()  # then the alarm: a usage error first, and no import past the deadline
    arm_budget(budget)
    limit = "--timeout" if budget.timeout is None else budget.describe("timeout")
    model = build_within(sc, scene, key, max_states, budget, limit)
    unfolded = time.monotonic()
    save_multi(model, output)
    l, u, last = key[0], key[1], key[2]
    say(
        f"wrote {escape_control(output)}: {model.n_states} states, {model.n_transitions} "
        f"transitions, steps 0..{last}, design {model.meta['design']}, window {l}..{u}",
        as_json,
    )
    if as_json:
        emit(_document(sc, scene, output, model, key, (budget.started, loaded, unfolded)))


def _document(
    sc: Scene,
    scene: str,
    output: str,
    model: MultiModel,
    key: BuildKey,
    times: tuple[float, float, float],
) -> dict[str, Any]:
    """``lesmc build --json`` of a multi-target model (its sha256 is the file's;
    ``times``: started, scene loaded, model unfolded)."""
    started, loaded, unfolded = times
    seconds = {
        "load": loaded - started,
        "unfold": unfolded - loaded,
        "write": time.monotonic() - unfolded,
        "total": time.monotonic() - started,
    }
    return build_document(scene, output, model, file_sha256(output), sc, (key[0], key[1]), seconds)


def _key(
    sc: Scene,
    window: tuple[int, int] | None,
    end: int | None,
    spec_path: str | None,
    prop: str | None,
) -> BuildKey:
    """What the model is unfolded for: ``--spec``'s property (``--window`` and ``--end``,
    when given too, must agree with it), else ``--window`` and ``--end`` with every
    detection attackable and the attacker hiding."""
    from lesmc.api import load_spec
    from lesmc.pipeline.multi import property_key

    last = len(sc.frames) - 1
    if spec_path is None:
        if prop is not None:
            raise UsageError("--property names a property of --spec: give --spec FILE")
        if window is None:
            raise UsageError("give --window L..U, or --spec FILE for its property's window")
        return (window[0], window[1], last if end is None else end, None, DEFAULT_ACTIONS)
    spec = load_spec(spec_path)
    key = property_key(sc, spec, prop)
    for flag, got, own in (("--window", window, key[:2]), ("--end", end, key[2])):
        if got is not None and got != own:
            name = prop or spec.properties[0].name
            p = next(q for q in spec.properties if q.name == name)
            pos = p.clause_pos.get("window", p.pos)
            raise UsageError(
                f"{flag} {_text(got)} contradicts property '{name}', which needs "
                f"{_text(own)}: leave {flag} out (the property's is used)",
                Location(spec.path, pos.line, pos.column, source_line(spec.text, pos.line)),
            )
    return key


def _text(v: Any) -> str:
    return f"{v[0]}..{v[1]}" if isinstance(v, tuple) else str(v)
