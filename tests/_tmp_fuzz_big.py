"""A damaged multi-target model file (``lesmc-multi-npz``) is a located ModelError (exit
status 2), never an internal error: bytes flipped or cut, arrays changed in value, dtype or
shape, header fields changed or dropped. A file that still loads is one the engine checks
without an internal error."""

from __future__ import annotations

import contextlib
import json
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_run import lesmc
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import lesmc as api
from lesmc.common.errors import LesmcError, ModelError
from lesmc.language.parser import parse_spec
from lesmc.model.lts_binary import read_npz, write_npz
from lesmc.model.multi import MultiModel
from lesmc.model.multi_format import load_model_file
from lesmc.pipeline.multi import check_multi_model

pytest.importorskip("sort_tracker")
from test_multi_build import _case

SETTINGS = settings(
    max_examples=1500,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)


@cache
def _model_bytes() -> tuple[bytes, str]:
    """A small built model's file, and the spec it was built for."""
    import tempfile

    doc, text = _case(2)
    spec = parse_spec(text, "p.spec")
    with tempfile.TemporaryDirectory() as tmp:
        scene = Path(tmp) / "s.json"
        scene.write_text(json.dumps(doc))
        model = api.build(scene, None, spec=spec, property="hijack")
        path = Path(tmp) / "m.npz"
        api.save_model(model, path)
        return path.read_bytes(), text


def _load(path: Path) -> None:
    """Load the file; if it loads, check every property on it: only LesmcErrors escape."""
    try:
        model = load_model_file(path)
    except ModelError as exc:
        assert str(path) in exc.render()
        return
    assert isinstance(model, MultiModel)
    with contextlib.suppress(LesmcError):
        check_multi_model(model, (parse_spec(_model_bytes()[1], "p.spec"),))


@SETTINGS
@given(
    cut=st.one_of(st.none(), st.integers(0, 40_000)),
    edits=st.lists(st.tuples(st.integers(0, 40_000), st.integers(0, 255)), max_size=4),
)
def test_bytes_flipped_or_cut_are_located_errors(
    tmp_path: Path, cut: int | None, edits: list[tuple[int, int]]
) -> None:
    raw = bytearray(_model_bytes()[0])
    for pos, byte in edits:
        raw[pos % len(raw)] = byte
    if cut is not None:
        raw = raw[: cut % len(raw)]
    path = tmp_path / "m.npz"
    path.write_bytes(bytes(raw))
    _load(path)


def _arrays(tmp: Path) -> dict[str, np.ndarray]:
    """The model file's arrays (copies), its header among them."""
    p = tmp / "orig.npz"
    p.write_bytes(_model_bytes()[0])
    return {k: np.array(v) for k, v in read_npz(str(p)).items()}


_VALUES = st.one_of(
    st.integers(-(2**63), 2**63 - 1),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([-1, 0, 1, 2, 3, 10**6]),
)
_JSON = st.recursive(
    st.one_of(
        st.none(), st.booleans(), st.integers(-5, 10**7), st.floats(-1e9, 1e9), st.text(max_size=4)
    ),
    lambda inner: st.one_of(
        st.lists(inner, max_size=3), st.dictionaries(st.text(max_size=3), inner, max_size=3)
    ),
    max_leaves=6,
)


@SETTINGS
@given(data=st.data())
def test_arrays_and_header_changed_are_located_errors(tmp_path: Path, data: Any) -> None:
    arrays = _arrays(tmp_path)
    head = json.loads(arrays["header"].tobytes())
    kind = data.draw(st.sampled_from(["value", "dtype", "shape", "drop", "header", "meta"]))
    names = sorted(k for k in arrays if k != "header")
    name = data.draw(st.sampled_from(names))
    a = arrays[name]
    if kind == "value" and a.size:
        i = data.draw(st.integers(0, a.size - 1))
        flat = a.reshape(-1).copy()
        v = data.draw(_VALUES)
        try:
            flat[i] = v
        except (OverflowError, ValueError, TypeError):
            return
        arrays[name] = flat.reshape(a.shape)
    elif kind == "dtype":
        arrays[name] = a.astype(data.draw(st.sampled_from([np.int32, np.float32, np.uint8, bool])))
    elif kind == "shape":
        arrays[name] = a.reshape(-1)[: max(0, a.size - data.draw(st.integers(0, 3)))]
    elif kind == "drop":
        del arrays[name]
    elif kind == "header":
        key = data.draw(st.sampled_from(sorted(head)))
        if data.draw(st.booleans()):
            del head[key]
        else:
            head[key] = data.draw(_JSON)
    else:
        key = data.draw(st.sampled_from(sorted(head["meta"])))
        head["meta"][key] = data.draw(_JSON)
    arrays["header"] = np.frombuffer(json.dumps(head).encode(), dtype=np.uint8)
    path = tmp_path / "m.npz"
    with open(path, "wb") as fh:
        write_npz(fh, arrays)
    _load(path)


def test_a_truncated_model_is_exit_2_at_the_file(tmp_path: Path) -> None:
    raw, text = _model_bytes()
    path, spec = tmp_path / "m.npz", tmp_path / "p.spec"
    path.write_bytes(raw[: len(raw) // 2])
    spec.write_text(text)
    r = lesmc("check", str(path), str(spec))
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert r.stderr.startswith(f"error: {path}") or str(path) in r.stderr, r.stderr
    # a wrong index inside a sound archive: the array and transition are named
    good = tmp_path / "g.npz"
    good.write_bytes(raw)
    arrays = {k: np.array(v) for k, v in read_npz(str(good)).items()}
    arrays["dst"] = arrays["dst"].copy()
    arrays["dst"][0] = 10**9
    with open(path, "wb") as fh:
        write_npz(fh, arrays)
    r = lesmc("check", str(path), str(spec))
    assert r.returncode == 2 and "array 'dst'[0]" in r.stderr, r.stderr
