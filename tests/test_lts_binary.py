"""The binary model form (.npz, lesmc/model/lts_binary.py): the same model as the JSON
.lts, the same answers, the same rules, and a located error for any bad file."""

from __future__ import annotations

import io
import json
import zipfile
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_run import lesmc
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lesmc.common.errors import ModelError
from lesmc.model.arrays import ArrayModel, IdArray
from lesmc.model.lts import to_arrays
from lesmc.model.lts_binary import load_lts_npz, save_lts_npz
from lesmc.model.lts_format import load_lts, lts_from_dict, lts_to_dict, save_lts
from lesmc.model.random_models import RandomModelConfig, random_lts
from lesmc.model.validate import id_array_problems
from lesmc.model.validate_arrays import check_arrays

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "tests" / "golden" / "tiny"
SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def model(seed: int, covariance: bool = True, halt: float = 0.2) -> ArrayModel:
    cfg = RandomModelConfig(steps=4, width=3, branching=(1, 3), covariance=covariance,
                            halt_prob=halt)  # fmt: skip
    return to_arrays(random_lts(cfg, seed=seed))


@SETTINGS
@given(seed=st.integers(0, 2**31), covariance=st.booleans(), halt=st.sampled_from([0.0, 0.3]))
def test_the_binary_form_holds_the_model_the_json_holds(
    tmp_path_factory: pytest.TempPathFactory, seed: int, covariance: bool, halt: float
) -> None:
    m = model(seed, covariance, halt)
    d = tmp_path_factory.mktemp("npz")
    save_lts(m, d / "m.lts")
    save_lts(m, d / "m.npz")  # the suffix chooses the form
    assert zipfile.is_zipfile(d / "m.npz")
    from_json, from_npz = load_lts(d / "m.lts"), load_lts(d / "m.npz")
    assert lts_to_dict(from_npz) == lts_to_dict(from_json) == lts_to_dict(m)


def test_check_answers_the_same_from_both_forms(tmp_path: Path) -> None:
    scene, spec = ROOT / "examples" / "merge.json", ROOT / "examples" / "merge.spec"
    answers = []
    for name in ("m.lts", "m.npz"):
        out = tmp_path / name
        r = lesmc("build", str(scene), "--window", "6..8", "-o", str(out))
        assert r.returncode == 0, r.stderr
        r = lesmc("check", str(out), str(spec), "--json")
        assert r.returncode in (0, 1) and "Traceback" not in r.stderr, r.stderr
        answers.append([{k: v for k, v in x.items() if k != "stats"}
                        for x in json.loads(r.stdout)["results"]])  # fmt: skip
    assert answers[0] == answers[1] and answers[0]


