"""A very small HTML builder for self-contained reports (no template engine, no external assets).

Every text that comes from data goes through :func:`esc` (``html.escape``); builders take
already-built HTML fragments as :class:`Html` so escaping happens exactly once.
Figures are embedded as ``data:image/png;base64`` URIs (:func:`figure_img`).
"""

from __future__ import annotations

import base64
import html
import io
import math
from collections.abc import Iterable, Sequence
from typing import Any


class Html(str):
    """A string that is already HTML (not escaped again)."""


def esc(value: Any) -> Html:
    """``value`` as escaped HTML text (an :class:`Html` value is returned unchanged)."""
    if isinstance(value, Html):
        return value
    return Html(html.escape("" if value is None else str(value), quote=True))


VOID_ELEMENTS = frozenset({"br", "hr", "img", "meta", "wbr"})


def tag(name: str, body: Any = "", **attrs: Any) -> Html:
    """``<name attrs>body</name>`` (``<name attrs>`` for void elements such as ``br``).

    Attribute names lose a trailing ``_`` (``class_``) and ``_`` becomes ``-``.
    """
    parts = [name]
    for key, val in attrs.items():
        if val is None or val is False:
            continue
        key = key.rstrip("_").replace("_", "-")
        parts.append(key if val is True else f'{key}="{esc(val)}"')
    if name in VOID_ELEMENTS:
        return Html(f"<{' '.join(parts)}>")
    return Html(f"<{' '.join(parts)}>{esc(body)}</{name}>")


def join(items: Iterable[Any], sep: str = "\n") -> Html:
    """Concatenate fragments (text items are escaped)."""
    return Html(sep.join(esc(i) for i in items))


def p(text: Any, class_: str | None = None) -> Html:
    return tag("p", text, class_=class_)


def ul(items: Iterable[Any], class_: str | None = None) -> Html:
    return tag("ul", join(tag("li", i) for i in items), class_=class_)


def table(headers: Sequence[Any], rows: Iterable[Sequence[Any]], *, class_: str = "data",
          caption: Any = None, numeric_from: int = 1, text_cols: Iterable[int] = ()) -> Html:
    """A table in its own sideways-scrolling box (:func:`scroll_box`); cells from column ``numeric_from`` on
    (except ``text_cols``) are right-aligned (class ``num``)."""
    text = set(text_cols)
    head = tag("tr", join(tag("th", h) for h in headers))
    body = join(
        tag("tr", join(tag("td", c, class_="num" if j >= numeric_from and j not in text else None)
                       for j, c in enumerate(r)))
        for r in rows
    )
    cap = tag("caption", caption) if caption is not None else Html("")
    return scroll_box(tag("table", Html(cap + tag("thead", head) + tag("tbody", body)), class_=class_))


def scroll_box(body: Any) -> Html:
    """``body`` (a wide table) in a box that scrolls sideways by itself, so the page never does."""
    return tag("div", body, class_="scroll")


def section(anchor: str, title: Any, body: Any) -> Html:
    return tag("section", Html(tag("h2", title) + "\n" + esc(body)), id=anchor)


