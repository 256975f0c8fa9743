"""Reading a report page back with the standard library's HTML parser (no lxml): its tables, row by row,
and the elements the tests ask about (links, scroll boxes, style rules).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from html.parser import HTMLParser


@dataclass
class Cell:
    text: str
    attrs: dict[str, str]


@dataclass
class Table:
    """One ``<table>``: its attributes, header texts, body rows (cells with attributes), and its ancestors'
    classes (``in_scroll``: it sits in a ``div.scroll``)."""

    attrs: dict[str, str]
    headers: list[str] = field(default_factory=list)
    rows: list[list[Cell]] = field(default_factory=list)
    row_attrs: list[dict[str, str]] = field(default_factory=list)
    in_scroll: bool = False

    def column(self, header_start: str) -> list[str]:
        """The texts of the first column whose header starts with ``header_start``."""
        j = next(i for i, h in enumerate(self.headers) if h.startswith(header_start))
        return [r[j].text for r in self.rows]

    def cell(self, row_key: str, header_start: str) -> Cell:
        j = next(i for i, h in enumerate(self.headers) if h.startswith(header_start))
        return next(r[j] for r in self.rows if r[0].text == row_key)


class _Parser(HTMLParser):
    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.tables: list[Table] = []
        self.stack: list[tuple[str, dict[str, str]]] = []
        self.current: list[Table] = []
        self.text: list[str] | None = None
        self.cell_attrs: dict[str, str] = {}
        self.in_head = False
        self.links: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = {k: v or "" for k, v in attrs}
        if tag == "a" and "href" in a:
            self.links.append(a["href"])
        if tag in ("img", "source", "br", "meta", "wbr", "hr"):
            return
        self.stack.append((tag, a))
        if tag == "table":
            scroll = any(t == "div" and "scroll" in x.get("class", "").split() for t, x in self.stack[:-1])
            self.current.append(Table(a, in_scroll=scroll))
        elif tag == "thead":
            self.in_head = True
        elif tag == "tr" and self.current and not self.in_head:
            self.current[-1].rows.append([])
            self.current[-1].row_attrs.append(a)
        elif tag in ("td", "th") and self.current:
            self.text, self.cell_attrs = [], a

    def handle_endtag(self, tag: str) -> None:
        while self.stack:
            t, _ = self.stack.pop()
            if t == tag:
                break
        if tag in ("td", "th") and self.current and self.text is not None:
            text = re.sub(r"\s+", " ", "".join(self.text)).strip()
            if self.in_head:
                self.current[-1].headers.append(text)
            else:
                self.current[-1].rows[-1].append(Cell(text, self.cell_attrs))
            self.text = None
        elif tag == "thead":
            self.in_head = False
        elif tag == "table" and self.current:
            self.tables.append(self.current.pop())

    def handle_data(self, data: str) -> None:
        if self.text is not None:
            self.text.append(data)


def parse_page(html: str) -> tuple[list[Table], list[str]]:
    """The page's tables (in document order of their end) and every link's href."""
    parser = _Parser()
    parser.feed(html)
    return parser.tables, parser.links


def table_by_id(html: str, table_id: str) -> Table:
    tables, _ = parse_page(html)
    return next(t for t in tables if t.attrs.get("id") == table_id)


def style_rules(html: str) -> str:
    """Every inline ``<style>`` block of the page, joined."""
    return "\n".join(re.findall(r"<style>(.*?)</style>", html, re.S))
