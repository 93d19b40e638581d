"""``packlab cell``: serve packlab to a robot cell over HTTP (depth images in, a placement out),
or write the service's OpenAPI document. Needs the ``cell`` extra (FastAPI, uvicorn, httpx)."""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import sys
from pathlib import Path
from types import ModuleType

from packlab.cell.settings import ServeSettings
from packlab.cli.options import add_field, config_kwargs
from packlab.core.errors import ConfigError

#: What the commands do (the web app, uvicorn), imported when one runs.
RUN_MODULE = "packlab.cell.server"
#: The cell extra's packages; without them the command says how to install them.
EXTRA_MODULES = ("fastapi", "uvicorn", "httpx")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Serve packlab to a robot cell: the cell sends its depth images (or its own box "
        "detections), the service answers which box, its rotation, the place pose in the "
        "container frame and the place skill's approach (docs/cell.md)."
    )
    sub = p.add_subparsers(dest="cell_command", required=True, metavar="{serve,schema}")
    s = sub.add_parser(
        "serve",
        help="serve the HTTP API (sessions, steps, a stateless plan)",
        description="Serve the cell API at http://HOST:PORT/v1 (interactive docs at /docs) "
        "until stopped with Ctrl-C. A session a cell opens keeps its own policy and history "
        "in memory; the server keeps --max-sessions at most and closes one that idles longer "
        "than --idle-timeout.",
    )
    add_field(
        s,
        ServeSettings,
        "policy",
        "--policy",
        help="the policy of sessions that name none (packlab policies lists them); "
        "default {default}",
    )
    add_field(s, ServeSettings, "host", "--host", help="address to listen on; default {default}")
    add_field(s, ServeSettings, "port", "--port", help="port to listen on; default {default}")
    add_field(
        s,
        ServeSettings,
        "workers",
        "--workers",
        help="planner processes: 1 plans in the server process; N starts N processes and "
        "spreads the sessions over them (one per core); default {default}",
    )
    add_field(
        s,
        ServeSettings,
        "max_sessions",
        "--max-sessions",
        help="sessions kept open at once (more are answered 503); default {default}",
    )
    add_field(
        s,
        ServeSettings,
        "idle_s",
        "--idle-timeout",
        metavar="SECONDS",
        help="close a session idle this long; default {default}",
    )
    s.set_defaults(func=run_serve)
    o = sub.add_parser(
        "schema",
        help="write the API's OpenAPI document",
        description="Write the OpenAPI document of the cell API (what GET /openapi.json serves): "
        "every request and answer with its fields, units and limits.",
    )
    o.add_argument("--out", metavar="FILE", help="file to write; default: print it")
    o.set_defaults(func=run_schema)


def _server() -> ModuleType:
    """The server module, once the cell extra is there."""
    missing = [m for m in EXTRA_MODULES if importlib.util.find_spec(m) is None]
    if missing:
        raise ConfigError(
            f"packlab cell needs the cell extra ({', '.join(missing)} not installed): "
            'pip install -e ".[cell]"'
        )
    return importlib.import_module(RUN_MODULE)


def run_serve(args: argparse.Namespace) -> int:
    """``packlab cell serve``."""
    settings = ServeSettings(**config_kwargs(args, "cell serve", ServeSettings))
    _server().serve(settings)
    return 0


def run_schema(args: argparse.Namespace) -> int:
    """``packlab cell schema``."""
    out = None if args.out is None else Path(args.out)
    text = _server().write_openapi(out)
    if out is None:
        sys.stdout.write(text)
    else:
        print(f"wrote {out}")
    return 0
