"""One self-contained HTML page per run: sections of text, tables and figures, PNGs embedded as base64, so the
page can be mailed or opened from anywhere with nothing beside it.

    page = [Section("Gap", [Text("Gap before: **0.42**"), Table(["family", "before"], [["speckle", "0.3"]]),
                            Figure("diag_families.png", "gap per statistic family")])]
    write_html("report.html", "Sim-to-real gap diagnosis", page, subtitle="sim: out/sim, real: data/real")

Text is plain text with `**bold**` and `` `code` `` marks (everything else is escaped); the page has its own
CSS and no scripts.
"""

from __future__ import annotations

import base64
import html
import os
import re
import shutil
import subprocess
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path


@dataclass(frozen=True)
class Text:
    text: str


@dataclass(frozen=True)
class Table:
    header: Sequence[str]
    rows: Sequence[Sequence[object]]
    caption: str = ""


@dataclass(frozen=True)
class Figure:
    """A PNG file (embedded when the page is written) with a caption under it."""

    path: str | Path
    caption: str = ""
    width_percent: int = 100


@dataclass(frozen=True)
class Row:
    """Figures side by side (e.g. simulated input, samples, a real frame)."""

    figures: Sequence[Figure]


@dataclass(frozen=True)
class Section:
    title: str
    items: Sequence[Text | Table | Figure | Row] = field(default_factory=list)


_CSS = """
body { font-family: system-ui, -apple-system, "Segoe UI", sans-serif; margin: 2em auto; max-width: 1200px;
       padding: 0 1em; color: #222; line-height: 1.45; }
h1 { margin-bottom: 0.1em; } .subtitle { color: #666; margin-top: 0; }
h2 { border-bottom: 1px solid #ddd; padding-bottom: 0.2em; margin-top: 1.6em; }
table { border-collapse: collapse; margin: 0.8em 0; font-size: 0.92em; }
th, td { border: 1px solid #ccc; padding: 0.3em 0.6em; text-align: left; vertical-align: top; }
th { background: #f3f3f3; } tr:nth-child(even) td { background: #fafafa; }
figure { margin: 0.8em 0; } figure img { max-width: 100%; height: auto; border: 1px solid #eee; }
figcaption { color: #555; font-size: 0.9em; } caption { caption-side: bottom; color: #555; font-size: 0.9em; }
.row { display: flex; gap: 1em; align-items: flex-start; flex-wrap: wrap; }
.row figure { flex: 1 1 0; min-width: 240px; }
code { background: #f3f3f3; padding: 0 0.2em; }
footer { color: #888; font-size: 0.85em; margin-top: 2em; }
"""


def write_html(path: str | Path, title: str, sections: Sequence[Section], subtitle: str = "") -> Path:
    """Write the page to `path` (figures read now and embedded); returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    parts = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
             '<meta name="viewport" content="width=device-width, initial-scale=1">',
             f"<title>{html.escape(title)}</title><style>{_CSS}</style></head><body>",
             f"<h1>{html.escape(title)}</h1>"]
    if subtitle:
        parts.append(f'<p class="subtitle">{_inline(subtitle)}</p>')
    for section in sections:
        parts.append(f"<section><h2>{html.escape(section.title)}</h2>")
        parts.extend(_item(item) for item in section.items)
        parts.append("</section>")
    stamp = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    parts.append(f"<footer>Written by sonar-realism, {stamp}.</footer></body></html>")
    path.write_text("\n".join(parts), encoding="utf-8")
    return path


def to_markdown(title: str, sections: Sequence[Section], subtitle: str = "") -> str:
    """The same page as Markdown (figures linked by file name, so report.md sits beside its PNGs)."""
    lines = [f"# {title}", ""] + ([subtitle, ""] if subtitle else [])
    for section in sections:
        lines += [f"## {section.title}", ""]
        for item in section.items:
            lines += _markdown_item(item) + [""]
    return "\n".join(lines)


def _markdown_item(item: Text | Table | Figure | Row) -> list[str]:
    if isinstance(item, Text):
        return [item.text]
    if isinstance(item, Table):
        def cell(value: object) -> str:
            return str(value).replace("\n", "<br>").replace("|", "\\|")
        lines = ["| " + " | ".join(cell(c) for c in item.header) + " |", "|---" * len(item.header) + "|"]
        lines += ["| " + " | ".join(cell(c) for c in row) + " |" for row in item.rows]
        return lines + ([f"*{item.caption}*"] if item.caption else [])
    if isinstance(item, Row):
        return [" ".join(f"![{figure.caption}]({Path(figure.path).name})" for figure in item.figures)]
    return [f"![{item.caption}]({Path(item.path).name})"]


def _item(item: Text | Table | Figure | Row) -> str:
    if isinstance(item, Text):
        return "".join(f"<p>{_inline(paragraph)}</p>" for paragraph in item.text.split("\n\n") if paragraph.strip())
    if isinstance(item, Table):
        head = "".join(f"<th>{_inline(str(cell))}</th>" for cell in item.header)
        body = "".join("<tr>" + "".join(f"<td>{_inline(str(cell))}</td>" for cell in row) + "</tr>"
                       for row in item.rows)
        caption = f"<caption>{_inline(item.caption)}</caption>" if item.caption else ""
        return f"<table>{caption}<thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"
    if isinstance(item, Row):
        return '<div class="row">' + "".join(_item(figure) for figure in item.figures) + "</div>"
    data = base64.b64encode(Path(item.path).read_bytes()).decode("ascii")
    caption = f"<figcaption>{_inline(item.caption)}</figcaption>" if item.caption else ""
    alt = html.escape(item.caption or Path(item.path).name)
    return (f'<figure><img style="width:{item.width_percent}%" alt="{alt}" src="data:image/png;base64,{data}">'
            f"{caption}</figure>")


BROWSER_ENV = "SONAR_REALISM_BROWSER"
_BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable", "chrome")


def find_browser() -> str | None:
    """A headless-capable Chromium: $SONAR_REALISM_BROWSER, else the first of the usual names on PATH."""
    return os.environ.get(BROWSER_ENV) or next(filter(None, (shutil.which(name) for name in _BROWSERS)), None)


def screenshot(page: str | Path, out: str | Path, browser: str, size: tuple[int, int] = (1280, 1600),
               timeout_s: float = 120.0) -> Path:
    """A PNG of `page` as headless Chromium draws it (how a reader sees the report)."""
    out = Path(out).resolve()
    out.parent.mkdir(parents=True, exist_ok=True)
    command = [browser, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
               f"--window-size={size[0]},{size[1]}", f"--screenshot={out}", Path(page).resolve().as_uri()]
    subprocess.run(command, check=True, capture_output=True, timeout=timeout_s)
    return out


def _inline(text: str) -> str:
    escaped = html.escape(text)
    escaped = re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", escaped)
    escaped = re.sub(r"`(.+?)`", r"<code>\1</code>", escaped)
    return escaped.replace("\n", "<br>")
