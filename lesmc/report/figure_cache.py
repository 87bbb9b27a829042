"""The report's figures by file name, each drawn or found again by what it is drawn from.

Drawing the report's figures is most of ``lesmc report``'s time (matplotlib's text
layout and PNG encoding: docs/performance.md). Every function of
:mod:`lesmc.report.figures` is a pure function of its arguments, so a figure is
named by the SHA-256 of those arguments, bit for bit (every array's dtype, shape
and bytes, every float's exact value), of the drawing function's name, of the
source of ``figures.py`` and of matplotlib's version. A :class:`PngStore` (``lesmc
verify`` keeps one under OUT/cache) returns the PNG drawn before under the same
digest; anything else is drawn again, once per report. An argument the digest
cannot read exactly (an object of an unknown type) makes that figure uncached:
never a wrong hit.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import itertools
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

import numpy as np

#: Version of the digest's encoding: a new encoding never reads an old entry.
KEY_VERSION = b"lesmc-figure-1"


class PngStore(Protocol):
    """Where figures drawn before are kept: ``get`` a PNG by its digest, ``put`` one."""

    def get(self, key: str) -> bytes | None: ...

    def put(self, key: str, png: bytes) -> None: ...


class Unreadable(TypeError):
    """An argument whose value the digest cannot encode exactly."""


def _feed(h: Any, x: Any) -> None:
    """Add ``x`` to the hash ``h`` with its type and length, so that no two values meet."""
    if x is None:
        h.update(b"N")
    elif isinstance(x, bool | np.bool_):
        h.update(b"T" if x else b"F")
    elif isinstance(x, int | np.integer):
        h.update(b"I%d;" % int(x))
    elif isinstance(x, float | np.floating):
        h.update(b"R" + float(x).hex().encode() + b";")
    elif isinstance(x, str):
        data = x.encode("utf-8", "surrogatepass")
        h.update(b"S%d;" % len(data) + data)
    elif isinstance(x, bytes):
        h.update(b"Y%d;" % len(x) + x)
    elif isinstance(x, np.ndarray):
        if x.dtype.hasobject:
            raise Unreadable("an array of objects")
        h.update(b"A" + x.dtype.str.encode() + repr(x.shape).encode())
        h.update(np.ascontiguousarray(x).data)
    elif isinstance(x, tuple | list):
        h.update(b"L%d;" % len(x))
        for item in x:
            _feed(h, item)
    elif isinstance(x, dict):
        h.update(b"D%d;" % len(x))
        for key in sorted(x, key=repr):
            _feed(h, key)
            _feed(h, x[key])
    elif dataclasses.is_dataclass(x) and not isinstance(x, type):
        name = type(x).__qualname__.encode()
        h.update(b"C%d;" % len(name) + name)
        for f in dataclasses.fields(x):
            _feed(h, f.name)
            _feed(h, getattr(x, f.name))
    else:
        raise Unreadable(f"a {type(x).__name__}")


@functools.cache
def _code() -> bytes:
    """What draws the figures: figures.py's source and matplotlib's version (read from its
    installed metadata: a report whose figures are all cached never imports matplotlib)."""
    from importlib.metadata import version

    from lesmc.report import figures

    h = hashlib.sha256(KEY_VERSION)
    h.update(Path(figures.__file__).read_bytes())
    h.update(version("matplotlib").encode())
    return h.digest()


def figure_key(draw: Callable[..., bytes], args: tuple[Any, ...]) -> str | None:
    """The digest of ``draw(*args)``'s figure; None when an argument cannot be read exactly."""
    h = hashlib.sha256(_code())
    _feed(h, draw.__name__)
    try:
        _feed(h, args)
    except Unreadable:
        return None
    return h.hexdigest()


class FigureSet:
    """The report's figures by file name. A figure drawn from the same values as one drawn
    before is not drawn again: it is taken from this report (two designs often draw the
    same tracks) or from ``store``. The others are drawn when :attr:`pngs` is read, all
    together (:func:`lesmc.report.drawing.draw_all`)."""

    def __init__(self, store: PngStore | None = None) -> None:
        self.store = store
        self.by_key: dict[str, bytes] = {}
        #: file name -> its figure's key, or the number of a figure that has none
        self._names: dict[str, str | int] = {}
        #: the figures to draw, by key or number, in the order asked for
        self._queue: dict[str | int, tuple[Callable[..., bytes], tuple[Any, ...]]] = {}
        self._keyless: dict[int, bytes] = {}
        self._numbers = itertools.count()

    def draw(self, name: str, draw: Callable[..., bytes], *args: Any) -> None:
        """``pngs[name]`` is to be ``draw(*args)``: queued, unless the same figure is at hand."""
        key = figure_key(draw, args)
        ref: str | int = next(self._numbers) if key is None else key
        if key is None or not self._at_hand(key):
            self._queue[ref] = (draw, args)
        self._names[name] = ref

    def _at_hand(self, key: str) -> bool:
        """Whether the figure of ``key`` is drawn, queued, or in the store (then taken)."""
        if key in self.by_key or key in self._queue:
            return True
        png = None if self.store is None else self.store.get(key)
        if png is not None:
            self.by_key[key] = png
        return png is not None

    @property
    def pngs(self) -> dict[str, bytes]:
        """Every figure by file name, in the order they were asked for; the queued ones are
        drawn now and kept (here, and in ``store``)."""
        if self._queue:
            from lesmc.report.drawing import draw_all

            queue, self._queue = self._queue, {}
            pngs = draw_all(list(queue.values()))
            for ref, png in zip(queue, pngs, strict=True):
                if isinstance(ref, int):
                    self._keyless[ref] = png
                    continue
                self.by_key[ref] = png
                if self.store is not None:
                    self.store.put(ref, png)
        return {
            name: self._keyless[ref] if isinstance(ref, int) else self.by_key[ref]
            for name, ref in self._names.items()
        }
