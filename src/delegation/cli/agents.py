"""``delegation agents``: the live units a broker shows (heartbeats, positions, batteries)."""

from __future__ import annotations

import argparse
import json
import threading
import time
from contextlib import suppress
from typing import Any

from delegation.cli.connect import add_broker_args, client_settings
from delegation.cli.options import add_format_args
from delegation.errors import DelegationError


def register(subparsers: Any) -> None:
    agents = subparsers.add_parser("agents", help="list the live units a broker shows")
    agents.add_argument(
        "--wait", type=float, default=3.0, help="seconds to listen for heartbeats (default 3)"
    )
    add_format_args(agents)
    add_broker_args(agents)
    agents.set_defaults(func=_agents)


def _agents(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

    from delegation.fleet import FleetRegistry
    from delegation.messages import decode
    from delegation.runtime.transport import make_client

    settings = client_settings(args)
    registry = FleetRegistry()
    lock = threading.Lock()

    def sink(msg: Any) -> None:
        try:
            message = decode(msg.topic, msg.payload)
        except DelegationError:
            return
        with lock, suppress(DelegationError):
            registry.observe(msg.topic, message, time.time())

    client = make_client(settings, sink=sink)
    for rest in (
        "heartbeat",
        "direct_execution_info",
        "delegation_info",
        "sensor_info",
        "sensor/position",
        "sensor/battery_state",
    ):
        client.subscribe(f"{args.prefix}/unit/+/+/+/{rest}")
    # --wait bounds the connect too, but never below 3 s: a loaded broker (amqtt refusing MQTT 5
    # first, then 3.1.1) may take more than a second to answer a CONNECT
    client.connect(timeout=max(args.wait, 3.0))
    try:
        threading.Event().wait(args.wait)
    finally:
        client.disconnect()
    with lock:
        rows = registry.agents(time.time(), alive_only=True)
    if args.format == "json":
        print(json.dumps(rows, indent=2))
        return 0
    table = Table(title=f"live units on {settings.describe()} under {args.prefix}/")
    for col in ("name", "type", "state", "position", "seen", "tasks-available"):
        table.add_column(col, no_wrap=col in ("name", "seen"), overflow="fold")
    now = time.time()
    for r in rows:
        pos = r["position"]
        seen = r.get("last-seen")
        levels = r.get("levels", [])
        state = str(r.get("state", "")) if "direct execution" in levels else ", ".join(levels)
        if r.get("delegator"):  # another delegation service: its fleet's summary
            managed = r.get("units-managed", [])
            state = f"delegator of {len(managed)}: {', '.join(managed) or '-'}"
        elif r.get("managed-by"):
            state = f"{state} (managed by {r['managed-by']})"
        offers = r.get("delegates-tasks") if r.get("delegator") else r.get("tasks-available")
        table.add_row(
            r["name"],
            str(r.get("type") or "?"),
            state,
            f"{pos['latitude']:.5f},{pos['longitude']:.5f}" if pos else "-",
            f"{now - seen:.0f}s ago" if isinstance(seen, int | float) else "-",
            ", ".join(offers or []) or "-",
        )
    Console().print(table)
    if not rows:
        print(f"no live units seen within {args.wait:g} s")
    return 0
