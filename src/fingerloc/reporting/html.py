"""Plain HTML pages for the report folders: no JavaScript, no network, figures as PNG files beside the page.

:class:`Page` collects headings, paragraphs, tables, figures and cards and
writes ``index.html``; :func:`markdown_to_html` turns the small Markdown subset
the demo's report writes (headings, paragraphs, lists, tables, images, bold,
code, links) into the same kind of page, so that a browser opens every report
the same way.
"""

from __future__ import annotations

import html
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import InvalidParameterError

__all__ = [
    "Page",
    "check_report_dir",
    "ellipsize_middle",
    "esc",
    "markdown_to_html",
    "table_html",
    "write_markdown_page",
]

#: The page's style sheet (inline: the folder holds only the page and its figures).
CSS = """
body { font-family: system-ui, -apple-system, "Segoe UI", sans-serif; max-width: 1200px; margin: 1.5em auto;
       padding: 0 1em; color: #222; line-height: 1.45; }
h1 { font-size: 1.6em; border-bottom: 1px solid #ccc; padding-bottom: .2em; }
h2 { font-size: 1.3em; margin-top: 1.6em; border-bottom: 1px solid #eee; }
h3 { font-size: 1.1em; }
table { border-collapse: collapse; margin: .6em 0; font-size: .92em; }
th, td { border: 1px solid #ddd; padding: .2em .5em; vertical-align: top; overflow-wrap: anywhere; }
th { background: #f4f4f4; text-align: left; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
code, .fp { font-family: ui-monospace, "DejaVu Sans Mono", monospace; font-size: .92em; overflow-wrap: anywhere; }
figure { margin: 1em 0; }
pre { overflow-x: auto; margin: .2em 0 .8em; }
img { max-width: 100%; height: auto; }
figure img { border: 1px solid #eee; }
summary { cursor: pointer; font-weight: bold; margin: .5em 0; }
figcaption { color: #555; font-size: .92em; max-width: 60em; }
.cards { display: flex; flex-wrap: wrap; gap: .6em; }
.card { border: 1px solid #ddd; border-radius: 4px; padding: .4em; width: 150px; font-size: .8em; }
.card img { display: block; margin: 0 auto; }
.card .name { font-weight: bold; overflow-wrap: anywhere; }
.row { display: flex; flex-wrap: wrap; gap: 1em; align-items: flex-start; }
.view { width: 190px; font-size: .85em; }
.note { color: #555; font-size: .9em; }
.right { color: #1a7f1a; } .wrong { color: #b00020; }
"""


def esc(text: object) -> str:
    """HTML-escaped ``str(text)`` (quotes too, so it fits in attributes)."""
    return html.escape(str(text), quote=True)


def ellipsize_middle(text: str, width: int) -> str:
    """``text`` cut to ``width`` characters with an ellipsis in the middle (both ends stay readable).

    For figures' tick labels and terminal columns; pages and JSON carry the full name.
    """
    if width < 3:
        raise InvalidParameterError(f"width must be >= 3, got {width}")
    if len(text) <= width:
        return text
    k = (width - 1) // 2
    return text[:k] + "…" + text[len(text) - (width - 1 - k) :]


def check_report_dir(path: str | Path, *, flag: str = "--report") -> Path:
    """Check that a report folder can be written, before anything else is written.

    Parameters
    ----------
    path : str or Path
        The folder; it may exist (its report files are overwritten) or not (it is created, with its parents).
    flag : str
        How the user named it, for the message.

    Raises
    ------
    InvalidParameterError
        When ``path`` is an existing file, or a path component above it is a file.
    """
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise InvalidParameterError(f"{flag}: {p} exists and is not a folder")
    for parent in p.parents:
        if parent.exists():
            if not parent.is_dir():
                raise InvalidParameterError(f"{flag}: {parent} is not a folder, cannot create {p} in it")
            break
    return p


