"""Following a mission: a pure progress model fed with feedback, rendered with rich.

``submit`` and ``demo`` feed it the service's ``tst/feedback`` and ``delegation/feedback`` with
wall-clock ``now``; it keeps one row per task (unit, status, planned and actual times) and renders
a live table and a plan-vs-actual summary per unit. Actual times are mission seconds: wall seconds
since the mission started, times ``speedup`` (the simulation's time factor), so they compare with
the plan's.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from rich.table import Table

from delegation.errors import InputError
from delegation.messages import FINAL_MISSION_STATUSES, TERMINAL_NODE_STATUSES
from delegation.tst.node import TstNode, parse_tree, walk

_FINAL_NODE = TERMINAL_NODE_STATUSES
_FINAL_MISSION = FINAL_MISSION_STATUSES
_STYLE = {
    "succeeded": "green",
    "failed": "red",
    "aborted": "red",
    "revoked": "red",
    "running": "yellow",
    "paused": "magenta",
}


@dataclass(slots=True)
class TaskRow:
    """One task node of the mission: who runs it, the plan's times, and what happened."""

    node_uuid: str
    name: str
    unit: str
    planned_start: float
    planned_end: float
    status: str = "not-active"
    started: float | None = None  # mission seconds
    ended: float | None = None


class MissionProgress:
    """The state of one mission as seen from its feedback (no I/O, ``now`` passed in)."""

    def __init__(self, plan: dict[str, Any], speedup: float = 1.0) -> None:
        self.plan = plan
        self.speedup = speedup
        tree = parse_tree(plan["tst"])
        self.root_uuid: str = tree.node_uuid or ""
        order = {n.node_uuid: i for i, (_, n) in enumerate(walk(tree))}
        assignments = sorted(
            plan.get("assignments", []), key=lambda a: order.get(a.get("node-uuid"), 0)
        )
        self.rows: dict[str, TaskRow] = {
            a["node-uuid"]: TaskRow(
                node_uuid=a["node-uuid"],
                name=a.get("name", ""),
                unit=str(a.get("execunit", "")),
                planned_start=float(a.get("start", 0.0)),
                planned_end=float(a.get("end", 0.0)),
            )
            for a in assignments
        }
        self.open_ended: frozenset[str] = frozenset(
            n.node_uuid for _, n in walk(tree)
            if n.node_uuid in self.rows and _is_open_ended(n)
        )
        self.enough_sent: set[str] = set()
        self._running_since: dict[str, float] = {}
        self.status = "planned"
        self.fail_reason = ""
        self.started_at: float | None = None  # wall clock
        self.ended_at: float | None = None
        self.root_status = "not-active"

    # ----------------------------------------------------------------- feeding

    def _mission_time(self, now: float) -> float:
        if self.started_at is None:
            self.started_at = now
        return (now - self.started_at) * self.speedup

    def on_node(self, node_uuid: str, status: str, now: float) -> bool:
        """A ``tst/feedback`` for a node; True if it changed something shown."""
        if node_uuid == self.root_uuid:
            self.root_status = status
            if status == "running" and self.started_at is None:
                self.started_at = now
        row = self.rows.get(node_uuid)
        if row is None or row.status in _FINAL_NODE or row.status == status:
            return node_uuid == self.root_uuid
        row.status = status
        if status == "running":
            self._running_since.setdefault(node_uuid, now)
        t = self._mission_time(now)
        if status == "running" and row.started is None:
            row.started = t
        if status in _FINAL_NODE:
            row.ended = t
        return True

    def resume(self, node_uuid: str, status: str, started: float | None, ended: float | None,
               now: float) -> None:
        """A task's state as the service reported it (re-attaching to a running mission):
        ``started``/``ended`` in mission seconds."""
        row = self.rows.get(node_uuid)
        if row is None:
            return
        row.status, row.started, row.ended = status, started, ended
        if status == "running":
            self._running_since.setdefault(node_uuid, now)

    def on_mission(self, status: str, fail_reason: str, now: float) -> None:
        """A lifecycle event from ``delegation/feedback``."""
        if self.status in _FINAL_MISSION:
            return
        self.status = status
        self.fail_reason = fail_reason
        if status in ("started", "running") and self.started_at is None:
            self.started_at = now
        if status in _FINAL_MISSION:
            self.ended_at = now

    def due_for_enough(self, now: float, dwell: float = 1.0) -> list[str]:
        """Open-ended tasks (look-at-*, ...) that hold the mission up: running for at least
        ``dwell`` wall seconds while no other task is running. An operator ends them with
        ``$enough`` so that the mission can go on (a seq after them) and finish."""
        if any(r.status in ("running", "paused") for u, r in self.rows.items()
               if u not in self.open_ended):
            return []
        return [
            u for u in self.open_ended
            if u not in self.enough_sent and self.rows[u].status == "running"
            and self._running_since.get(u, now) <= now - dwell
        ]

    @property
    def done(self) -> bool:
        return self.status in _FINAL_MISSION

    @property
    def succeeded(self) -> bool:
        return self.status == "succeeded"

    @property
    def elapsed(self) -> float | None:
        """Mission seconds from start to end (or to the last event)."""
        if self.started_at is None:
            return None
        end = self.ended_at if self.ended_at is not None else self.started_at
        return (end - self.started_at) * self.speedup

    # ----------------------------------------------------------------- summaries

    def unit_summary(self) -> list[dict[str, Any]]:
        """Per unit: tasks, tasks succeeded, planned end and actual end (mission seconds).

        Open-ended tasks (look-at-*) end when told to, not by plan: they do not count for ends.
        """
        units: dict[str, dict[str, Any]] = {}
        for row in self.rows.values():
            u = units.setdefault(
                row.unit,
                {"unit": row.unit, "tasks": 0, "succeeded": 0, "planned-end": 0.0,
                 "actual-end": None},
            )
            u["tasks"] += 1
            u["succeeded"] += row.status == "succeeded"
            if row.node_uuid in self.open_ended:
                continue
            u["planned-end"] = max(u["planned-end"], row.planned_end)
            if row.ended is not None:
                u["actual-end"] = max(u["actual-end"] or 0.0, row.ended)
        return sorted(units.values(), key=lambda u: u["unit"])

    # ----------------------------------------------------------------- rendering

    def table(self) -> Table:
        """The live view: a line per task with its unit and status."""
        title = f"mission {self.root_uuid[:8]}  [{self.status}]"
        table = Table(title=title, title_justify="left", expand=False,
                      caption="start-end in mission seconds")
        table.add_column("task", no_wrap=True)
        table.add_column("unit", no_wrap=True)
        table.add_column("status", no_wrap=True, min_width=9)
        table.add_column("plan (s)", justify="right", no_wrap=True)
        table.add_column("actual (s)", justify="right", no_wrap=True)
        for row in self.rows.values():
            style = _STYLE.get(row.status, "")
            actual = "" if row.started is None else f"{_fmt(row.started)}-{_fmt(row.ended)}"
            table.add_row(
                row.name,
                row.unit,
                f"[{style}]{row.status}[/]" if style else row.status,
                f"{row.planned_start:.0f}-{row.planned_end:.0f}",
                actual,
            )
        return table

    def summary_table(self) -> Table:
        """Plan vs actual per unit, in mission seconds."""
        table = Table(title="plan vs actual (mission seconds)", title_justify="left")
        for col in ("unit", "tasks", "succeeded", "planned end", "actual end", "difference"):
            table.add_column(col, justify="left" if col == "unit" else "right")
        for u in self.unit_summary():
            actual = u["actual-end"]
            diff = "-" if actual is None else _signed(actual - u["planned-end"])
            table.add_row(u["unit"], str(u["tasks"]), str(u["succeeded"]),
                          f"{u['planned-end']:.0f}", _fmt(actual), diff)
        return table


