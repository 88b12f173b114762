"""Following a mission live (``demo``, ``submit``, ``follow``): a table on a terminal, else one
line per change; ``$enough`` to open-ended tasks on request; the summary at the end."""

from __future__ import annotations

import argparse
import logging
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from delegation.cli.options import Stopped, positive_float
from delegation.errors import DelegationError

if TYPE_CHECKING:
    from rich.console import Console

    from delegation.render.progress import MissionProgress
    from delegation.runtime.client import ServiceClient

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class Watch:
    """How a command follows a mission: ``speedup`` the fleet's time factor (actual times are
    shown in mission seconds), ``timeout`` wall seconds at most; ``tracks`` collects the units'
    positions when given. With ``enough``, open-ended tasks (look-at-*) that hold the mission up
    (nothing else running) get ``$enough``, as an operator would send it, so that the mission
    can finish."""

    speedup: float
    timeout: float
    tracks: dict[str, list[Any]] | None = None
    enough: bool = False


def add_watch_args(parser: argparse.ArgumentParser) -> None:
    """``--speedup``, ``--timeout`` and ``--enough`` of a command that follows a mission it did
    not start the fleet of (``submit``, ``follow``): `watch_from` makes them a `Watch`."""
    parser.add_argument("--speedup", type=positive_float, default=1.0,
                        help="the fleet's time factor, to show actual times in mission seconds")
    parser.add_argument("--timeout", type=positive_float, default=3600.0,
                        help="stop following after this many seconds (exit 1; the mission goes "
                        "on)")
    parser.add_argument("--enough", action="store_true",
                        help="send $enough to open-ended tasks (look-at-*) once all others ended")


def watch_from(args: argparse.Namespace) -> Watch:
    """The `Watch` of `add_watch_args`' flags."""
    return Watch(args.speedup, args.timeout, enough=args.enough)


def follow(
    client: ServiceClient,
    plan: dict[str, Any],
    watch: Watch,
    console: Console,
    progress: MissionProgress | None = None,
) -> MissionProgress:
    """Show a mission's progress until it ends or the watch's timeout passes: a live table on a
    terminal, else one plain line per change (logs, CI, ``tee``). ``progress`` continues a
    mission already under way (``delegation follow``)."""
    from rich.live import Live

    from delegation.render.progress import MissionProgress, status_lines

    if progress is None:
        progress = MissionProgress(plan, speedup=watch.speedup)
    deadline = time.monotonic() + watch.timeout
    if not console.is_terminal:
        shown: dict[str, str] = {}

        def lines() -> None:
            for line in status_lines(progress, shown):
                console.print(line, soft_wrap=True, highlight=False)

        lines()
        _pump(client, progress, deadline, lines, watch)
        return progress
    with Live(
        progress.table(), console=console, refresh_per_second=6, transient=False, auto_refresh=True
    ) as live:
        _pump(client, progress, deadline, lambda: live.update(progress.table()), watch)
        live.update(progress.table())
    return progress


def _pump(
    client: ServiceClient,
    progress: MissionProgress,
    deadline: float,
    refresh: Any,
    watch: Watch,
) -> None:
    """Feed the client's events to ``progress`` until the mission ends or the deadline."""
    import queue

    root = progress.root_uuid
    while not progress.done and time.monotonic() < deadline:
        if watch.enough:
            _send_enough(client, progress, time.time())
        try:
            ev = client.events.get(timeout=0.25)
        except queue.Empty:
            continue
        if ev.kind == "position":
            if watch.tracks is not None:
                watch.tracks.setdefault(ev.unit, []).append(ev.data)
            continue
        data = ev.data
        if ev.kind == "mission" and data.get("root-uuid") == root:
            progress.on_mission(str(data.get("status")), str(data.get("fail-reason", "")), ev.at)
        elif ev.kind == "tst-feedback" and isinstance(data.get("node-uuid"), str):
            progress.on_node(data["node-uuid"], str(data.get("status")), ev.at)
        refresh()


def still_running_hint(console: Console, root: str, status: str = "running") -> None:
    """What an operator needs once a command stops following a mission that goes on."""
    console.print(
        f"mission {root} is still {status}; re-attach: delegation follow {root[:8]}; "
        f"cancel: delegation cancel {root[:8]}; end open-ended tasks: "
        f"delegation signal {root[:8]} '$enough'",
        soft_wrap=True,
    )


def _send_enough(client: ServiceClient, progress: MissionProgress, now: float) -> None:
    for node_uuid in progress.due_for_enough(now):
        progress.enough_sent.add(node_uuid)
        answer = client.request(
            {"command": "signal-tst-node", "node-uuid": node_uuid, "signal": "$enough"},
            api="tst",
            timeout=10.0,
        )
        if answer.get("response") != "ok":
            log.warning("$enough to %s: %s", node_uuid, answer.get("fail-reason"))


def run_mission(
    client: ServiceClient,
    command: dict[str, Any],
    console: Console,
    watch: Watch,
    *,
    hint: bool = True,
) -> MissionProgress | None:
    """Send a ``delegate`` with ``start``, follow the mission live and print the summary; None
    (after saying why) when it was not started. With ``hint``, stopping early says how to
    re-attach to or cancel the mission, which goes on."""
    answer = client.request({**command, "command": "delegate", "start": True}, timeout=120.0)
    if answer.get("response") != "started":
        console.print(f"[red]not started[/]: {answer.get('fail-reason')}")
        return None
    started = time.monotonic()
    root = mission_id(answer["plan"])
    try:  # from here on a stop leaves a running mission behind: always say how to go on
        console.print(f"mission {root} started", soft_wrap=True)
        for note in answer["plan"].get("notes") or []:  # default speeds, suspicious input
            console.print(f"note: {note}", soft_wrap=True, highlight=False)
        progress = follow(client, answer["plan"], watch, console)
    except (KeyboardInterrupt, Stopped):
        console.print()
        if hint:
            still_running_hint(console, root)
        raise
    _print_summary(console, progress, time.monotonic() - started)
    if not progress.done:
        console.print(f"[red]gave up following after {watch.timeout:g} s[/]")
        if hint:
            still_running_hint(console, root, progress.status)
    return progress


def mission_id(plan: dict[str, Any]) -> str:
    """A started mission's id: its tree's root node-uuid, under either spelling of the common
    params (the plan keeps the operator's: ``common_params`` or ``common-params``)."""
    tree = plan.get("tst")
    for key in ("common_params", "common-params"):
        common = tree.get(key) if isinstance(tree, dict) else None
        if isinstance(common, dict) and isinstance(common.get("node-uuid"), str):
            return str(common["node-uuid"])
    raise DelegationError("the service started a mission but its plan names no root node-uuid")


def _print_summary(console: Console, progress: MissionProgress, wall: float) -> None:
    console.print()
    console.print(progress.summary_table())
    plan = progress.plan
    status = progress.status
    style = "green" if progress.succeeded else "red"
    elapsed = progress.elapsed
    console.print(
        f"mission [{style}]{status}[/]"
        + (f": {progress.fail_reason}" if progress.fail_reason else "")
        + f"  plan makespan {float(plan.get('makespan') or 0):.0f} s"
        + (f", actual {elapsed:.0f} s" if elapsed is not None and progress.done else "")
        + f" (mission seconds; {wall:.1f} s wall at speedup {progress.speedup:g})"
    )


# --------------------------------------------------------------------------- demo
