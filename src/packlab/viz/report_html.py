"""The interactive bench report as one self-contained HTML file (plotly.js inlined, no network).

The page is a fixed template (``assets/report.html``), a stylesheet and a script (``assets/``),
plotly.js from the installed ``plotly`` package (a core dependency) inlined once, and the
report's data (``packlab.viz.report_data``) embedded once as JSON; the script builds every
table, plot and 3D replay in the browser from that data. The output is a function of the data,
packlab's and plotly's versions alone, except for the one ``packlab-generated`` line carrying
the timestamp, so the same records give the same bytes.
"""

from __future__ import annotations

import json
import re
from importlib import resources
from importlib.metadata import PackageNotFoundError, version
from typing import Any

from packlab.core.errors import PacklabError

#: The line of the page that carries the build time (the only line that differs between builds).
GENERATED_META = "packlab-generated"
_SLOT = re.compile(r"\{\{(\w+)\}\}")
_PLOTLY_VERSION = re.compile(r"plotly\.js v(\d[\w.\-]*)")


class ReportUnavailable(PacklabError):
    """plotly, a core dependency the HTML report inlines, is missing (a broken install)."""


def plotly_js() -> str:
    """plotly.js as shipped in the installed plotly package (its minified bundle)."""
    try:
        # Imported when a page is built: plotly.js is about 4 MB.
        from plotly.offline import get_plotlyjs
    except ImportError:
        raise ReportUnavailable(
            "the HTML report needs plotly, a core dependency that is missing here: "
            "pip install plotly"
        ) from None
    return get_plotlyjs()


def _asset(name: str) -> str:
    return resources.files("packlab.viz").joinpath("assets", name).read_text(encoding="utf-8")


def _packlab_version() -> str:
    try:
        return version("packlab")
    except PackageNotFoundError:  # running from a source tree that is not installed
        return "unknown"


def embed_json(data: Any) -> str:
    """JSON for a ``<script type="application/json">``: compact, ASCII, ``<`` escaped so no
    string in it can close the script element."""
    text = json.dumps(data, separators=(",", ":"), ensure_ascii=True, allow_nan=False)
    return text.replace("<", "\\u003c")


def render_report_html(data: dict[str, Any], generated: str, plotly: str | None = None) -> str:
    """The page for ``data`` (``report_data``'s dict); ``generated`` is the timestamp shown.

    ``plotly`` is plotly.js's source (default: the installed package's; ReportUnavailable when
    plotly is not installed).
    """
    js = plotly_js() if plotly is None else plotly
    found = _PLOTLY_VERSION.search(js[:2000])
    if "\n" in generated:
        raise ValueError("generated must be one line")
    slots = {
        "version": _packlab_version(),
        "plotly_version": found.group(1) if found else "unknown",
        "generated": _html_attr(generated),
        "title": _html_text(str(data.get("title", "packlab report"))),
        "css": _asset("report.css"),
        "plotly": js,
        "data": embed_json(data),
        "script": _asset("report.js"),
    }
    # One pass over the template only: text put into a slot is never scanned again.
    return _SLOT.sub(lambda m: slots[m.group(1)], _asset("report.html"))


def _html_text(text: str) -> str:
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def _html_attr(text: str) -> str:
    return _html_text(text).replace('"', "&quot;")


def embedded_data(html: str) -> dict[str, Any]:
    """The data a page embeds (tests and tools read a report back with this)."""
    start = html.index('<script type="application/json" id="packlab-data">')
    start = html.index(">", start) + 1
    end = html.index("</script>", start)
    return json.loads(html[start:end])


__all__ = [
    "GENERATED_META",
    "ReportUnavailable",
    "embed_json",
    "embedded_data",
    "plotly_js",
    "render_report_html",
]
