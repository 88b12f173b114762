"""``delegation ui``, and the ``--http`` options ``serve`` and ``demo`` share: the operator page.

The page (docs/ui.md) joins the broker as one more client of the service: it shows the live
units and missions and sends the operator's commands with their own ``sender``. A host other than
loopback needs ``--users`` (or ``--insecure-http``): the page can start and cancel missions.
"""

from __future__ import annotations

import argparse
import threading
from contextlib import ExitStack
from typing import TYPE_CHECKING, Any

from delegation.cli.options import UsageError

if TYPE_CHECKING:
    from delegation.runtime.settings import BrokerSettings
    from delegation.web.server import WebServer

DEFAULT_HTTP = "127.0.0.1:8765"
OSM_TILES = "https://tile.openstreetmap.org/{z}/{x}/{y}.png"


def add_http_args(parser: argparse.ArgumentParser, *, default: str | None) -> None:
    """``--http``, ``--tiles``, ``--tile-attribution``, ``--users``, ``--insecure-http``,
    ``--sender``."""
    g = parser.add_argument_group("operator page (docs/ui.md)")
    g.add_argument("--http", default=default, metavar="HOST:PORT",
                   help="serve the operator page here (port 0: any free port)"
                   + (f"; default {default}" if default else ""))
    g.add_argument("--tiles", default=None, metavar="URL",
                   help=f"map tile URL template, e.g. {OSM_TILES} (default: a plain local grid, "
                   "works offline)")
    g.add_argument("--tile-attribution", default=None, metavar="TEXT",
                   help="attribution shown with the tiles (default: OpenStreetMap's for "
                   "tile.openstreetmap.org)")
    g.add_argument("--users", default=None, metavar="FILE",
                   help="lines 'TOKEN NAME': every API call needs a token and acts as NAME")
    g.add_argument("--insecure-http", action="store_true",
                   help="allow a non-loopback --http host without --users")
    g.add_argument("--sender", default=None, metavar="NAME",
                   help="who the page is to the service without --users [WARAPS_SENDER, else "
                   "the login name]")


def register(subparsers: Any) -> None:
    from delegation.cli.connect import add_broker_args

    ui = subparsers.add_parser(
        "ui", help="the operator page: live units and missions in the browser",
        description="Serves the operator page (map of the units, missions, plans, tree and "
        "timeline, events; submit, preview, start, signal and cancel missions) for a service "
        "running on a broker. Ctrl-C stops.",
    )
    ui.add_argument("--service", default="delegator0", help="the service's unit name")
    add_http_args(ui, default=DEFAULT_HTTP)
    add_broker_args(ui)
    ui.set_defaults(func=_ui)


def page_options(args: argparse.Namespace) -> tuple[str, int, dict[str, Any]]:
    """(host, port, app options) from the flags; `UsageError` for a bad address or users file,
    or a non-loopback host without ``--users`` or ``--insecure-http``."""
    from delegation.errors import InputError
    from delegation.web.auth import read_users
    from delegation.web.server import is_loopback, parse_http

    try:
        host, port = parse_http(args.http)
    except ValueError as exc:
        raise UsageError(f"--http {exc}") from None
    users = None
    if args.users:
        try:
            users = read_users(args.users)
        except InputError as exc:
            raise UsageError(f"--users: {exc.fail_reason}") from None
    if not is_loopback(host) and users is None and not args.insecure_http:
        raise UsageError(f"--http {args.http}: a non-loopback host needs --users FILE (or "
                         "--insecure-http): anyone who reaches it could start and cancel missions")
    attribution = args.tile_attribution
    if attribution is None:
        attribution = ("© OpenStreetMap contributors"
                       if args.tiles and "openstreetmap.org" in args.tiles else "")
    return host, port, {"users": users, "tile_url": args.tiles,
                        "tile_attribution": attribution, "loopback_only": is_loopback(host)}


def start_page(stack: ExitStack, args: argparse.Namespace, settings: BrokerSettings, *,
               prefix: str, service: str, time_scale: float = 1.0) -> WebServer:
    """Start the bridge and the page's server on ``stack`` (stopped when it closes)."""
    from delegation.web.app import create_app
    from delegation.web.bridge import Bridge
    from delegation.web.server import WebServer

    host, port, options = page_options(args)
    bridge = Bridge(settings, prefix=prefix, service=service, sender=args.sender,
                    time_scale=time_scale)
    bridge.start()
    stack.callback(bridge.stop)
    server = WebServer(create_app(bridge, **options), host, port).start()
    stack.callback(server.stop)
    return server


def _ui(args: argparse.Namespace) -> int:
    from delegation.cli.connect import client_settings

    settings = client_settings(args)
    page_options(args)  # usage errors before any connection
    with ExitStack() as stack:
        server = start_page(stack, args, settings, prefix=args.prefix, service=args.service)
        print(f"operator page on {server.url} (service {args.service} on "
              f"{settings.describe()}); Ctrl-C stops", flush=True)
        threading.Event().wait()
    return 0
