"""The gap report as one self-contained page: ``report.md`` and its PNG figures (as
:func:`apmcal.diagnosis.output.report.write_report` leaves them in the report folder) turned into
``index.html``, the figures embedded as base64 PNG, nothing loaded from the network.

The Markdown is the report's own small subset — headings, paragraphs, ``-`` lists (an indented
line continues an item), pipe tables, ``**bold**``, ``*emphasis*``, ``code`` and
``![caption](file.png)`` figures — converted here (about sixty lines) rather than with a
Markdown library, which would be a new runtime dependency for one page.
"""
from __future__ import annotations

import base64
import html
import re
from pathlib import Path

STYLE = """body{font-family:sans-serif;max-width:60em;margin:1em auto;padding:0 1em;color:#222}
h1{font-size:1.4em}h2{font-size:1.15em;margin-top:1.6em}h3{font-size:1em}
table{border-collapse:collapse;font-size:.9em}td,th{border:1px solid #d0d7de;padding:.2em .5em}
img{max-width:100%}figure{margin:1em 0}figcaption{font-size:.9em;color:#57606a}
code{background:#f6f8fa}"""
_IMAGE = re.compile(r"^!\[([^\]]*)\]\(([^)\s]+)\)\s*$")


def _inline(text: str) -> str:
    """HTML-escaped ``text`` with **bold**, *emphasis* and `code` marked up (code first: an
    asterisk inside code stays one)."""
    parts = re.split(r"(`[^`]+`)", text)
    out = []
    for part in parts:
        if part.startswith("`") and part.endswith("`") and len(part) > 1:
            out.append(f"<code>{html.escape(part[1:-1], quote=False)}</code>")
            continue
        part = html.escape(part, quote=False)
        part = re.sub(r"\*\*(.+?)\*\*", r"<b>\1</b>", part)
        out.append(re.sub(r"(?<![\w*])\*(?!\s)(.+?)(?<!\s)\*(?![\w*])", r"<em>\1</em>", part))
    return "".join(out)


def _image(folder: Path, caption: str, name: str) -> str:
    """A figure of the folder embedded as base64 (a missing file is named, not linked)."""
    path = folder / name
    if not path.is_file() or "/" in name or name.startswith(("http:", "https:")):
        return f"<p>(figure {html.escape(name)} missing)</p>"
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return (f"<figure><img alt='{html.escape(caption)}' src='data:image/png;base64,{data}'>"
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def _table(rows: list[str]) -> str:
    cells = [[c.strip() for c in r.strip().strip("|").split("|")] for r in rows]
    body = [r for r in cells if not all(re.fullmatch(r":?-+:?", c) for c in r)]
    head, rest = body[0], body[1:]
    return ("<table><tr>" + "".join(f"<th>{_inline(c)}</th>" for c in head) + "</tr>"
            + "".join("<tr>" + "".join(f"<td>{_inline(c)}</td>" for c in r) + "</tr>"
                      for r in rest) + "</table>")


def markdown_to_html(text: str, folder: Path) -> str:
    """The report's Markdown subset (see the module doc) as HTML, figures from ``folder``.

    A block (paragraph, table, list) ends where another kind begins or at a blank line, so the
    blocks come out in the order written; an indented line continues the list item above it.
    """
    out, block, kind = [], [], None

    def flush():
        nonlocal kind
        if kind == "p":
            out.append("<p>" + _inline(" ".join(block)) + "</p>")
        elif kind == "table":
            out.append(_table(block))
        elif kind == "ul":
            out.append("<ul>" + "".join(f"<li>{_inline(i)}</li>" for i in block) + "</ul>")
        block.clear()
        kind = None

    def add(to: str, line: str):
        nonlocal kind
        if kind != to:
            flush()
            kind = to
        block.append(line)

    for line in text.splitlines():
        heading = re.match(r"^(#{1,3}) (.*)$", line)
        image = _IMAGE.match(line)
        if heading:
            flush()
            level = len(heading.group(1))
            out.append(f"<h{level}>{_inline(heading.group(2))}</h{level}>")
        elif image:
            flush()
            out.append(_image(folder, image.group(1), image.group(2)))
        elif line.startswith("|"):
            add("table", line)
        elif line.startswith("- "):
            add("ul", line[2:].strip())
        elif not line.strip():
            flush()
        elif kind == "ul" and line.startswith(" "):
            block[-1] += " " + line.strip()         # the list item goes on
        else:
            add("p", line.strip())
    flush()
    return "\n".join(out)


def write_index(directory) -> Path:
    """``directory/index.html`` from ``directory/report.md`` and its figures; its path."""
    folder = Path(directory)
    text = (folder / "report.md").read_text(encoding="utf-8")
    title = next((ln[2:] for ln in text.splitlines() if ln.startswith("# ")), "apmcal gap report")
    page = (f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>"
            f"{html.escape(title)}</title><style>{STYLE}</style></head><body>\n"
            + markdown_to_html(text, folder) + "\n</body></html>\n")
    path = folder / "index.html"
    path.write_text(page, encoding="utf-8")
    return path
