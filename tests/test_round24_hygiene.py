"""Round 24's leftovers (task hygiene).

1. The run-time schema validator (lesmc/schemas/__init__.py) compares ``enum`` and
   ``const`` as JSON Schema does: 1 and 1.0 are equal, true and 1 (false and 0) are not.
   The oracle is the ``jsonschema`` package, on every enum/const node of the shipped
   schemas and on hand-made ones, for values of each JSON type.
2. The eager build (lesmc/unfold/unfold.py ``build_model``) sizes its batches by counted
   work (lesmc/model/growing.py ``counted_batch``, the lazy model's notion), not by the
   wall clock: the states at which it looks at its budget, and so where ``--max-states``
   stops it, are the same under the real clock and a clock 1000x slower.
3. ``lesmc check SCENE SPEC --design sort --report DIR`` writes a ``lesmc-multi-check``
   document that ``lesmc replay`` replays, as verify's: with the scene's ``perception``
   (lesmc.perception.attack_settings ``scene_perception``, the function the point designs'
   check and verify call) and the ``meta`` that places the check's target on the scene
   (lesmc/experiment/multi_verify.py ``replay_meta``, verify's); the replay reruns the
   front end the scene was perceived with (``--delta-bc 16``, not the default 12), and its
   counterexamples are confirmed. A bad ``meta.frontend`` is refused before anything is
   written.
4. Every module of lesmc/ (but the generated parser tables) is at most 600 lines.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_run import lesmc
from multi_video import SPEC, write_small_video

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
    import lesmc.unfold.unfold as unfold

    monkeypatch.setattr(unfold, "BATCH_WORK", 256)  # a step's states in several batches
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


#: Not the default (12): blobs need a larger difference from the background
#: (tests/test_multi_replay_frontend.py's setting and target on the same video).
DELTA_BC = 16
TARGET = "119.0,71.5@4"


@pytest.fixture(scope="module")
def perceived(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path]:
    """The small video perceived with ``--delta-bc 16``: (frames, scene, spec)."""
    base = tmp_path_factory.mktemp("multicheck")
    video, scene, spec = base / "video", base / "scene.json", base / "identity.spec"
    write_small_video(video)
    r = lesmc("perceive", str(video), "-o", str(scene), "--delta-bc", str(DELTA_BC))
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    spec.write_text(SPEC)
    return video, scene, spec


def _check(scene: Path, spec: Path, out: Path) -> Any:
    return lesmc("check", str(scene), str(spec), "--design", "sort", "--target", TARGET,
                 "--report", str(out), timeout=300)  # fmt: skip


def test_a_multi_target_checks_report_replays_with_the_recorded_front_end(
    perceived: tuple[Path, Path, Path], tmp_path: Path
) -> None:
    from lesmc.perception.blobs import BlobConfig
    from lesmc.schemas import validate

    video, scene, spec = perceived
    out = tmp_path / "out"
    r = _check(scene, spec, out)
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stdout + r.stderr
    doc = json.loads((out / "results.json").read_text())
    validate(doc, "multi-check")
    assert doc["perception"]["delta_bc"] == DELTA_BC != BlobConfig().delta_bc
    assert doc["meta"]["scene"] == str(scene.resolve())
    assert doc["meta"]["properties"] == [str(spec.resolve())]
    x, y, step = 119.0, 71.5, 4  # TARGET
    assert doc["meta"]["scene_target"]["step"] == step
    assert doc["meta"]["scene_target"]["start"][:2] == [x, y]
    violated = [res["property"] for res in doc["results"] if res["verdict"] == "violated"]
    assert violated
    r = lesmc("replay", str(out / "results.json"), "--frames", str(video), "--json", timeout=300)
    assert "Traceback" not in r.stderr, r.stderr
    assert r.returncode == 1, r.stdout + r.stderr  # confirmed violations
    rows = json.loads(r.stdout)["replays"]
    validate(json.loads(r.stdout), "replay")
    assert sorted(row["property"] for row in rows) == sorted(violated)
    for row in rows:
        rp = row["replay"]
        assert rp["status"] == "confirmed", rp.get("reason")
        assert rp["frontend"] == {
            "history": 4,
            "delta_bc": DELTA_BC,
            "recorded": ["history", "delta_bc"],
            "from": "results",
        }


def test_a_bad_front_end_setting_is_refused_before_a_multi_target_check(
    perceived: tuple[Path, Path, Path], tmp_path: Path
) -> None:
    _, scene, spec = perceived
    data = json.loads(scene.read_text())
    data["meta"]["frontend"] = {"history": 4, "delta_bc": 300}
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(data, indent=1))
    lines = bad.read_text().splitlines()
    line = next(i for i, t in enumerate(lines) if t.strip().startswith('"delta_bc": 300')) + 1
    out = tmp_path / "out"
    r = _check(bad, spec, out)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stdout + r.stderr
    assert f"{bad}:{line}:" in r.stderr and "meta.frontend.delta_bc" in r.stderr, r.stderr
    assert not out.exists()


def test_every_module_is_at_most_600_lines() -> None:
    root = Path(__file__).resolve().parents[1] / "lesmc"
    sizes = {
        str(p.relative_to(root)): len(p.read_text(encoding="utf-8").splitlines())
        for p in root.rglob("*.py")
        if p.name != "lark_tables.py"  # generated (python -m lesmc.language.parser)
    }
    assert len(sizes) > 100
    assert {p: n for p, n in sizes.items() if n > 600} == {}
