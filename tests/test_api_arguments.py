"""Every public API function checks its arguments (issue 57): a hostile argument raises a
``lesmc.LesmcError`` subclass whose message names the argument, never an exception from
inside, and is never silently accepted or ignored; nothing is written.

The first cases are every call the hostile run found mishandled (issue 57, "The API's
errors are not its own": its 29 counted the variants of these 26 calls); the rest are
ours.
"""

from __future__ import annotations

import io
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

import lesmc

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "tests" / "golden" / "tiny"
MERGE = ROOT / "examples" / "merge.json"


@pytest.fixture(scope="module")
def model() -> Any:
    return lesmc.load_model(TINY / "model.lts")


@pytest.fixture(scope="module")
def spec() -> Any:
    return lesmc.load_spec(TINY / "properties.spec")


@pytest.fixture(scope="module")
def scene() -> Any:
    return lesmc.load_scene(MERGE)


#: (case id, the argument the message must name, the error class, the call)
Call = Callable[[Any, Any, Any, Path], object]
CASES: list[tuple[str, str, type[Exception], Call]] = [
    # 23 calls that raised non-lesmc exceptions from inside
    ("load_model-dict", "path", lesmc.UsageError, lambda m, s, sc, out: lesmc.load_model({})),
    ("load_model-None", "path", lesmc.UsageError, lambda m, s, sc, out: lesmc.load_model(None)),
    ("load_model-int", "path", lesmc.UsageError, lambda m, s, sc, out: lesmc.load_model(5)),
    ("load_model-bytes", "path", lesmc.UsageError, lambda m, s, sc, out: lesmc.load_model(b"x")),
    ("load_model-list", "path", lesmc.UsageError, lambda m, s, sc, out: lesmc.load_model(["a"])),
    (
        "load_model-StringIO",
        "path",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.load_model(io.StringIO("{}")),
    ),
    ("load_scene-None", "path", lesmc.UsageError, lambda m, s, sc, out: lesmc.load_scene(None)),
    ("load_scene-dict", "path", lesmc.UsageError, lambda m, s, sc, out: lesmc.load_scene({})),
    ("load_spec-None", "path", lesmc.UsageError, lambda m, s, sc, out: lesmc.load_spec(None)),
    ("load_spec-dict", "path", lesmc.UsageError, lambda m, s, sc, out: lesmc.load_spec({})),
    (
        "load_scene-target-int",
        "target",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.load_scene(MERGE, target=5),
    ),
    (
        "load_scene-tracker-int",
        "tracker",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.load_scene(MERGE, tracker=5),
    ),
    ("parse_spec-int", "text", lesmc.UsageError, lambda m, s, sc, out: lesmc.parse_spec(5)),
    (
        "export_model-path-None",
        "path",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.api.export_model(m, None, "json"),
    ),
    (
        "export_model-path-int",
        "path",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.api.export_model(m, 5, "json"),
    ),
    (
        "export_model-max_nodes-str",
        "max_nodes",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.api.export_model(m, out, "dot", max_nodes="5"),
    ),
    (
        "save_scene-None",
        "scene",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.save_scene(None, out),
    ),
    (
        "save_scene-model",
        "scene",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.save_scene(m, out),
    ),
    (
        "save_scene-path-int",
        "path",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.save_scene(sc, 5),
    ),
    # 6 arguments that were silently ignored or accepted
    (
        "build-max_states-1",
        "max_states",
        lesmc.BudgetError,
        lambda m, s, sc, out: lesmc.build(sc, (6, 8), max_states=1),
    ),
    (
        "check-model-designs",
        "designs",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.check(m, s, designs=("joint",)),
    ),
    (
        "check-timeout-True",
        "timeout",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.check(m, s, timeout=True),
    ),
    (
        "load_scene-design-monitor",
        "design",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.load_scene(MERGE, design="monitor"),
    ),
    (
        "export_model-roles-unknown",
        "roles",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.api.export_model(m, out, "dot", roles={"zz": [1]}),
    ),
    (
        "export_model-strict-yes",
        "strict",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.api.export_model(m, out, "drn", s, "robustness", strict="yes"),
    ),
    (
        "export_model-max_nodes-negative",
        "max_nodes",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.api.export_model(m, out, "dot", max_nodes=-1),
    ),
    # ours
    (
        "check-engine",
        "engine",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.check(m, s, engine="z3"),
    ),
    (
        "check-payoffs",
        "payoffs",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.check(m, s, payoffs="cheapest"),
    ),
    (
        "check-timeout-nan",
        "timeout",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.check(m, s, timeout=math.nan),
    ),
    (
        "check-max_states-True",
        "max_states",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.check(m, s, max_states=True),
    ),
    ("check-specs-empty", "specs", lesmc.UsageError, lambda m, s, sc, out: lesmc.check(m, [])),
    ("check-specs-int", "specs", lesmc.UsageError, lambda m, s, sc, out: lesmc.check(m, 5)),
    ("check-source-int", "source", lesmc.UsageError, lambda m, s, sc, out: lesmc.check(5, s)),
    (
        "check-designs-unknown",
        "designs",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.check(sc, s, designs="nope"),
    ),
    (
        "check-only-int",
        "only",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.check(m, s, only=[5]),
    ),
    (
        "build-window-reversed",
        "window",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.build(sc, (8, 6)),
    ),
    (
        "build-window-text",
        "window",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.build(sc, "6-8"),
    ),
    (
        "build-window-range-step",
        "window",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.build(sc, range(6, 9, 2)),
    ),
    (
        "build-window-float",
        "window",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.build(sc, (6.5, 8)),
    ),
    ("build-end", "end", lesmc.UsageError, lambda m, s, sc, out: lesmc.build(sc, (6, 8), end=-1)),
    ("build-scene-int", "scene", lesmc.UsageError, lambda m, s, sc, out: lesmc.build(5, (6, 8))),
    (
        "build-design-monitor",
        "design",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.build(sc, (6, 8), design="monitor"),
    ),
    ("check_job-int", "job", lesmc.UsageError, lambda m, s, sc, out: lesmc.check_job(5)),
    (
        "expand_designs-int",
        "choice",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.expand_designs(5),
    ),
    (
        "parse_spec-path-int",
        "path",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.parse_spec("", 5),
    ),
    (
        "load_model_or_scene-None",
        "path",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.load_model_or_scene(None),
    ),
    (
        "export-spec-int",
        "spec",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.export(m, out, format="drn", spec=5),
    ),
    (
        "export-property-int",
        "property",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.export(m, out, format="drn", spec=s, property=5),
    ),
    (
        "export-model-int",
        "model",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.export(5, out, format="json"),
    ),
    (
        "export-roles-row-out-of-range",
        "roles",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.export(m, out, format="dot", roles={"witness": [0, 10**6]}),
    ),
    (
        "export-roles-not-a-transition",
        "roles",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.export(m, out, format="dot", roles={"witness": [0, 0]}),
    ),
    (
        "export-roles-bool-row",
        "roles",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.export(m, out, format="dot", roles={"witness": [True]}),
    ),
    ("perceive-int", "request", lesmc.UsageError, lambda m, s, sc, out: lesmc.perceive(5)),
    ("verify-path", "request", lesmc.UsageError, lambda m, s, sc, out: lesmc.verify("v/")),
    (
        "export-max_nodes-bool",
        "max_nodes",
        lesmc.UsageError,
        lambda m, s, sc, out: lesmc.export(m, out, format="dot", max_nodes=True),
    ),
]


