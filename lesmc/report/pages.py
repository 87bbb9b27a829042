"""HTML pages from Jinja2 templates (lesmc/report/templates): report.html, campaign.html.

The templates hold the pages' structure: one template per page, both extending
``base.html.j2`` (head, style), every table drawn by one macro (``macros.html.j2``).
Python hands them data: a :class:`Table` is built from its header and rows and
refuses rows that are not as wide as its header, so a table cannot come out
broken; text is escaped by the templates (autoescape), markup passes only as
:class:`markupsafe.Markup`.
"""

from __future__ import annotations

import base64
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cache
from typing import Any, ClassVar

import jinja2
from markupsafe import Markup

__all__ = [
    "Cell",
    "Figure",
    "Markup",
    "Row",
    "Table",
    "Text",
    "images",
    "key_values",
    "para",
    "render_page",
    "table",
]


@dataclass(frozen=True)
class Cell:
    """A table cell: its text (escaped unless Markup), class, spans, th or td."""

    text: Any
    cls: str = ""
    span: int = 1
    rows: int = 1
    head: bool = False


@dataclass(frozen=True)
class Row:
    cells: Sequence[Cell]
    cls: str = ""


@dataclass(frozen=True)
class Table:
    """A table: header rows (cells that may span) and body rows, as wide as the header."""

    head: Sequence[Sequence[Cell]]
    rows: Sequence[Row]
    cls: str = ""
    width: int = field(init=False)
    kind: ClassVar[str] = "table"

    def __post_init__(self) -> None:
        widths = _widths([*self.head, *(r.cells for r in self.rows)])
        width = max(widths[: len(self.head)], default=None)
        if width is None:
            width = max(widths, default=0)
        bad = [i for i, w in enumerate(widths) if w != width]
        if bad:
            raise ValueError(f"table rows {bad} are not {width} columns wide: {widths}")
        object.__setattr__(self, "width", width)


def _widths(rows: Sequence[Sequence[Cell]]) -> list[int]:
    """Each row's width, counting the cells that rows above span into it."""
    widths = [sum(c.span for c in r) for r in rows]
    for i, r in enumerate(rows):
        for c in r:
            for below in range(i + 1, min(i + c.rows, len(rows))):
                widths[below] += c.span
    return widths


def table(head: Sequence[Any], rows: Sequence[Sequence[Any]], cls: str = "") -> Table:
    """A table of one header row and plain rows (each value a cell's text; Cells pass)."""
    return Table(
        [[c if isinstance(c, Cell) else Cell(c, head=True) for c in head]],
        [Row([c if isinstance(c, Cell) else Cell(c) for c in r]) for r in rows],
        cls,
    )


def key_values(pairs: Sequence[tuple[str, Any]]) -> Table:
    """A two-column table of names (row headers) and values, without a header row."""
    return Table([], [Row([Cell(k, head=True), Cell(v)]) for k, v in pairs], "meta")


@dataclass(frozen=True)
class Figure:
    """A figure: the PNG's name (its data URI is filled in by the page) and caption."""

    name: str
    caption: str
    kind: ClassVar[str] = "figure"


@dataclass(frozen=True)
class Text:
    """A paragraph (``p``, Markup or text), a list (``ul``: ``items``) or a heading (``h3``)."""

    kind: str
    text: Any = ""
    cls: str = ""
    items: Sequence[Any] = ()


def para(text: Any, cls: str = "") -> Text:
    return Text("p", text, cls)


def images(figs: dict[str, bytes], scale: int = 1) -> dict[str, dict[str, Any]]:
    """Each PNG as a data URI with its size on the page (its pixels divided by ``scale``:
    figures drawn at 2x are shown at half their natural size, sharp)."""
    out = {}
    for name, png in figs.items():
        w, h = int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")
        uri = "data:image/png;base64," + base64.b64encode(png).decode()
        out[name] = {"uri": uri, "width": w // scale, "height": h // scale}
    return out


@cache
def _environment() -> jinja2.Environment:
    return jinja2.Environment(
        loader=jinja2.PackageLoader("lesmc.report", "templates"),
        autoescape=True,
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
    )


def render_page(template: str, **context: Any) -> str:
    """The page ``template`` rendered with ``context``."""
    return _environment().get_template(template).render(**context)
