"""The .lts loader: every problem reported by id; round trip; atomic writes."""

from __future__ import annotations

import copy
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as hs

from lesmc.common import files as fileio
from lesmc.common.errors import ModelError
from lesmc.model.arrays import ArrayModel
from lesmc.model.lts import to_arrays
from lesmc.model.lts_format import load_lts, lts_from_dict, lts_to_dict, save_lts
from lesmc.model.random_models import RandomModelConfig, random_lts

GOLDEN = Path(__file__).parent / "golden"
TINY = GOLDEN / "tiny" / "model.lts"
GOLDEN_MODELS = sorted(GOLDEN.glob("*/model.lts"))


def _doc() -> dict:
    return json.loads(TINY.read_text())


def _problem(doc: dict) -> str:
    with pytest.raises(ModelError) as exc:
        lts_from_dict(doc, "m.lts")
    return exc.value.render()


def test_load_tiny() -> None:
    m = load_lts(TINY)
    assert isinstance(m, ArrayModel)
    assert m.end == 3 and m.components == ("x",) and m.has_covariance
    q0 = m.index("q0")
    assert m.initial == q0 == 0
    assert [m.state_id(int(m.dst[t])) for t in m.out(q0)] == ["a", "b", "c"]
    assert m.combined[m.out(q0)[2]] == 5.0
    assert m.halted[m.index("bH")] and int(m.halted.sum()) == 1
    assert [m.state_id(int(q)) for q in m.original] == ["q0", "a", "a2", "a3"]
    assert m.obs_of(m.edge(m.index("b"), m.index("bH"))) is None
    assert m.obs_of(m.edge(q0, m.index("c"))) == "1:c"


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
    m = to_arrays(random_lts(RandomModelConfig(steps=5, covariance=True), seed=4))
    save_lts(m, tmp_path / "r.lts")
    again = load_lts(tmp_path / "r.lts")
    assert lts_to_dict(again) == lts_to_dict(m)


@pytest.mark.parametrize("path", GOLDEN_MODELS, ids=[p.parent.name for p in GOLDEN_MODELS])
def test_golden_files_round_trip(path: Path) -> None:
    """load -> lts_to_dict gives back the file's document (its ignored comment aside)."""
    doc = json.loads(path.read_text())
    doc.pop("comment", None)
    again = lts_to_dict(load_lts(path))
    assert again == doc
    assert json.loads(json.dumps(again)) == doc