@pytest.mark.parametrize(
    ("arg", "error", "call"), [c[1:] for c in CASES], ids=[c[0] for c in CASES]
)
def test_a_hostile_argument_is_refused_naming_it(
    arg: str,
    error: type[Exception],
    call: Call,
    model: Any,
    spec: Any,
    scene: Any,
    tmp_path: Path,
) -> None:
    out = tmp_path / "out.file"
    with pytest.raises(lesmc.LesmcError) as info:
        call(model, spec, scene, out)
    assert isinstance(info.value, error), repr(info.value)
    assert arg in str(info.value), str(info.value)
    assert not out.exists()  # nothing half-written
    assert list(tmp_path.iterdir()) == []


def test_roles_of_another_models_result_are_refused(model: Any, tmp_path: Path) -> None:
    """A CheckResult names states by id: a result of another model does not mark this one."""
    other = lesmc.check(
        ROOT / "tests" / "golden" / "wami_single" / "model.lts",
        ROOT / "tests" / "golden" / "wami_single" / "robustness.spec",
    )
    cex = next(r for r in other if r.counterexample is not None)
    with pytest.raises(lesmc.UsageError, match="roles"):
        lesmc.export(model, tmp_path / "x.dot", format="dot", roles=cex)
    assert list(tmp_path.iterdir()) == []
