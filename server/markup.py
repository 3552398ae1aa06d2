"""Text from run folders and browsers, made safe to put into the dashboard's Markdown.

viser renders Markdown with raw HTML enabled, so a folder named `<img src=x onerror=...>`,
a status.json `error` or a task name would otherwise run in every browser that shows the
runs table. Everything that did not come from the dashboard's own code goes through
`md_text` (or `md_code`) before it enters Markdown or HTML.
"""

from __future__ import annotations

import html
import re

_MARKDOWN_SPECIAL = re.compile(r"([\\`*_\[\]|~!])")
"""Characters that start Markdown syntax inside a line (emphasis, code, links and images,
table cells, strike-through); `<`, `>` and `&` become HTML entities first."""


def md_text(text: object) -> str:
    """`text` as literal text in a Markdown line: HTML entities for & < >, backslash escapes
    for Markdown syntax, line breaks as spaces (a table cell stays one cell)."""
    escaped = html.escape(str(text), quote=False)
    escaped = _MARKDOWN_SPECIAL.sub(r"\\\1", escaped)
    return re.sub(r"[\r\n]+", " ", escaped)


def md_code(text: object) -> str:
    """`text` in a monospace span (an HTML <code>, since a Markdown code span cannot hold a
    backtick safely and shows escapes literally)."""
    return f"<code>{md_text(text)}</code>"
