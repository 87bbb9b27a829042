"""The report's figures are drawn once per set of values (issue 31): a figure drawn from
the same values as one drawn before is taken from the report or from ``verify``'s cache,
and is then the figure a fresh drawing gives; any other values are drawn again."""

from __future__ import annotations

import copy
import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from pipeline_run import design_runs

from lesmc.experiment.cache import FigureStore, StageCache
from lesmc.language.parser import load_spec
from lesmc.report.figure_cache import figure_key
from lesmc.report.html import render
from lesmc.report.publish import publish
from lesmc.results.document import provenance
from lesmc.results.read import results_of
from lesmc.scene import load_scene

SCENES = Path(__file__).parent / "scenes"


@dataclasses.dataclass
class Point:
    x: Any
    label: Any


def _same(a: Any, b: Any) -> bool:
    """Equal values for drawing, written out on its own: the same type (a tuple and a list
    are both sequences), floats equal to the bit (all NaNs alike), arrays of the same dtype,
    shape and bytes."""
    if isinstance(a, list | tuple) and isinstance(b, list | tuple):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if type(a) is not type(b):
        return False
    if isinstance(a, float):
        return (math.isnan(a) and math.isnan(b)) or (
            a == b and math.copysign(1, a) == math.copysign(1, b)
        )
    if isinstance(a, np.ndarray):
        return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, Point):
        return _same(a.x, b.x) and _same(a.label, b.label)
    return bool(a == b)


_arrays = hnp.arrays(
    st.sampled_from([np.float64, np.float32, np.int32, np.uint8]),
    hnp.array_shapes(min_dims=0, max_dims=2, max_side=3),
)
_leaves = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-3, 3),
    st.floats(width=64) | st.sampled_from([0.0, -0.0, 1.0]),
    st.text(max_size=3),
    _arrays,
)
_values = st.recursive(
    _leaves,
    lambda inner: st.one_of(
        st.lists(inner, max_size=3),
        st.lists(inner, max_size=3).map(tuple),
        st.dictionaries(st.text(max_size=2), inner, max_size=3),
        st.builds(Point, inner, inner),
    ),
    max_leaves=8,
)


def _draw(*args: Any) -> bytes:
    return b""


@settings(max_examples=400, deadline=None)
@given(_values, st.data())
def test_two_figures_share_a_key_exactly_when_drawn_from_equal_values(a: Any, data: Any) -> None:
    b = data.draw(st.one_of(st.just(copy.deepcopy(a)), _values))
    assert (figure_key(_draw, (a,)) == figure_key(_draw, (b,))) == _same(a, b)


def test_a_flipped_bit_or_another_function_is_another_figure() -> None:
    x = np.linspace(0.0, 1.0, 50)
    y = x.copy()
    y.view(np.uint64)[17] ^= 1  # the last bit of one value
    assert figure_key(_draw, (x,)) != figure_key(_draw, (y,))

    def other(*args: Any) -> bytes:
        return b""

    assert figure_key(_draw, (x,)) != figure_key(other, (x,))
    assert figure_key(_draw, (object(),)) is None  # not readable exactly: never cached


class _Store:
    """A store in memory that counts what it is asked."""

    def __init__(self) -> None:
        self.pngs: dict[str, bytes] = {}
        self.found = 0

    def get(self, key: str) -> bytes | None:
        png = self.pngs.get(key)
        self.found += png is not None
        return png

    def put(self, key: str, png: bytes) -> None:
        self.pngs[key] = png


def _doc(tmp_path: Path) -> dict[str, Any]:
    scene = load_scene(SCENES / "rq4_merge.json")
    specs = [load_spec(str(SCENES / "rq4_merge.spec"))]
    runs = design_runs(scene, specs, ["single", "improved"])
    return publish(runs, tmp_path / "rep", {}, provenance(specs, ["test"]))[1]


def test_figures_from_the_store_are_the_figures_drawn_afresh(tmp_path: Path) -> None:
    doc = json.loads(json.dumps(_doc(tmp_path)))  # as read from results.json
    fresh = render(results_of(doc))[1]
    store = _Store()
    first = render(results_of(doc), None, store)[1]
    assert first == fresh and store.found == 0
    drawn = len(store.pngs)
    assert drawn < len(fresh)  # the two designs share figures: each drawn once
    again = render(results_of(doc), None, store)[1]
    assert again == fresh and store.found == drawn and len(store.pngs) == drawn

    # one counterexample's deviations changed: only its figure is drawn again
    run = doc["runs"][0]
    cex = run["results"][0]["counterexample"]["deviation"]
    k = next(k for k, v in enumerate(cex) if isinstance(v, float) and v > 0)
    cex[k] *= 1.5
    changed = render(results_of(doc), None, store)[1]
    assert changed == render(results_of(doc))[1]
    assert len(store.pngs) == drawn + 1
    assert [n for n in fresh if changed[n] != fresh[n]] == ["single-robustness-deviation.png"]


def test_a_damaged_entry_in_verify_s_cache_is_drawn_again(tmp_path: Path) -> None:
    cache = StageCache(tmp_path)
    store = FigureStore(cache)
    png = b"\x89PNG\r\n\x1a\n" + bytes(range(256))
    store.put("k", png)
    assert store.get("k") == png and store.get("other") is None
    entry = json.loads(cache.path("figure", "k").read_text())
    for damage in ("!!", entry["value"]["png"][:-4] + "AAAA", "aGVsbG8="):
        cache.put("figure", "k", {"png": damage, "sha256": entry["value"]["sha256"]})
        assert store.get("k") is None
    cache.put("figure", "k", {"png": entry["value"]["png"]})
    assert store.get("k") is None
