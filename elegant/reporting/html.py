"""Every report as Markdown and as one self-standing HTML page beside it (tables, plots and videos by relative
link: open the file, no server needed).

`write_report(path, markdown)` writes `path` (report.md, comparison.md, ...) and `path` with the suffix
.html, each whole (`atomic_write`). The page renders the Markdown with markdown-it (CommonMark and tables);
images stay <img> tags, and links to MP4 clips become <video> players with the link beneath.
"""

from __future__ import annotations

import html
import os
import re
from pathlib import Path

from base_suites.runtime.io import atomic_write

_STYLE = """
body { font-family: system-ui, sans-serif; max-width: 1200px; margin: 2em auto; padding: 0 1em; color: #222; }
table { border-collapse: collapse; margin: 1em 0; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.3em 0.6em; text-align: left; }
th { background: #f3f3f3; }
img { max-width: 100%; }
video { display: block; max-width: 100%; margin: 0.5em 0 0.2em; }
code { background: #f6f6f6; padding: 0 0.2em; }
"""
_VIDEO_LINK = re.compile(r'<a href="([^"]+\.mp4)">([^<]*)</a>')


def markdown_page(markdown: str, title: str) -> str:
    """The HTML page of a report written in Markdown."""
    from markdown_it import MarkdownIt

    body = MarkdownIt("commonmark").enable("table").render(markdown)
    body = _VIDEO_LINK.sub(r'<video controls muted preload="metadata" src="\1"></video><a href="\1">\2</a>', body)
    return (
        '<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        f"<title>{html.escape(title)}</title>\n<style>{_STYLE}</style>\n</head>\n<body>\n{body}</body>\n</html>\n"
    )


def write_report(path: str | os.PathLike, markdown: str) -> Path:
    """Write the Markdown report at `path` and its HTML page beside it; returns the page's path."""
    path = Path(path)
    atomic_write(path, markdown)
    first = next((line.lstrip("# ").strip() for line in markdown.splitlines() if line.startswith("#")), path.stem)
    page = path.with_suffix(".html")
    atomic_write(page, markdown_page(markdown, first))
    return page
