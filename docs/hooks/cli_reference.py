"""mkdocs hook: fill the command-line reference page from packlab's parsers at build time."""

from __future__ import annotations

MARKER = "<!-- cli-reference -->"


def on_page_markdown(markdown: str, page, config, files) -> str:
    if MARKER not in markdown:
        return markdown
    from packlab.cli.reference import cli_reference_markdown

    return markdown.replace(MARKER, cli_reference_markdown())