def _arrays(path: Path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def _write(path: Path, arrays: dict[str, np.ndarray]) -> None:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    path.write_bytes(buf.getvalue())


MUTATIONS = st.sampled_from(
    ["drop", "extra", "dtype", "int", "float", "header", "version", "truncate", "object", "id"]
)


@SETTINGS
@given(seed=st.integers(0, 2**31), how=MUTATIONS, pick=st.integers(0, 10**6))
def test_a_mutated_file_loads_or_is_a_located_model_error(
    tmp_path_factory: pytest.TempPathFactory, seed: int, how: str, pick: int
) -> None:
    """Never another exception, whatever is changed; and what loads is a valid model
    (the JSON form's rules accept it too)."""
    d = tmp_path_factory.mktemp("mut")
    good = d / "m.npz"
    save_lts_npz(model(seed), good)
    arrays = _arrays(good)
    names = sorted(k for k in arrays if k != "header")
    name = names[pick % len(names)]
    a = arrays[name]
    if how == "drop":
        del arrays[name]
    elif how == "extra":
        arrays["surprise"] = np.zeros(3)
    elif how == "dtype" and a.dtype.kind == "S":
        arrays[name] = a.astype(str)
    elif how == "dtype":
        arrays[name] = a.astype(np.int32 if a.dtype != np.int32 else np.float64)
    elif how == "id" and "ids" in arrays:  # one byte of one id: order, duplicates, UTF-8
        raw = arrays["ids"].copy()
        cells = raw.view(np.uint8)
        cells[pick % cells.size] = [0, 0x80, 0xE2, ord("q"), ord("0")][pick % 5]
        arrays["ids"] = raw
    elif how == "int" and a.size and a.dtype == np.int64:
        a = a.copy()
        a.flat[pick % a.size] = (pick % 7) - 3 + int(a.flat[pick % a.size])
        arrays[name] = a
    elif how == "float" and a.size and a.dtype == np.float64:
        a = a.copy()
        a.flat[pick % a.size] = [np.nan, np.inf, -1.0, 0.0][pick % 4]
        arrays[name] = a
    elif how == "header":
        text = arrays["header"].tobytes()[: pick % 40]
        arrays["header"] = np.frombuffer(text + b"}", dtype=np.uint8)
    elif how == "version":
        head = json.loads(arrays["header"].tobytes())
        head["version"] = True
        arrays["header"] = np.frombuffer(json.dumps(head).encode(), dtype=np.uint8)
    bad = d / "bad.npz"
    if how == "truncate":
        raw = good.read_bytes()
        bad.write_bytes(raw[: pick % len(raw)])
    elif how == "object":
        buf = io.BytesIO()
        np.save(buf, np.array([{"x": 1}], dtype=object), allow_pickle=True)
        with zipfile.ZipFile(bad, "w") as z:
            z.writestr("header.npy", buf.getvalue())
    else:
        _write(bad, arrays)
    try:
        got = load_lts_npz(bad)
    except ModelError as exc:
        assert exc.location is not None and exc.location.path == str(bad)
        return
    assert lts_to_dict(lts_from_dict(lts_to_dict(got))) == lts_to_dict(got)


@SETTINGS
@given(seed=st.integers(0, 2**31), which=st.integers(0, 10**6), kind=st.integers(0, 3))
def test_the_binary_form_refuses_what_the_json_form_refuses(
    tmp_path_factory: pytest.TempPathFactory, seed: int, which: int, kind: int
) -> None:
    """One set of rules: a model broken in its values (halting, payoffs, the original
    path, the ranks' unique minimum) is refused by both readers, or by neither."""
    m = model(seed)
    if kind == 0:
        halted = m.halted.copy()
        halted[which % m.n_states] ^= True
        m = replace(m, halted=halted)
    elif kind == 1 and m.payoff.size:
        payoff = m.payoff.copy()
        payoff[which % payoff.size] = [-1.0, np.nan, np.inf][which % 3]
        m = replace(m, payoff=payoff)
    elif kind == 2:
        original = m.original.copy()
        original[which % original.size] = which % m.n_states
        m = replace(m, original=original)
    elif kind == 3 and m.rank.size:
        rank = m.rank.copy()
        q = int(np.searchsorted(m.ptr, which % m.rank.size, side="right") - 1)
        rank[m.ptr[q] : m.ptr[q + 1]] = 0  # every successor of q at the lowest rank
        m = replace(m, rank=rank)
    path = tmp_path_factory.mktemp("rules") / "m.npz"
    save_lts_npz(m, path)
    try:
        load_lts_npz(path)
        binary_ok = True
    except ModelError:
        binary_ok = False
    try:
        lts_from_dict(json.loads(json.dumps(lts_to_dict(m))))
        json_ok = True
    except (ModelError, ValueError):  # ValueError: a non-finite number has no JSON
        json_ok = False
    assert binary_ok == json_ok


def test_a_bad_binary_model_is_a_located_error_through_the_cli(tmp_path: Path) -> None:
    good = tmp_path / "m.npz"
    save_lts_npz(load_lts(TINY / "model.lts"), good)
    arrays = _arrays(good)
    arrays["dst"] = arrays["dst"].astype(np.float64)
    _write(tmp_path / "bad.npz", arrays)
    r = lesmc("check", str(tmp_path / "bad.npz"), str(TINY / "properties.spec"))
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert f"{tmp_path / 'bad.npz'}: array 'dst': must be int64" in r.stderr
    (tmp_path / "text.npz").write_text("not a zip")
    r = lesmc("check", str(tmp_path / "text.npz"), str(TINY / "properties.spec"))
    assert r.returncode == 2 and "not a lesmc binary model" in r.stderr, r.stderr


def _swap_first_pair(ids: np.ndarray, step: np.ndarray) -> np.ndarray:
    """Two rows of one step in the wrong order."""
    ids = ids.copy()
    k = int(np.flatnonzero(step[1:] == step[:-1])[0])
    ids[[k, k + 1]] = ids[[k + 1, k]]
    return ids


def _split_character(ids: np.ndarray, step: np.ndarray) -> np.ndarray:
    """A 3-byte character begun at the end of a full row, ended in the next one."""
    n = len(ids)
    out = np.array([b"q%06d" % i for i in range(n)], dtype="S8")
    cells = out.view(np.uint8).reshape(n, 8)
    cells[0, 6:] = [0xE2, 0x82]
    cells[1, 0] = 0xAC
    return out


def _first_and_last_alike(ids: np.ndarray, step: np.ndarray) -> np.ndarray:
    """The first state (step 0, alone there) and the last (the last step) share an id."""
    assert step[1] > step[0] < step[-1]
    out = np.array([b"q%06d" % i for i in range(len(ids))], dtype="S8")
    out[0] = out[-1]
    return out


#: Broken id arrays (version 2) and what the error must say.
CRAFTED_IDS = {
    "empty id": (
        lambda ids, step: np.concatenate([np.array([b""], ids.dtype), ids[1:]]),
        "row 0: state ids must be non-empty strings",
    ),
    "id order": (_swap_first_pair, "states must be in (step, id) order"),
    "same id in two steps": (_first_and_last_alike, "state ids must be unique"),
    "same id in one step": (
        lambda ids, step: np.full(len(ids), b"q", ids.dtype),
        "state ids must be unique",
    ),
    "not UTF-8": (
        lambda ids, step: np.where(np.arange(len(ids)) == 1, b"\xff", ids),
        "row 1: not UTF-8",
    ),
    "split character": (_split_character, "row 1: not UTF-8"),
    "ids of numbers": (lambda ids, step: np.arange(len(ids)), "array 'ids': must be fixed-width"),
    "ids of two dimensions": (lambda ids, step: ids[:, None], "array 'ids': must be fixed-width"),
}


def _crafted(kind: str, good: Path, bad: Path) -> None:
    """A file made to break the reader in one way (issue 31's review)."""
    arrays = _arrays(good)
    head = json.loads(arrays["header"].tobytes())
    if kind == "huge shape":  # a .npy header claiming 8 TiB in a small member
        buf = io.BytesIO()
        np.lib.format.write_array_header_1_0(
            buf, {"descr": "<i8", "fortran_order": False, "shape": (2**40,)}
        )
        with zipfile.ZipFile(bad, "w") as z:
            z.writestr("dst.npy", buf.getvalue() + b"\0" * 64)
        return
    if kind in ("trailing bytes", "short member"):  # data longer / shorter than announced
        members = {}
        for name, a in arrays.items():
            buf = io.BytesIO()
            np.save(buf, a)
            members[name] = buf.getvalue()
        dst = members["dst"]
        members["dst"] = dst + b"\0" * 8 if kind == "trailing bytes" else dst[:-8]
        with zipfile.ZipFile(bad, "w") as z:
            for name, data in members.items():
                z.writestr(f"{name}.npy", data)
        return
    if kind == "raw member":  # not an .npy at all
        with zipfile.ZipFile(bad, "w") as z:
            z.writestr("rank", b"hello")
        return
    if kind == "bare npy":
        np.save(bad.with_suffix(".npy"), np.arange(3))
        bad.with_suffix(".npy").rename(bad)
        return
    if kind == "compressed":
        np.savez_compressed(bad, **arrays)
        return
    if kind == "deep header":
        arrays["header"] = np.frombuffer(b"[" * 200_000, dtype=np.uint8)
    elif kind == "label key":
        head["labels"] = {"²": ["x"]}
    elif kind == "component name":
        head["components"] = ["not a name"] * len(head["components"])
    elif kind.startswith("v1 "):  # version 1: the ids in the header
        del arrays["ids"]
        n = len(arrays["step"])
        head["version"] = 1
        head["ids"] = (
            [""] + [f"q{i}" for i in range(1, n)]
            if kind == "v1 empty id"
            else [f"q{n - i:06d}" for i in range(n)]
        )
    elif kind == "v1 ids array":  # version 1 has no ids array
        head["version"], head["ids"] = 1, None
    elif kind in CRAFTED_IDS:
        arrays["ids"] = CRAFTED_IDS[kind][0](arrays["ids"], arrays["step"])
    elif kind == "nan meta":
        arrays["header"] = np.frombuffer(
            json.dumps(head).replace('"meta": {', '"meta": {"x": NaN, ').encode(), np.uint8
        )
    if kind not in ("deep header", "nan meta"):
        arrays["header"] = np.frombuffer(json.dumps(head).encode(), dtype=np.uint8)
    _write(bad, arrays)


@pytest.mark.parametrize(
    "kind",
    [
        "huge shape",
        "trailing bytes",
        "short member",
        "raw member",
        "bare npy",
        "compressed",
        "deep header",
        "label key",
        "component name",
        "v1 empty id",
        "v1 id order",
        "v1 ids array",
        *CRAFTED_IDS,
        "nan meta",
    ],
)
def test_a_crafted_file_is_a_located_model_error(tmp_path: Path, kind: str) -> None:
    good, bad = tmp_path / "good.npz", tmp_path / "bad.npz"
    save_lts_npz(model(3), good)
    _crafted(kind, good, bad)
    with pytest.raises(ModelError) as info:
        load_lts_npz(bad)
    assert info.value.location is not None and info.value.location.path.startswith(str(bad))
    if kind in CRAFTED_IDS:
        assert CRAFTED_IDS[kind][1] in str(info.value), str(info.value)


IDS = st.text(st.characters(codec="utf-8", exclude_characters="\0"), min_size=1, max_size=4)


@SETTINGS
@given(
    ids=st.lists(st.one_of(IDS, IDS.map(lambda t: t + "\0x")), min_size=1, max_size=30),
    steps=st.lists(st.integers(0, 3), min_size=30, max_size=30),
    width=st.integers(0, 9),
)
def test_id_rules_on_the_byte_array_agree_with_python_strings(
    ids: list[str], steps: list[int], width: int
) -> None:
    """The vectorised id rules (binary form) against the same rules on Python strings:
    unique, and in (step, id) order within each step (ids with NULs inside included;
    ``width`` extra bytes of padding)."""
    step = np.array(sorted(steps[: len(ids)]), dtype=np.int64)
    coded = [i.encode() for i in ids]
    raw = np.array(coded, dtype=f"S{max(map(len, coded)) + width}")
    got = id_array_problems(raw, step)
    unique = len(set(ids)) == len(ids)
    pairs = zip(ids[:-1], ids[1:], step[:-1], step[1:], strict=True)
    ordered = all(a < b for a, b, s, t in pairs if s == t)
    assert (got == []) == (unique and ordered), got
    if not unique and ordered:
        assert "unique" in got[0][1]


@pytest.mark.parametrize(
    "ids",
    [["é", "q\0r", "ß", "z"], ["k0.0", "a\u20ac", "a\u20acb", "b"], ["end\0", "x", "y", "z"]],
)
def test_custom_ids_round_trip_through_the_binary_form(tmp_path: Path, ids: list[str]) -> None:
    """Non-ASCII ids and NULs inside an id come back as they were (version 2, the ids as
    bytes); an id ending in NUL, which the padding would eat, is written as version 1."""
    m = model(7)
    n = m.n_states
    names = [f"{ids[i % len(ids)]}{i:03d}" if i else ids[0] for i in range(n)]
    m = replace(m, ids=[names[i] for i in range(n)])
    m = lts_from_dict(lts_to_dict(m))  # the JSON form lays the rows out
    save_lts_npz(m, tmp_path / "m.npz")
    head = json.loads(_arrays(tmp_path / "m.npz")["header"].tobytes())
    assert head["version"] == (1 if any(i.endswith("\0") for i in m.state_ids()) else 2)
    got = load_lts_npz(tmp_path / "m.npz")
    assert list(got.state_ids()) == m.state_ids()
    assert lts_to_dict(got) == lts_to_dict(m)


def test_arrays_are_read_in_place_when_aligned_and_copied_when_not(tmp_path: Path) -> None:
    """lesmc's writer puts every array's data at a multiple of 64 bytes in the file (the
    reader then uses the file's bytes in place); an archive numpy.savez wrote (as
    version 1 files were) loads the same, its unaligned arrays copied."""
    m = model(11)
    ours, plain = tmp_path / "ours.npz", tmp_path / "plain.npz"
    save_lts_npz(m, ours)
    _write(plain, _arrays(ours))
    data = ours.read_bytes()
    with zipfile.ZipFile(ours) as z:
        for info in z.infolist():
            name_len, extra_len = np.frombuffer(data, "<u2", 2, info.header_offset + 26)
            start = info.header_offset + 30 + int(name_len) + int(extra_len)
            member = io.BytesIO(data[start : start + info.file_size])
            np.lib.format.read_magic(member)
            np.lib.format.read_array_header_1_0(member)
            assert (start + member.tell()) % 64 == 0, info.filename
    a, b = load_lts_npz(ours), load_lts_npz(plain)
    assert lts_to_dict(a) == lts_to_dict(b) == lts_to_dict(m)
    assert all(x.flags.aligned for x in (a.S, a.dst, a.ptr, b.S, b.dst, b.ptr))
    assert not a.S.flags.owndata  # a view of the file's bytes


def _as_bytes(ids: list[str]) -> IdArray:
    return IdArray(np.array([i.encode() for i in ids], dtype="S8"))


@pytest.mark.parametrize("held", [list, tuple, _as_bytes])
def test_ids_out_of_order_are_refused_whatever_sequence_holds_them(held: Any) -> None:
    """The (step, id) order rule holds for ids given as a list, a tuple or the binary
    form's bytes alike."""
    m = ArrayModel(
        components=("x",), step=np.array([0, 1, 1]), S=np.zeros((3, 1)),
        halted=np.zeros(3, dtype=bool), ptr=np.array([0, 2, 2, 2]), dst=np.array([1, 2]),
        payoff=np.zeros(2), rank=np.array([0, 1]), original=np.array([0, 1]),
        ids=held(["a", "z", "b"]),
    )  # fmt: skip
    with pytest.raises(ModelError, match=r"in \(step, id\) order"):
        check_arrays(m)
    check_arrays(replace(m, ids=held(["a", "b", "z"])))