def table_html(
    header: Sequence[str],
    rows: Iterable[Sequence[object]],
    *,
    numeric: Sequence[bool] | None = None,
    raw_columns: Sequence[int] = (),
) -> str:
    """An HTML table; cells are escaped except the columns in ``raw_columns``; ``numeric`` right-aligns columns."""
    num = list(numeric) if numeric is not None else [False] * len(header)
    out = ["<table><thead><tr>", *(f"<th>{esc(h)}</th>" for h in header), "</tr></thead><tbody>"]
    for row in rows:
        out.append("<tr>")
        for j, cell in enumerate(row):
            cls = ' class="num"' if j < len(num) and num[j] else ""
            out.append(f"<td{cls}>{cell if j in raw_columns else esc(cell)}</td>")
        out.append("</tr>")
    out.append("</tbody></table>")
    return "".join(out)


@dataclass
class Page:
    """An HTML page assembled from parts, written as ``index.html`` with :meth:`write`.

    Parameters
    ----------
    title : str
        The page's title and first heading.
    title_html : str, optional
        The first heading as HTML (already escaped), when it differs from ``title``.
    """

    title: str
    title_html: str | None = None
    parts: list[str] = field(default_factory=list)

    def heading(self, text: str, level: int = 2) -> None:
        """A heading ``<h{level}>``; text is escaped."""
        self.parts.append(f"<h{level}>{esc(text)}</h{level}>")

    def paragraph(self, text: str, *, raw: bool = False, cls: str | None = None) -> None:
        """A paragraph; ``raw=True`` keeps ``text`` as HTML (the caller escaped it)."""
        body = text if raw else esc(text)
        c = f' class="{cls}"' if cls else ""
        self.parts.append(f"<p{c}>{body}</p>")

    def items(self, lines: Iterable[str], *, raw: bool = False) -> None:
        """A bulleted list."""
        body = "".join(f"<li>{line if raw else esc(line)}</li>" for line in lines)
        self.parts.append(f"<ul>{body}</ul>")

    def table(
        self,
        header: Sequence[str],
        rows: Iterable[Sequence[object]],
        *,
        numeric: Sequence[bool] | None = None,
        raw_columns: Sequence[int] = (),
    ) -> None:
        """A table; cells are escaped except the columns in ``raw_columns``; ``numeric`` right-aligns columns."""
        self.parts.append(table_html(header, rows, numeric=numeric, raw_columns=raw_columns))

    def details(self, summary: str, markup: str, *, open_: bool = False) -> None:
        """A folded section (``<details>``: opens on a click, no script needed) holding ``markup``."""
        self.parts.append(f"<details{' open' if open_ else ''}><summary>{esc(summary)}</summary>{markup}</details>")

    def figure(self, src: str, alt: str, caption: str | None = None, *, width: int | None = None) -> None:
        """A figure: the image ``src`` (a file name beside the page), its alt text and an optional caption."""
        w = f' width="{int(width)}"' if width else ""
        cap = f"<figcaption>{esc(caption)}</figcaption>" if caption else ""
        self.parts.append(f'<figure><img src="{esc(src)}" alt="{esc(alt)}"{w}>{cap}</figure>')

    def raw(self, markup: str) -> None:
        """Markup the caller built (and escaped) itself."""
        self.parts.append(markup)

    def render(self) -> str:
        """The whole document."""
        body = "\n".join(self.parts)
        return (
            '<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
            '<meta name="viewport" content="width=device-width, initial-scale=1">\n'
            f"<title>{esc(self.title)}</title>\n<style>{CSS}</style>\n</head>\n<body>\n"
            f"<h1>{self.title_html or esc(self.title)}</h1>\n{body}\n</body>\n</html>\n"
        )

    def write(self, out_dir: str | Path) -> Path:
        """Write ``out_dir / "index.html"`` (the folder is created); return its path."""
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        path = out / "index.html"
        path.write_text(self.render(), encoding="utf-8")
        return path


# ----------------------------------------------------------------------------- Markdown subset

_IMG = re.compile(r"!\[([^\]]*)\]\(([^)\s]+)\)")
_LINK = re.compile(r"\[([^\]]+)\]\(([^)\s]+)\)")
_BOLD = re.compile(r"\*\*(.+?)\*\*")
_CODE = re.compile(r"`([^`]+)`")


def _inline(text: str) -> str:
    """Inline Markdown (code, images, links, bold) to HTML; everything else escaped."""
    out: list[str] = []
    pos = 0
    for m in _CODE.finditer(text):  # code spans first: nothing inside them is markup
        out.append(_inline_plain(text[pos : m.start()]))
        out.append(f"<code>{esc(m.group(1))}</code>")
        pos = m.end()
    out.append(_inline_plain(text[pos:]))
    return "".join(out)