def test_writing_is_atomic(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    target = tmp_path / "out.lts"
    target.write_text("old")
    m = load_lts(TINY)
    doc = lts_to_dict(m)

    def broken(*_a: object, **_k: object) -> Iterator[str]:
        yield '{"format": '  # half a file written, then the disk fills up
        raise RuntimeError("disk full")

    monkeypatch.setattr(fileio, "_json_chunks", broken)
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
    assert m.state_id(m.initial) == "__import__('os').system('false')"


BIG = 2**63  # one beyond int64


@pytest.mark.parametrize(
    ("path", "value", "message"),
    [
        ("version", True, "version: must be 1, got true"),
        ("version", 1.0, "version: must be 1, got 1.0"),
        ("states/1/step", True, "state 'a': step must be an integer >= 0, got True"),
        ("states/1/step", BIG, "state 'a': step must be an integer >= 0 that fits in 64 bits"),
        ("states/1/step", 10**400, "state 'a': step must be an integer >= 0 that fits in 64"),
        ("states/1/s", [True], "state 'a': s must be a non-empty list of finite numbers"),
        ("states/1/s", [10**400], "state 'a': s must be a non-empty list of finite numbers"),
        ("states/1/s", [float("nan")], "state 'a': s must be a non-empty list of finite"),
        ("states/1/s", [], "state 'a': s must be a non-empty list of finite numbers"),
        ("states/1/P", [[True]], "state 'a': P must be a square list of lists"),
        ("states/1/P", [[float("inf")]], "state 'a': P must be a square list of lists"),
        ("states/1/P", [[1], [2]], "state 'a': P must be a square list of lists"),
        ("states/1/P", None, "state 'a': P must be a square list of lists"),
        ("states/1/P", [[1, 0], [0, 1]], "state 'a': P must be 1x1, got 2x2"),
        ("states/1/labels", "halted", "state 'a': labels must be a list of strings"),
        ("states/1/labels", None, "state 'a': labels must be a list of strings"),
        ("states/1/id", "", "states[1]: id must be a non-empty string"),
        ("states/1/id", 7, "states[1]: id must be a non-empty string"),
        ("states/1", [], "states[1]: must be an object"),
        ("transitions/0", "q0->a", "transitions[0]: must be an object"),
        ("transitions/0/src", 1, "transitions[0]: src and dst must be state ids"),
        ("transitions/0/payoff", 10**400, "transition 0 (q0 -> a): payoff must be a finite"),
        ("transitions/0/payoff", False, "transition 0 (q0 -> a): payoff must be a finite"),
        ("transitions/0/rank", BIG, "transition 0 (q0 -> a): rank must be an integer that fits"),
        ("transitions/0/rank", -BIG - 1, "transition 0 (q0 -> a): rank must be an integer that"),
        ("transitions/0/rank", True, "transition 0 (q0 -> a): rank must be an integer, got True"),
        ("transitions/0/obs", 3, "transition 0 (q0 -> a): obs must be a string or absent"),
        ("transitions/0/weight", 3, "transition 0 (q0 -> a): unknown key 'weight'"),
        ("transitions/1/dst", "a", "transition 1 (q0 -> a): a second transition between"),
        ("states/4/labels", ["halted"], "state 'a2': is labelled halted but has successors"),
        ("original/2", "a2x", "original[2]: 'a2x' is not the unattacked (rank-minimal) "),
        ("original/2", "b2", "original[2]: no transition from 'a' to 'b2'"),
        ("original/3", "zz", "original[3]: unknown state 'zz'"),
        ("original/2", "c", "original[2]: state 'c' is at step 1, not 2"),
        ("original", [], "original: the original path is empty"),
        ("initial", "a", "initial: state 'a' must be at step 0"),
        ("components", ["x", "x"], "components: component names must be unique"),
        ("components", ["1x"], "components: must be a non-empty list of names"),
        ("states", [], "states: must be a non-empty list"),
        ("transitions", {}, "transitions: must be a list"),
    ],
)
def test_more_problems_are_reported_by_id(path: str, value: object, message: str) -> None:
    text = _problem(_mutate(path, value))
    assert f"m.lts: {message}" in text, text


def test_problems_come_in_file_order() -> None:
    doc = _doc()
    doc["states"][3]["step"] = -1
    doc["states"][1]["colour"] = 1
    doc["states"][1]["s"] = "x"
    doc["transitions"][2]["rank"] = 0.5
    doc["transitions"][0]["payoff"] = None
    lines = _problem(doc).splitlines()
    assert lines == [
        "m.lts: state 'a': unknown key 'colour'",
        "m.lts: state 'a': s must be a non-empty list of finite numbers",
        "m.lts: state 'c': step must be an integer >= 0, got -1",
        "m.lts: transition 0 (q0 -> a): payoff must be a finite number >= 0, got None",
        "m.lts: transition 2 (q0 -> c): rank must be an integer, got 0.5",
    ]


def test_structural_problems_come_in_file_order() -> None:
    doc = _doc()
    doc["states"].insert(0, {"id": "late", "step": 4, "s": [0]})
    doc["states"].append({"id": "lost", "step": 1, "s": [0]})
    doc["transitions"][5]["rank"] = 1  # b: two transitions of rank 1, none of rank 0
    doc["transitions"][1]["rank"] = 0  # q0: a tie at the lowest rank
    lines = _problem(doc).splitlines()
    # the order rule's problems first, then the paths', each in file order
    assert lines == [
        "m.lts: state 'q0': 2 transitions share the lowest rank 0; "
        "the unattacked successor must be unique",
        "m.lts: state 'b': 2 transitions share the lowest rank 1; "
        "the unattacked successor must be unique",
        "m.lts: state 'late': not reachable from the initial state",
        "m.lts: state 'late': step 4 is beyond the original path's end 3",
        "m.lts: state 'lost': not reachable from the initial state",
        "m.lts: state 'lost': has no successor before step 3; label it 'halted' "
        "if the tracker stopped there",
    ]


def test_layout_sorts_states_and_transitions() -> None:
    """States by (step, id) whatever the file's order; transitions by (rank, target id)."""
    doc = _doc()
    doc["states"].reverse()
    doc["transitions"].reverse()
    doc["transitions"][-1]["rank"] = 5  # q0 -> a keeps the lowest rank 0 but moves last
    doc["transitions"][-2]["rank"] = 5  # q0 -> b ties with it: ties by target id
    doc["original"] = ["q0", "c", "c2", "c3"]
    m = lts_from_dict(doc)
    assert m.ids == [st["id"] for st in _doc()["states"]]
    assert [m.state_id(int(m.dst[t])) for t in m.out(0)] == ["c", "a", "b"]
    assert m.rank[m.out(0)].tolist() == [2, 5, 5]
    back = lts_to_dict(m)
    assert [t["dst"] for t in back["transitions"][:3]] == ["c", "a", "b"]
    assert lts_to_dict(lts_from_dict(back)) == back


def test_covariances_are_deduplicated() -> None:
    m = load_lts(TINY)
    assert m.P_table is not None and m.cov is not None
    assert m.P_table.shape == (6, 1, 1)
    assert m.P_table[:, 0, 0].tolist() == [10, 5, 3, 6, 4, 2]  # in order of first use
    assert m.P(m.index("b2"))[0, 0] == 6 and m.P(m.index("c3"))[0, 0] == 3
    doc = _doc()
    del doc["states"][2]["P"]
    m = lts_from_dict(doc)
    assert m.cov is not None and m.cov[m.index("b")] == -1 and not m.has_covariance
    assert "P" not in lts_to_dict(m)["states"][2]
    for st in doc["states"]:
        st.pop("P", None)
        st.pop("labels", None)
    doc["states"][7]["labels"] = ["zeta", "halted", "alpha", "zeta"]
    for t in doc["transitions"]:
        t.pop("obs", None)
    m = lts_from_dict(doc)
    assert m.cov is None and m.P_table is None and m.obs is None and m.obs_names == ()
    assert m.labels == {m.index("bH"): ("alpha", "zeta")}
    assert lts_to_dict(m)["states"][7]["labels"] == ["alpha", "halted", "zeta"]


def test_negative_zero_is_kept_apart() -> None:
    """The covariance table deduplicates by exact bytes."""
    doc = _doc()
    doc["states"][1]["P"] = [[0.0]]
    doc["states"][2]["P"] = [[-0.0]]
    doc["states"][3]["P"] = [[0.0]]
    m = lts_from_dict(doc)
    assert m.cov is not None and m.P_table is not None
    a, b, c = (int(m.cov[m.index(q)]) for q in ("a", "b", "c"))
    assert a == c != b
    assert np.signbit(m.P_table[b, 0, 0]) and not np.signbit(m.P_table[a, 0, 0])


def test_ids_with_nul_characters_sort_as_python_strings() -> None:
    doc = _doc()
    rename = {"b": "a\x00", "c": "a\x00\x00"}
    for st in doc["states"]:
        st["id"] = rename.get(st["id"], st["id"])
    for t in doc["transitions"]:
        t["src"], t["dst"] = rename.get(t["src"], t["src"]), rename.get(t["dst"], t["dst"])
    m = lts_from_dict(doc)
    assert m.ids is not None and m.ids[1:4] == ["a", "a\x00", "a\x00\x00"]
    assert lts_to_dict(m)["states"] == sorted(doc["states"], key=lambda s: (s["step"], s["id"]))


def test_meta_is_kept_and_comment_ignored() -> None:
    doc = _doc()
    doc["meta"] = {"source": "test", "window": [1, 2]}
    m = lts_from_dict(doc)
    assert m.meta == {"source": "test", "window": [1, 2]}
    out = lts_to_dict(m)
    assert out["meta"] == doc["meta"] and "comment" not in out


# --- random mutations never raise anything but ModelError ------------------------------

_scalars = hs.one_of(
    hs.none(),
    hs.booleans(),
    hs.integers(),
    hs.integers(min_value=2**62, max_value=2**70),
    hs.integers(max_value=-(2**62), min_value=-(2**70)),
    hs.sampled_from([10**400, -(10**400), 2**63 - 1, -(2**63), 0, -1]),
    hs.floats(),
    hs.text(max_size=4),
    hs.sampled_from(["q0", "a", "b", "a2", "bH", "halted", "lesmc-lts", "x"]),
)
_values = hs.recursive(
    _scalars,
    lambda inner: hs.one_of(
        hs.lists(inner, max_size=3), hs.dictionaries(hs.text(max_size=3), inner, max_size=3)
    ),
    max_leaves=6,
)


def _paths(doc: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    out = [prefix]
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            out += _paths(v, (*prefix, i))
    return out


def _mutate_once(doc: Any, data: hs.DataObject) -> Any:
    paths = [p for p in _paths(doc) if p]
    path = data.draw(hs.sampled_from(paths))
    parent = doc
    for k in path[:-1]:
        parent = parent[k]
    last = path[-1]
    kind = data.draw(hs.sampled_from(["drop", "set", "dup", "swap", "key", "huge"]))
    if kind == "drop":
        del parent[last]
    elif kind == "set":
        parent[last] = data.draw(_values)
    elif kind == "huge":
        parent[last] = data.draw(hs.sampled_from([2**63, -(2**63) - 1, 10**400, 2**64 + 1]))
    elif kind == "dup":
        if isinstance(parent, list):
            parent.insert(data.draw(hs.integers(0, len(parent))), copy.deepcopy(parent[last]))
        else:
            parent[data.draw(hs.text(max_size=3))] = copy.deepcopy(parent[last])
    elif kind == "swap":
        states = doc.get("states") if isinstance(doc, dict) else None
        if isinstance(states, list) and len(states) > 1:
            i = data.draw(hs.integers(0, len(states) - 1))
            j = data.draw(hs.integers(0, len(states) - 1))
            if isinstance(states[i], dict) and isinstance(states[j], dict):
                a, b = states[i].get("id"), states[j].get("id")
                states[i]["id"], states[j]["id"] = b, a
    elif isinstance(parent, dict):
        parent[data.draw(hs.text(max_size=3))] = data.draw(_values)
    return doc


def _base_docs() -> list[dict[str, Any]]:
    cfg = RandomModelConfig(steps=3, width=3, covariance=True, halt_prob=0.3)
    return [_doc(), lts_to_dict(to_arrays(random_lts(cfg, seed=1)))]


_BASES = _base_docs()


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(hs.data())
def test_mutations_raise_only_model_errors(data: hs.DataObject) -> None:
    doc = copy.deepcopy(data.draw(hs.sampled_from(_BASES)))
    for _ in range(data.draw(hs.integers(1, 3))):
        doc = _mutate_once(doc, data)
    try:
        m = lts_from_dict(doc, "m.lts")
    except ModelError as exc:
        text = exc.render()
        assert text.startswith("m.lts: "), text
        return
    again = lts_to_dict(m)
    assert lts_to_dict(lts_from_dict(json.loads(json.dumps(again)))) == again


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=hs.integers(0, 2**31),
    covariance=hs.booleans(),
    halt=hs.sampled_from([0.0, 0.3]),
    odd_ids=hs.booleans(),
)
def test_the_column_writer_writes_what_json_reads_as_the_document(
    tmp_path_factory: pytest.TempPathFactory,
    seed: int,
    covariance: bool,
    halt: float,
    odd_ids: bool,
) -> None:
    """save_lts formats rows column by column; json's own parser must read the file as
    lts_to_dict's document, and the generic writer must lay that document out in the
    same bytes (ids needing escapes, labels, halting, no covariance, observations)."""
    from dataclasses import replace

    cfg = RandomModelConfig(steps=4, width=3, covariance=covariance, halt_prob=halt)
    m = to_arrays(random_lts(cfg, seed=seed))
    if odd_ids:
        ids = m.ids or [m.state_id(i) for i in range(m.n_states)]
        m = replace(m, ids=[f'{s}"\\é\t{i}' for i, s in enumerate(ids)], labels={0: ("x<y",)})
    path = tmp_path_factory.mktemp("lts") / "m.lts"
    save_lts(m, path)
    text = path.read_text()
    assert json.loads(text) == lts_to_dict(m)
    assert text == fileio.json_text(lts_to_dict(m))
    assert lts_to_dict(load_lts(path)) == lts_to_dict(m)


def test_a_model_with_a_non_finite_number_is_refused_by_the_writer(tmp_path: Path) -> None:
    m = to_arrays(random_lts(RandomModelConfig(steps=3, covariance=True), seed=2))
    m.S[1, 0] = np.inf
    with pytest.raises(ValueError):
        save_lts(m, tmp_path / "m.lts")
    assert not list(tmp_path.iterdir())  # nothing half-written
