"""The Python API's argument checks (lesmc/api.py): each raises a
:class:`~lesmc.common.errors.UsageError` naming the argument's rule and the value given.

A file argument is checked here and read by the API; the registries the choices come
from (designs, export formats, the graph roles) are asked, never copied.
"""

from __future__ import annotations

import itertools
import os
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from lesmc.common.errors import UsageError
from lesmc.common.fields import MAX_STEP, is_finite, is_int, parse_window
from lesmc.designs import registry
from lesmc.engines.result import CheckResult
from lesmc.language import parser as parse
from lesmc.language.properties import SpecFile
from lesmc.model.arrays import ArrayModel

if TYPE_CHECKING:
    from lesmc.exporters.formats import ExportFormat


def need(ok: bool, what: str, got: Any) -> None:
    """A UsageError naming the argument's rule and the value given, unless ``ok``."""
    if not ok:
        shown = repr(got)
        raise UsageError(f"{what}; got {shown if len(shown) <= 60 else shown[:57] + '...'}")


def file_path(value: Any, name: str, alternative: str = "", read: bool = True) -> str:
    """A file argument as a string: a str or an ``os.PathLike`` (not bytes, not an open
    file), neither empty nor holding a NUL; ``alternative`` says what else the argument
    may be. A file to write (not ``read``) must not be a directory."""
    ok = isinstance(value, str) or (
        isinstance(value, os.PathLike) and isinstance(os.fspath(value), str)
    )
    more = f" {alternative}" if alternative else ""
    need(ok, f"{name} must be a file path (a str or a pathlib.Path){more}", value)
    text = str(os.fspath(value))
    need(text != "", f"{name} must be a file path, not an empty string", value)
    need("\0" not in text, f"{name} must be a file path without a NUL character", value)
    if not read:  # a file to read that is missing or a directory: InputError at the file
        need(not os.path.isdir(text), f"{name} must be a file to write, not a directory", value)
    return text


def spec_files(specs: Any, name: str = "specs") -> tuple[SpecFile, ...]:
    """``specs``: one spec file or a list of them, each parsed or a path (read now);
    ``name``: the argument's, for messages."""
    rule = f"{name} must be a spec file (a SpecFile or its path) or a non-empty list of them"
    one = isinstance(specs, SpecFile | str | os.PathLike)
    need(one or (isinstance(specs, Sequence) and not isinstance(specs, bytes)), rule, specs)
    given = (specs,) if one else tuple(specs)
    need(bool(given), rule, specs)
    out = []
    for s in given:
        if isinstance(s, SpecFile):
            out.append(s)
        else:
            need(isinstance(s, str | os.PathLike), rule, s)
            out.append(parse.load_spec(file_path(s, name)))
    return tuple(out)


def design_list(designs: Any) -> tuple[str, ...]:
    """``designs``: a ``--design`` choice (a design, a set, ``all``) or a list of designs."""
    if isinstance(designs, str):
        need(
            designs in registry.choices(),
            f"designs must be one of {', '.join(registry.choices())} or a list of designs",
            designs,
        )
        return registry.expand(designs)
    chosen = sequence(designs, "designs")
    check_designs(chosen)
    return chosen


def attack_window(window: Any) -> tuple[int, int]:
    """An attack window from ``"L..U"``, ``(L, U)`` or ``range(L, U + 1)``."""
    if isinstance(window, str):
        return parse_window(window, "window")
    if isinstance(window, range):
        ok = window.step == 1 and len(window) > 0
        need(ok, "window must be a non-empty range of step 1 (range(6, 9) is 6..8)", window)
        window = (window.start, window[-1])
    need(
        are_steps(window, 2) and window[0] <= window[1],
        'window must be "L..U", (L, U) or range(L, U + 1) with 0 <= L <= U',
        window,
    )
    return int(window[0]), int(window[1])


def sequence(values: Any, name: str) -> tuple[Any, ...]:
    """A sequence argument as a tuple; one string is refused (it would iterate by letter)."""
    ok = not isinstance(values, (str, bytes)) and isinstance(values, Sequence | set | frozenset)
    need(ok, f"{name} must be a list or tuple (not one string)", values)
    return tuple(values)


def are_steps(values: Any, n: int) -> bool:
    """``values`` is ``n`` integer steps in 0..MAX_STEP (booleans are not integers here)."""
    return (
        isinstance(values, Sequence)
        and len(values) == n
        and all(type(v) is int and 0 <= v <= MAX_STEP for v in values)
    )


def check_limits(timeout: Any, max_states: Any) -> None:
    """A search's limits: ``timeout`` seconds and ``max_states``, each ``None`` or > 0."""
    good_t = timeout is None or (is_finite(timeout) and timeout > 0)
    need(good_t, "timeout must be None or a finite number of seconds > 0", timeout)
    good_n = max_states is None or (is_int(max_states) and max_states > 0)
    need(good_n, "max_states must be None or an integer > 0", max_states)


def check_designs(designs: tuple[Any, ...]) -> None:
    """A list of designs: each a name the design registry declares."""
    known = registry.names()
    bad = [d for d in designs if not (isinstance(d, str) and d in known)]
    need(
        not bad,
        f"designs are names among {', '.join(known)} (or one of "
        f"{', '.join((*registry.SETS, 'all'))})",
        bad[0] if bad else None,
    )


def format_takes(
    fmt: ExportFormat, spec: Any, prop: Any, strict: Any, roles: Any, max_nodes: Any
) -> None:
    """Arguments that format ``fmt`` would ignore are errors, as ``lesmc export`` refuses
    the options (the one rule: :func:`lesmc.exporters.formats.refused`)."""
    from lesmc.exporters import formats

    values = {"spec": spec, "property": prop, "strict": strict or None, "paths": roles}
    values["max_nodes"] = max_nodes
    given = {k: v is not None for k, v in values.items()}
    spelling = {k: k for k in values} | {"paths": "roles", "format": "format"}
    why = formats.refused(fmt, given, spelling)
    if why is not None:
        need(False, why[1], values[why[0]])


def marked_paths(model: ArrayModel, roles: Any) -> dict[str, list[int]] | None:
    """The paths to mark: a CheckResult's counterexample and witness (and the unattacked
    path), or role names mapped to model rows, each consecutive pair a transition."""
    from lesmc.exporters.graphs import ROLE_STYLE

    if roles is None:
        return None
    if isinstance(roles, CheckResult):
        out = {"original": [int(q) for q in model.original]}
        for role in ("witness", "counterexample"):
            path = getattr(roles, role)
            if path is None:
                continue
            missing = [s for s in path.states if s not in model.state_ids()]
            need(
                not missing,
                f"roles: the {role}'s states are not this model's (a result of another model?)",
                missing[:3],
            )
            out[role] = [model.index(s) for s in path.states]
        return out
    need(isinstance(roles, dict), "roles must be a CheckResult or map role names to rows", roles)
    bad = [k for k in roles if k not in ROLE_STYLE]
    need(not bad, f"roles are named {', '.join(ROLE_STYLE)}", bad[:3])
    for name, rows in roles.items():
        ok = isinstance(rows, list | tuple) and all(
            is_int(q) and 0 <= q < model.n_states for q in rows
        )
        need(ok, f"roles[{name!r}] must be a list of model rows 0..{model.n_states - 1}", rows)
        for a, b in itertools.pairwise(rows):
            try:
                model.edge(a, b)
            except KeyError:
                need(False, f"roles[{name!r}]: rows {a} -> {b} are not a transition", rows)
    return {k: list(v) for k, v in roles.items()}
