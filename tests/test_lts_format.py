"""The .lts loader: every problem reported by id; round trip; atomic writes."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest

from lesmc.errors import ModelError
from lesmc.model.lts_format import load_lts, lts_from_dict, lts_to_dict, save_lts
from lesmc.model.random_models import RandomModelConfig, random_lts

TINY = Path(__file__).parent / "golden" / "tiny" / "model.lts"


def _doc() -> dict:
    return json.loads(TINY.read_text())


def _problem(doc: dict) -> str:
    with pytest.raises(ModelError) as exc:
        lts_from_dict(doc, "m.lts")
    return exc.value.render()


def test_load_tiny() -> None:
    m = load_lts(TINY)
    assert m.end == 3 and m.components == ("x",) and m.has_covariance
    assert [t.dst for t in m.out("q0")] == ["a", "b", "c"]
    assert m.combined_payoff(m.out("q0")[2]) == 5.0
    assert m.state("bH").halted


def _mutate(path: str, value: object) -> dict:
    doc = _doc()
    target = doc
    keys = path.split("/")
    for k in keys[:-1]:
        target = target[int(k)] if k.isdigit() else target[k]
    last = keys[-1]
    if value is KeyError:
        del target[last]
    elif last.isdigit():
        target[int(last)] = value
    else:
        target[last] = value
    return doc


CASES = [
    ("format", "lts", 'format: must be "lesmc-lts"'),
    ("version", 2, "version: must be 1"),
    ("extra", 1, "key 'extra': unknown top-level key"),
    ("states/1/step", -1, "state 'a': step must be an integer >= 0"),
    ("states/1/step", 1.5, "state 'a': step must be an integer >= 0"),
    ("states/1/s", [1, 2], "state 'a': s has 2 entries, expected 1"),
    ("states/1/s", ["x"], "state 'a': s must be a non-empty list of finite numbers"),
    ("states/1/P", [[1, 2]], "state 'a': P must be a square list"),
    ("states/1/colour", "red", "state 'a': unknown key 'colour'"),
    ("states/2/id", "a", "state 'a': duplicate state id"),
    ("transitions/0/payoff", -1, "transition 0 (q0 -> a): payoff must be a finite number >= 0"),
    (
        "transitions/0/payoff",
        KeyError,
        "transition 0 (q0 -> a): payoff must be a finite number >= 0",
    ),
    ("transitions/0/rank", "0", "transition 0 (q0 -> a): rank must be an integer"),
    ("transitions/0/dst", "zz", "transition 0 (q0 -> zz): unknown state 'zz'"),
    ("transitions/0/dst", "a2", "transition 0 (q0 -> a2): goes from step 0 to step 2"),
    ("transitions/1/rank", 0, "state 'q0': 2 transitions share the lowest rank 0"),
    ("original/1", "b", "original[1]: 'b' is not the unattacked (rank-minimal) successor of 'q0'"),
    ("original/0", "a", "original: must start at the initial state 'q0'"),
    ("initial", "nowhere", "initial: unknown state 'nowhere'"),
    ("states/7/labels", [], "state 'bH': has no successor before step 3; label it 'halted'"),
    ("states/11/labels", ["halted"], None),
    ("components", ["x", "y"], "state 'q0': s has 1 entries, expected 2"),
]


@pytest.mark.parametrize(
    ("path", "value", "message"), CASES, ids=[c[0] + "=" + repr(c[1]) for c in CASES]
)
def test_each_problem_is_reported_by_id(path: str, value: object, message: str | None) -> None:
    doc = _mutate(path, value)
    if message is None:  # a state at the last step may be labelled halted: nothing to report
        lts_from_dict(doc, "m.lts")
        return
    text = _problem(doc)
    assert f"m.lts: {message}" in text, text


def test_unreachable_and_too_late_states() -> None:
    doc = _doc()
    doc["states"].append({"id": "lost", "step": 3, "s": [0]})
    doc["states"].append({"id": "late", "step": 4, "s": [0]})
    text = _problem(doc)
    assert "state 'lost': not reachable from the initial state" in text
    assert "state 'late': step 4 is beyond the original path's end 3" in text


def test_many_problems_reported_together() -> None:
    doc = _doc()
    for t in doc["transitions"]:
        t["payoff"] = -1
    assert _problem(doc).count("payoff must be") == len(doc["transitions"])


@pytest.mark.parametrize("text", ['{"format": NaN}', '{"format": "lesmc-lts",', "[1, 2]"])
def test_malformed_json(tmp_path: Path, text: str) -> None:
    p = tmp_path / "m.lts"
    p.write_text(text)
    with pytest.raises(ModelError) as exc:
        load_lts(p)
    assert exc.value.render().startswith(str(p))


def test_round_trip(tmp_path: Path) -> None:
    m = random_lts(RandomModelConfig(steps=5, covariance=True), seed=4)
    save_lts(m, tmp_path / "r.lts")
    again = load_lts(tmp_path / "r.lts")
    assert lts_to_dict(again) == lts_to_dict(m)


def test_writing_is_atomic(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    target = tmp_path / "out.lts"
    target.write_text("old")
    m = load_lts(TINY)
    doc = lts_to_dict(m)

    def broken(*_a: object, **_k: object) -> str:
        raise RuntimeError("disk full")

    monkeypatch.setattr(json, "dumps", broken)
    with pytest.raises(RuntimeError):
        save_lts(m, target)
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["out.lts"]
    assert doc["initial"] == "q0"


def test_never_executes_file_content() -> None:
    doc = copy.deepcopy(_doc())
    doc["states"][0]["id"] = "__import__('os').system('false')"
    doc["initial"] = doc["states"][0]["id"]
    doc["original"][0] = doc["states"][0]["id"]
    for t in doc["transitions"]:
        if t["src"] == "q0":
            t["src"] = doc["initial"]
    m = lts_from_dict(doc)
    assert m.initial == "__import__('os').system('false')"
