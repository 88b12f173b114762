"""Gantt charts of plans: one lane per unit over mission time, tasks coloured by type.

A bar's light part is the travel to the task, its solid part the work; a dotted grey line is a
unit waiting before its next task (for the tasks that must finish first: the tree's precedence);
a diamond is a task done in place (``look-at-*``; flown, a thin strip). With ``flown`` (from a
followed mission, see ``flown_bars``) each unit gets a second, hatched lane with what it did.
Figures are bare ``Figure`` objects on the Agg canvas (no pyplot state), so this runs headless
and off the main thread.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from delegation.allocation import Plan
    from delegation.render.progress import TaskRow

#: Gaps shorter than this (s) are not drawn as waits.
MIN_WAIT = 1e-6


@dataclass(frozen=True, slots=True)
class Bar:
    """One task on one unit: from ``start`` (travel begins) to ``end``; ``travel`` seconds of it
    are the way there."""

    unit: str
    name: str
    start: float
    end: float
    travel: float = 0.0
    node: str = ""


def plan_bars(plan: Plan | Mapping[str, Any]) -> list[Bar]:
    """The bars of a ``Plan`` or of its JSON (``plan.json``, the service's plan)."""
    if isinstance(plan, Mapping):
        return [
            Bar(str(a["execunit"]).lstrip("/"), str(a.get("name", "")), float(a["start"]),
                float(a["end"]), float(a.get("travel-time") or 0.0), str(a.get("node-uuid", "")))
            for a in plan.get("assignments", [])
        ]
    return [Bar(a.execunit.lstrip("/"), a.name, a.start, a.end, a.travel_time, a.node_uuid)
            for a in plan.assignments]


def flown_bars(rows: Iterable[TaskRow], now: float | None = None) -> list[Bar]:
    """What the units did, from a followed mission's rows (``MissionProgress.rows``): from
    started to ended in mission seconds; a task still running ends at ``now`` (if given)."""
    bars = []
    for row in rows:
        if row.started is None:
            continue
        end = row.ended if row.ended is not None else now
        if end is None:
            continue
        bars.append(Bar(row.unit.lstrip("/"), row.name, row.started, max(end, row.started),
                        node=row.node_uuid))
    return bars


def _waits(bars: Sequence[Bar]) -> list[tuple[float, float]]:
    """The gaps before each task of one unit's lane (from 0 or the previous task's end)."""
    gaps = []
    previous = 0.0
    for bar in sorted((b for b in bars if b.end > b.start), key=lambda b: b.start):
        if bar.start - previous > MIN_WAIT:
            gaps.append((previous, bar.start))
        previous = max(previous, bar.end)
    return gaps


def render_gantt(
    plan: Plan | Mapping[str, Any],
    path: str | Path,
    *,
    title: str | None = None,
    flown: Sequence[Bar] | None = None,
) -> Path:
    """Draw the plan's Gantt chart (with ``flown`` lanes when given) to a PNG at ``path``."""
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    planned = plan_bars(plan)
    units = sorted({b.unit for b in planned} | {b.unit for b in flown or []})
    kinds = sorted({b.name for b in planned} | {b.name for b in flown or []})
    colour = {k: matplotlib.colormaps["tab10"](i % 10) for i, k in enumerate(kinds)}
    lanes: list[tuple[str, str, list[Bar]]] = []
    for unit in units:
        lanes.append((unit, "plan", [b for b in planned if b.unit == unit]))
        if flown is not None:
            lanes.append((unit, "flown", [b for b in flown if b.unit == unit]))
    fig = Figure(figsize=(10.0, 1.2 + 0.45 * max(1, len(lanes))), dpi=110)
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    # Tasks done in place (planned with no duration, e.g. look-at-*): a diamond in the plan and a
    # thin strip along the flown lane's top, so that they never hide the unit's other tasks.
    in_place = {b.node for b in planned if b.end - b.start <= MIN_WAIT and b.node}
    waited = passive = False
    for y, (_, kind, bars) in enumerate(lanes):
        hatch = "xx" if kind == "flown" else None
        for b in bars:
            if b.node in in_place and b.end - b.start > MIN_WAIT:
                ax.barh(y - 0.38, b.end - b.start, left=b.start, height=0.14,
                        color=colour[b.name], edgecolor="black", linewidth=0.5)
                passive = True
                continue
            if b.end - b.start <= MIN_WAIT:
                ax.plot([b.start], [y], marker="D", ms=6, color=colour[b.name],
                        markeredgecolor="black")
                passive = True
                continue
            travel = min(max(b.travel, 0.0), b.end - b.start)
            if travel > 0:
                ax.barh(y, travel, left=b.start, height=0.6, color=colour[b.name], alpha=0.35,
                        edgecolor="black", linewidth=0.5, hatch=hatch)
            ax.barh(y, b.end - b.start - travel, left=b.start + travel, height=0.6,
                    color=colour[b.name], edgecolor="black", linewidth=0.5, hatch=hatch)
        for since, until in _waits([b for b in bars if b.node not in in_place]):
            ax.plot([since, until], [y, y], color="0.5", ls=":", lw=1.5)
            waited = True
    ax.set_yticks(range(len(lanes)),
                  [f"{u} ({k})" if flown is not None else u for u, k, _ in lanes], fontsize=8)
    ax.invert_yaxis()
    ax.set_xlabel("mission time (s)")
    ax.grid(True, axis="x", alpha=0.3)
    handles: list[Any] = [Patch(facecolor=colour[k], edgecolor="black", label=k) for k in kinds]
    handles.append(Patch(facecolor="0.7", alpha=0.35, edgecolor="black",
                         label="travel to the task (light)"))
    if waited:
        handles.append(Line2D([], [], color="0.5", ls=":", label="waiting for earlier tasks"))
    if passive:
        handles.append(Line2D([], [], marker="D", ls="", color="0.5", markeredgecolor="black",
                              label="task done in place (flown: thin strip)"))
    if flown is not None:
        handles.append(Patch(facecolor="white", edgecolor="black", hatch="xx",
                             label="flown (from feedback)"))
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8,
              frameon=False)
    ax.set_title(title or "plan", fontsize=10)
    fig.tight_layout()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, format="png")
    return out