def _inline_plain(text: str) -> str:
    s = esc(text)
    s = _IMG.sub(lambda m: f'<img src="{m.group(2)}" alt="{m.group(1)}">', s)
    s = _LINK.sub(lambda m: f'<a href="{m.group(2)}">{m.group(1)}</a>', s)
    return _BOLD.sub(r"<strong>\1</strong>", s)


def _cells(line: str) -> list[str]:
    s = line.strip()
    if s.startswith("|"):
        s = s[1:]
    if s.endswith("|"):
        s = s[:-1]
    return [c.strip() for c in s.split("|")]


def _is_rule(line: str) -> bool:
    return bool(re.fullmatch(r"\s*\|?\s*:?-{3,}:?\s*(\|\s*:?-{3,}:?\s*)*\|?\s*", line))


def markdown_to_html(markdown: str) -> str:
    """The body HTML of a Markdown text (the subset the reports write).

    Handles ATX headings (``#``..``####``), paragraphs, ``-`` and ``1.``
    lists, pipe tables with a rule line (``---:`` right-aligns), images,
    links, ``**bold**`` and ``code`` spans. Everything else is escaped text.

    Parameters
    ----------
    markdown : str

    Returns
    -------
    str
        HTML, without ``<html>``/``<body>``.
    """
    lines = markdown.splitlines()
    out: list[str] = []
    para: list[str] = []
    i = 0

    def flush() -> None:
        if para:
            out.append(f"<p>{_inline(' '.join(para))}</p>")
            para.clear()

    while i < len(lines):
        line = lines[i]
        stripped = line.strip()
        m = re.match(r"(#{1,4})\s+(.*)", stripped)
        if not stripped:
            flush()
            i += 1
        elif m:
            flush()
            n = len(m.group(1))
            out.append(f"<h{n}>{_inline(m.group(2))}</h{n}>")
            i += 1
        elif stripped.startswith("|") and i + 1 < len(lines) and _is_rule(lines[i + 1]):
            flush()
            head = _cells(stripped)
            right = [c.endswith(":") for c in _cells(lines[i + 1])]
            rows = []
            i += 2
            while i < len(lines) and lines[i].strip().startswith("|"):
                rows.append(_cells(lines[i]))
                i += 1
            t = ["<table><thead><tr>", *(f"<th>{_inline(h)}</th>" for h in head), "</tr></thead><tbody>"]
            for r in rows:
                t.append("<tr>")
                for j, c in enumerate(r):
                    cls = ' class="num"' if j < len(right) and right[j] else ""
                    t.append(f"<td{cls}>{_inline(c)}</td>")
                t.append("</tr>")
            t.append("</tbody></table>")
            out.append("".join(t))
        elif re.match(r"(-|\*|\d+\.)\s+", stripped):
            flush()
            ordered = bool(re.match(r"\d+\.", stripped))
            tag = "ol" if ordered else "ul"
            items = []
            while i < len(lines) and re.match(r"\s*(-|\*|\d+\.)\s+", lines[i]):
                items.append(re.sub(r"^\s*(-|\*|\d+\.)\s+", "", lines[i]))
                i += 1
                while i < len(lines) and lines[i].startswith("   ") and lines[i].strip():  # continuation lines
                    items[-1] += " " + lines[i].strip()
                    i += 1
            out.append(f"<{tag}>" + "".join(f"<li>{_inline(x)}</li>" for x in items) + f"</{tag}>")
        else:
            para.append(stripped)
            i += 1
    flush()
    return "\n".join(out)


def write_markdown_page(path: str | Path, markdown: str, *, title: str) -> Path:
    """Write a Markdown text as a plain HTML page (images stay files beside it); return the path.

    The first ``# heading`` of the text is the page's heading (``title`` is
    the window title and the heading when the text has none).
    """
    body = markdown_to_html(markdown)
    page = Page(title)
    if body.startswith("<h1>"):
        end = body.index("</h1>")
        page.title_html = body[len("<h1>") : end]
        body = body[end + len("</h1>") :].lstrip("\n")
    page.raw(body)
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(page.render(), encoding="utf-8")
    return p
