"""The structure of a page's tables, read with the standard library's HTML parser:
what a browser would show broken (tests/test_report.py, tests/test_campaign.py)."""

from __future__ import annotations

from html.parser import HTMLParser


class _Tables(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.tables: list[list[list[tuple[str, int, str]]]] = []  # rows of (tag, span, class)
        self.rowspans: list[list[tuple[int, int, int]]] = []  # per table: (row, col, rows)
        self._stack: list[list[list[tuple[str, int, str]]]] = []
        self._row: list[tuple[str, int, str]] | None = None
        self._spans: list[list[tuple[int, int, int]]] = []
        self._row_class = ""
        self.texts: list[list[list[str]]] = []  # per table, per row: each cell's text
        self._texts: list[list[list[str]]] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = dict(attrs)
        if tag == "table":
            self._stack.append([])
            self._spans.append([])
            self._texts.append([])
        elif tag == "tr" and self._stack:
            self._row = []
            self._row_class = a.get("class") or ""
            self._stack[-1].append(self._row)
            self._texts[-1].append([])
        elif tag in ("td", "th") and self._row is not None:
            self._row.append((tag, int(a.get("colspan") or 1), self._row_class))
            self._texts[-1][-1].append("")
            rows = int(a.get("rowspan") or 1)
            if rows > 1:
                self._spans[-1].append((len(self._stack[-1]) - 1, len(self._row) - 1, rows))

    def handle_endtag(self, tag: str) -> None:
        if tag == "table" and self._stack:
            self.tables.append(self._stack.pop())
            self.rowspans.append(self._spans.pop())
            self.texts.append(self._texts.pop())
            self._row = None

    def handle_data(self, data: str) -> None:
        if self._texts and self._texts[-1] and self._texts[-1][-1]:
            self._texts[-1][-1][-1] += data


def table_problems(page: str) -> list[str]:
    """Tables whose rows have different numbers of columns, or empty header rows."""
    parser = _Tables()
    parser.feed(page)
    out = []
    for i, rows in enumerate(parser.tables):
        widths = [sum(span for _, span, _ in row) for row in rows]
        for r, _, n in parser.rowspans[i]:  # a cell spanning rows fills the ones below
            for below in range(r + 1, min(r + n, len(rows))):
                widths[below] += 1
        widths = [w for w, row in zip(widths, rows, strict=True) if row]
        if len(set(widths)) > 1:
            out.append(f"table {i}: rows of {sorted(set(widths))} columns")
        if any(not row for row in rows):
            out.append(f"table {i}: an empty row")
        for row, texts in zip(rows, parser.texts[i], strict=True):
            if row and all(tag == "th" for tag, _, _ in row) and not "".join(texts).strip():
                out.append(f"table {i}: an empty header row")
    return out
