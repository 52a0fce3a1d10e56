"""The run report as one self-contained HTML file (plots inlined), the form people share.

It renders the Markdown the report writes itself, a known subset (headings, pipe tables, images,
bullets, quotes, paragraphs, ``**bold**`` and ``code``), so no Markdown library is needed; anything
outside the subset shows as escaped text, never as markup.
"""

from __future__ import annotations

import base64
import html
import re
from collections.abc import Sequence
from pathlib import Path

from lastmile.core.errors import LastmileError

_IMAGE = re.compile(r"^!\[(?P<alt>[^\]]*)\]\((?P<src>[^)]+)\)$")
_STYLE = """
body { font-family: system-ui, sans-serif; max-width: 1200px; margin: 2em auto; padding: 0 1em; color: #222; }
table { border-collapse: collapse; margin: 0.5em 0 1.5em; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; }
td.num, th.num { text-align: right; font-variant-numeric: tabular-nums; }
img { max-width: 100%; }
blockquote { border-left: 4px solid #d62728; margin: 1em 0; padding: 0.2em 1em; background: #fff5f5; }
code { background: #f4f4f4; padding: 0 0.2em; }
"""


def _inline(text: str) -> str:
    out = html.escape(text.replace("\\|", "|"), quote=False)
    out = re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", out)
    return re.sub(r"`([^`]+)`", r"<code>\1</code>", out)


def _cells(row: str) -> list[str]:
    # Split on pipes that the Markdown writer did not escape.
    return [c.strip() for c in re.split(r"(?<!\\)\|", row.strip().strip("|"))]


def _table(rows: Sequence[str]) -> list[str]:
    head, align, body = _cells(rows[0]), _cells(rows[1]), [_cells(r) for r in rows[2:]]
    numeric = [a.endswith(":") for a in align]
    out = [
        "<table>",
        "<tr>" + "".join(_cell("th", c, n) for c, n in zip(head, numeric, strict=False)) + "</tr>",
    ]
    out += [
        "<tr>" + "".join(_cell("td", c, n) for c, n in zip(r, numeric, strict=False)) + "</tr>" for r in body
    ]
    return [*out, "</table>"]


def _cell(tag: str, text: str, numeric: bool) -> str:
    cls = ' class="num"' if numeric else ""
    return f"<{tag}{cls}>{_inline(text)}</{tag}>"


def _image(alt: str, src: str, base: Path) -> str:
    path = base / src
    try:
        data = base64.b64encode(path.read_bytes()).decode("ascii")
    except OSError as exc:
        raise LastmileError(f"report.html: expected the plot {path} to inline, got {exc.strerror}") from None
    return f'<p><img alt="{html.escape(alt)}" src="data:image/png;base64,{data}"></p>'


def render(lines: Sequence[str], base: Path, title: str) -> str:
    """HTML of the report's Markdown ``lines``; images are read from ``base`` and inlined."""
    body: list[str] = []
    i = 0
    while i < len(lines):
        line = lines[i]
        if line.startswith("|"):
            j = i
            while j < len(lines) and lines[j].startswith("|"):
                j += 1
            body += _table(lines[i:j])
            i = j
            continue
        if line.startswith("- "):
            j = i
            while j < len(lines) and lines[j].startswith("- "):
                j += 1
            body += ["<ul>", *(f"<li>{_inline(x[2:])}</li>" for x in lines[i:j]), "</ul>"]
            i = j
            continue
        heading = re.match(r"^(#{1,6}) (.*)$", line)
        image = _IMAGE.match(line)
        if heading:
            level = len(heading.group(1))
            body.append(f"<h{level}>{_inline(heading.group(2))}</h{level}>")
        elif image:
            body.append(_image(image.group("alt"), image.group("src"), base))
        elif line.startswith("> "):
            body.append(f"<blockquote>{_inline(line[2:])}</blockquote>")
        elif line.strip():
            body.append(f"<p>{_inline(line)}</p>")
        i += 1
    return (
        f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>'
        f"<style>{_STYLE}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n"
    )


def write_html(lines: Sequence[str], base: Path, path: Path, title: str) -> Path:
    """Write :func:`render` of ``lines`` to ``path``; returns it."""
    path.write_text(render(lines, base, title), encoding="utf-8")
    return path