def png_uri(fig: Any, dpi: int = 96) -> str:
    """A matplotlib :class:`~matplotlib.figure.Figure` as a ``data:image/png;base64`` URI (rendered by Agg)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)  # the figures call tight_layout: no second "tight" pass
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def figure_img(fig: Any, alt: str, caption: Any = None, dpi: int = 96) -> Html:
    """A matplotlib :class:`~matplotlib.figure.Figure` as an embedded PNG (rendered by Agg)."""
    img = Html(f'<img src="{png_uri(fig, dpi)}" alt="{esc(alt)}">')
    cap = tag("figcaption", caption) if caption is not None else Html("")
    return tag("figure", Html(img + cap))


#: Widest viewport (CSS px) that gets a figure's narrow layout (:func:`figure_picture`).
NARROW_MAX_PX = 640


def figure_picture(wide: Any, narrow: Any, alt: str, caption: Any = None, dpi: int = 96) -> Html:
    """Two layouts of one figure as a ``<picture>``: ``narrow`` on viewports up to :data:`NARROW_MAX_PX`
    (a phone), ``wide`` otherwise; one ``<img>`` element either way."""
    source = Html(f'<source media="(max-width: {NARROW_MAX_PX}px)" srcset="{png_uri(narrow, dpi)}">')
    img = Html(f'<img src="{png_uri(wide, dpi)}" alt="{esc(alt)}">')
    cap = tag("figcaption", caption) if caption is not None else Html("")
    return tag("figure", Html(tag("picture", Html(source + img)) + cap))


def fmt(x: Any, digits: int = 4, unit: str = "") -> str:
    """A number with ``digits`` significant digits (``n/a`` for None/NaN), plus a unit."""
    if x is None:
        return "n/a"
    try:
        v = float(x)
    except (TypeError, ValueError):
        return str(x)
    if not math.isfinite(v):
        return "n/a"
    text = f"{v:.{digits}g}"
    return f"{text} {unit}".rstrip() if unit else text


def fmt_pm(x: Any, std: Any, digits: int = 4, unit: str = "") -> str:
    """``x ± std unit`` (just ``x unit`` when std is missing)."""
    s = fmt(std, 2)
    base = fmt(x, digits)
    if s == "n/a" or base == "n/a":
        return f"{base} {unit}".rstrip()
    return f"{base} ± {s} {unit}".rstrip()


def fmt_unc(x: Any, std: Any, unit: str = "") -> str:
    """``x ± std unit`` with ``x`` rounded to the two significant digits of ``std`` (``-7 ± 15 ms``, not
    ``-7.376 ± 15``); ``x unit (fixed)`` when ``std`` is 0 (a value that was set, not estimated); ``x`` with
    3 significant digits when ``std`` is missing; ``n/a`` when ``x`` is."""
    if fmt(x) == "n/a":
        return "n/a"
    v = float(x)
    if fmt(std) == "n/a":
        return fmt(v, 3, unit)
    s = abs(float(std))
    if s == 0.0:
        return f"{fmt(v, 4, unit)} (fixed)"
    decimals = max(0, 1 - math.floor(math.log10(s)))
    return f"{v:.{decimals}f} ± {s:.{decimals}f} {unit}".rstrip()


def code_words(code: str) -> str:
    """A machine code in words: ``bias_not_covered:recovered`` -> ``bias not covered (recovered)``."""
    head, _, tail = str(code).partition(":")
    words = head.replace("_", " ")
    return f"{words} ({tail.replace('_', ' ')})" if tail else words


def code_and_words(code: str) -> Html:
    """A code in words, the code itself kept beside them (small, for search)."""
    return Html(esc(code_words(code)) + " " + tag("code", code, class_="rule"))


def back_link(href: str | None) -> Html:
    """The link back to the dataset page (``href`` relative to the report), or nothing when ``href`` is None."""
    if href is None:
        return Html("")
    return tag("nav", tag("a", "← Dataset page: every sequence at a glance", href=href), class_="back")


CSS = """
body{font-family:-apple-system,"Segoe UI",Roboto,"DejaVu Sans",Arial,sans-serif;margin:0 auto;max-width:1100px;
padding:1.2em 2em 4em;color:#1d232b;line-height:1.45;background:#fff}
p,li,figcaption,summary{overflow-wrap:break-word}
.scroll{overflow-x:auto;max-width:100%}
@media (max-width:640px){body{padding:.8em .8em 3em}h1{font-size:1.35em}h2{font-size:1.15em}}
h1{font-size:1.7em;margin:.2em 0 .1em}h2{font-size:1.3em;border-bottom:2px solid #d8dee6;padding-bottom:.2em;
margin-top:2.2em}h3{font-size:1.05em;margin:1.4em 0 .4em}
.meta{color:#5b6672;font-size:.9em;margin:0 0 1em}
.verdict{border-radius:8px;padding:1em 1.3em;margin:1em 0 1.5em;border:2px solid}
.verdict .word{font-size:1.6em;font-weight:700;letter-spacing:.04em;margin-right:.5em}
.verdict p{margin:.35em 0}.verdict ul{margin:.3em 0 .2em 1.1em;padding:0}
.v-pass{background:#e9f7ee;border-color:#2f9e5b}.v-pass .word{color:#1e7a43}
.v-warn{background:#fff6e0;border-color:#d99a00}.v-warn .word{color:#9a6b00}
.v-fail{background:#fdecec;border-color:#c9302c}.v-fail .word{color:#a4231f}
.v-none{background:#eef1f5;border-color:#8a96a3}.v-none .word{color:#4b5661}
.missing{background:#eef1f5;border-left:4px solid #8a96a3;padding:.5em .9em;margin:.6em 0}
.implausible{background:#fdecec;border:3px solid #c9302c;border-radius:6px;padding:.4em .9em;margin:.6em 0}
.implausible>p.why{color:#a4231f;margin:.2em 0 .4em}
.warnbox{background:#fff6e0;border-left:4px solid #d99a00;padding:.5em .9em;margin:.6em 0}
table.data{border-collapse:collapse;margin:.6em 0 1em;font-size:.92em}
table.data th,table.data td{border:1px solid #d8dee6;padding:.25em .6em;vertical-align:top}
table.data th{background:#f3f6f9;text-align:left}td.num{text-align:right;font-variant-numeric:tabular-nums}
table.data caption{caption-side:top;text-align:left;color:#5b6672;font-size:.92em;padding-bottom:.2em}
.sev-fatal{color:#a4231f;font-weight:700}.sev-warning{color:#9a6b00;font-weight:600}
.sev-repairable{color:#7a4fb3;font-weight:600}.sev-info{color:#4b5661}
figure{margin:.8em 0 1.4em}figure img{max-width:100%;height:auto;border:1px solid #e3e8ee}
figcaption{color:#5b6672;font-size:.9em;margin-top:.3em}
nav.toc{font-size:.92em;background:#f7f9fb;border:1px solid #e3e8ee;padding:.5em 1em;border-radius:6px}
nav.toc ol{margin:.2em 0;padding-left:1.4em}
nav.back{font-size:.92em;margin:0 0 .6em}
.small{font-size:.88em;color:#5b6672}code{background:#f3f6f9;padding:0 .25em;border-radius:3px}
"""

#: Counts the images that failed to decode once the page has loaded (read by the Chromium test).
IMAGE_CHECK_SCRIPT = """
(function () {
  function check() {
    var imgs = document.images, broken = 0;
    for (var i = 0; i < imgs.length; i++) {
      if (!imgs[i].complete || imgs[i].naturalWidth === 0) { broken++; }
    }
    document.body.dataset.brokenImages = String(broken);
    document.body.dataset.images = String(imgs.length);
  }
  if (document.readyState === "complete") { check(); } else { window.addEventListener("load", check); }
})();
"""


def page(title: str, body: Any) -> str:
    """A complete HTML5 document with the inline stylesheet and the image-check script."""
    return (
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
        "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n"
        f"<title>{esc(title)}</title>\n<style>{CSS}</style>\n</head>\n"
        f"<body data-broken-images=\"unchecked\">\n{esc(body)}\n"
        f"<script>{IMAGE_CHECK_SCRIPT}</script>\n</body>\n</html>\n"
    )