def _is_open_ended(node: TstNode) -> bool:
    from delegation.costs import task_geometry

    try:
        return task_geometry(node).open_ended
    except (KeyError, ValueError, TypeError, InputError):
        return False


def _signed(value: float) -> str:
    """``+12``, ``-3``, and ``0`` (never ``-0``)."""
    return "0" if round(value) == 0 else f"{value:+.0f}"


def _fmt(value: float | None) -> str:
    return "" if value is None else f"{value:.0f}"


def status_lines(progress: MissionProgress, shown: dict[str, str]) -> list[str]:
    """Plain lines for what changed since the last call (``shown`` remembers what was printed):
    for output that is not a terminal, where a live table cannot redraw."""
    lines: list[str] = []
    key = f"mission:{progress.root_uuid}"
    if shown.get(key) != progress.status:
        shown[key] = progress.status
        reason = f": {progress.fail_reason}" if progress.fail_reason else ""
        lines.append(f"mission {progress.root_uuid[:8]} {progress.status}{reason}")
    for row in progress.rows.values():
        if shown.get(row.node_uuid, "not-active") == row.status:
            continue
        shown[row.node_uuid] = row.status
        actual = "" if row.started is None else f", actual {_fmt(row.started)}-{_fmt(row.ended)}"
        lines.append(
            f"  {row.name} {row.unit} {row.status} "
            f"(plan {row.planned_start:.0f}-{row.planned_end:.0f} s{actual})"
        )
    return lines
