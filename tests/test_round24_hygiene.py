"""Round 24's leftovers (task hygiene).

1. The run-time schema validator (lesmc/schemas/__init__.py) compares ``enum`` and
   ``const`` as JSON Schema does: 1 and 1.0 are equal, true and 1 (false and 0) are not.
   The oracle is the ``jsonschema`` package, on every enum/const node of the shipped
   schemas and on hand-made ones, for values of each JSON type.
2. The eager build (lesmc/unfold/unfold.py ``build_model``) sizes its batches by counted
   work (lesmc/model/growing.py ``counted_batch``, the lazy model's notion), not by the
   wall clock: the states at which it looks at its budget, and so where ``--max-states``
   stops it, are the same under the real clock and a clock 1000x slower.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from lesmc.scene import Scene

#: Values of every JSON type, among them those Python's ``==`` confuses (True == 1 == 1.0).
PROBES: list[Any] = [
    True, False, 0, 1, 2, 0.0, 1.0, 2.0, 1.5, -1, "1", "true", "", None,
    [], [1], [True], [1.0], [0], [False], {}, {"a": 1}, {"a": True}, {"a": 1.0},
]  # fmt: skip

#: Nodes where Python's equality and JSON Schema's differ.
HAND_MADE: list[dict[str, Any]] = [
    {"const": 1},
    {"const": 1.0},
    {"const": True},
    {"const": False},
    {"const": 0},
    {"enum": [0, "x"]},
    {"enum": [True, None]},
    {"enum": [1.0, [False]]},
    {"const": [1, {"a": False}]},
    {"const": {"a": 1}},
]


def _nodes(node: Any) -> Iterator[dict[str, Any]]:
    """Every enum/const node under ``node`` (a schema), as a node of that check alone."""
    if isinstance(node, dict):
        for key in ("enum", "const"):
            if key in node:
                yield {key: node[key]}
        for v in node.values():
            yield from _nodes(v)
    elif isinstance(node, list):
        for v in node:
            yield from _nodes(v)


def _shipped_nodes() -> list[dict[str, Any]]:
    from lesmc.schemas import SCHEMAS, schema

    return [n for name in sorted(set(SCHEMAS.values())) for n in _nodes(schema(name))]


def _agree(node: dict[str, Any]) -> list[str]:
    """The probes (and the node's own values) on which lesmc's validator and jsonschema's
    disagree about ``node``."""
    import jsonschema

    from lesmc.schemas import errors

    oracle = jsonschema.Draft202012Validator(node)
    values = [*PROBES, *node.get("enum", ()), *([node["const"]] if "const" in node else [])]
    return [
        f"{node} on {v!r}: lesmc {not errors(v, node, node)}, jsonschema {oracle.is_valid(v)}"
        for v in values
        if (not errors(v, node, node)) != oracle.is_valid(v)
    ]


@pytest.mark.parametrize("node", HAND_MADE, ids=str)
def test_enum_and_const_compare_as_json_schema_does(node: dict[str, Any]) -> None:
    assert _agree(node) == []


def test_the_shipped_schemas_enum_and_const_nodes_agree_with_jsonschema() -> None:
    nodes = _shipped_nodes()
    assert len(nodes) > 20  # the schemas have many (versions, formats, registered names)
    bad = [line for n in nodes for line in _agree(n)]
    assert bad == [], bad[:5]


def test_a_boolean_version_is_refused_at_run_time() -> None:
    from lesmc.common.errors import InputError
    from lesmc.schemas import validate

    doc = {"format": "lesmc-multi-check", "design": "sort", "reference": "truth", "results": []}
    for version in (1, 1.0, 2):
        validate({**doc, "version": version}, "multi-check")  # versions 1 and 2 (1.0 is 1)
    for version in (True, "1"):  # true is not 1
        with pytest.raises(InputError, match="version"):
            validate({**doc, "version": version}, "multi-check")


#: How much slower the slowed clock runs (tests/test_walk_cap_work.py's).
SLOWER = 1000.0


def _slow_clock(monkeypatch: pytest.MonkeyPatch) -> None:
    """time.perf_counter and time.monotonic running SLOWER times slower than real time."""
    for name in ("perf_counter", "monotonic"):
        real = getattr(time, name)
        t0 = real()
        monkeypatch.setattr(time, name, lambda real=real, t0=t0: t0 + (real() - t0) * SLOWER)


def _dense() -> Scene:
    """A target among 6 straight-line vehicles (benchmarks/bench_unfold.py's scene kind)."""
    from lesmc.scene.toy import Vehicle, vehicle_scene

    rng = np.random.default_rng(4)
    t = Vehicle("t", 500, 500, 10, 0, 3.0)
    others = [
        Vehicle(f"v{i}", 500 + float(dx), 500 + float(dy), 10, 0, float(p))
        for i, (dx, dy, p) in enumerate(rng.uniform((-15, -15, 1), (15, 15, 5), size=(6, 3)))
    ]
    return vehicle_scene([t, *others], 10, t)


class _Stop(Exception):
    """The budget of :func:`_batches` is spent."""


def _batches(max_states: int | None) -> tuple[list[int], int]:
    """The model's size each time the eager build looks at its budget (before each batch)
    and the size it ends at, stopped (as a budget stops it) once it has ``max_states``."""
    from lesmc.unfold.unfold import build_model

    seen: list[int] = []

    def on_batch(model: Any) -> None:
        seen.append(model.n_states)
        if max_states is not None and model.n_states >= max_states:
            raise _Stop

    try:
        built = build_model(_dense(), (2, 6), on_batch=on_batch, max_states=max_states)
        return seen, len(built.step)
    except _Stop:
        return seen, seen[-1]


@pytest.mark.parametrize("max_states", [None, 3000])
def test_the_eager_builds_batches_do_not_depend_on_the_clock(
    max_states: int | None, monkeypatch: pytest.MonkeyPatch
) -> None:
    import lesmc.model.growing as growing

    monkeypatch.setattr(growing, "BATCH_WORK", 256)  # a step's states in several batches
    real = _batches(max_states)
    levels = 10
    assert len(real[0]) > 2 * levels, real  # many batches: their sizes are what is tested
    if max_states is not None:
        whole = _batches(None)[1]
        assert max_states <= real[1] < whole, (real[1], whole)  # stopped, past the limit
    with monkeypatch.context() as m:
        _slow_clock(m)
        slowed = _batches(max_states)
    assert slowed == real
