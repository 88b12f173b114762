"""PNG plots of bench results: the objective per strategy, and each strategy's routes.

Figures are bare ``matplotlib.figure.Figure`` objects on the Agg canvas (no pyplot state), so
plotting works headless and off the main thread. Route maps reuse
``delegation.render.mapplot.render_map``.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from delegation.bench.runner import BenchResult, RunRecord

if TYPE_CHECKING:
    from matplotlib.figure import Figure

OBJECTIVE_LABEL: dict[str, str] = {"makespan": "makespan (s)", "total": "total time (s)"}


def slug(text: str) -> str:
    """A file-name-safe version of a scenario name."""
    return re.sub(r"[^A-Za-z0-9._-]+", "-", text).strip("-") or "scenario"


def new_figure(width: float, height: float) -> Figure:
    """A figure drawn by Agg, independent of pyplot."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=110)
    FigureCanvasAgg(fig)
    return fig


def bar_chart(records: Sequence[RunRecord], path: str | Path, title: str | None = None) -> Path:
    """One scenario's objective per strategy: a panel per objective, bars = mean over repeats.

    Whiskers span the repeats' min..max; a bar is hatched where its plan left tasks unassigned
    (with the count written above it); ``optimal``'s proven bound, where known, is a black tick.
    """
    objectives = list(dict.fromkeys(r.objective for r in records))
    strategies = list(dict.fromkeys(r.strategy for r in records))
    fig = new_figure(max(4.0, 3.2 * len(objectives) + 1.0), 4.0)
    axes = fig.subplots(1, len(objectives), squeeze=False)[0]
    import matplotlib

    cmap = matplotlib.colormaps["tab10"]
    for ax, objective in zip(axes, objectives, strict=True):
        for i, strategy in enumerate(strategies):
            runs = [r for r in records if r.objective == objective and r.strategy == strategy]
            if not runs:
                continue
            values = np.array([r.objective_value for r in runs], dtype=float)
            mean = float(values.mean())
            unassigned = max(r.unassigned for r in runs)
            ax.bar(
                i,
                mean,
                color=cmap(i % 10),
                edgecolor="black",
                hatch="//" if unassigned else None,
                yerr=[[mean - values.min()], [values.max() - mean]] if len(values) > 1 else None,
                capsize=4,
            )
            label = f"{mean:,.0f}" + (f"\n{unassigned} unassigned" if unassigned else "")
            ax.annotate(
                label,
                (i, mean),
                ha="center",
                va="bottom",
                fontsize=8,
                xytext=(0, 3),
                textcoords="offset points",
            )
            bounds = [r.bound for r in runs if r.bound is not None]
            if bounds:
                ax.plot([i - 0.4, i + 0.4], [max(bounds)] * 2, color="black", lw=2)
        ax.set_xticks(range(len(strategies)), strategies)
        ax.set_ylabel(OBJECTIVE_LABEL.get(objective, objective))
        ax.set_title(f"objective: {objective}", fontsize=10)
        ax.margins(y=0.15)
        ax.grid(True, axis="y", alpha=0.3)
    fig.suptitle(title or records[0].scenario, fontsize=11)
    fig.tight_layout()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, format="png")
    return out


def write_plots(
    result: BenchResult, directory: str | Path, *, maps: bool = True, max_map_tasks: int = 150
) -> list[Path]:
    """Per scenario: ``<name>-objective.png`` and ``<name>-<strategy>-<objective>-map.png``.

    Maps are skipped for scenarios with more than ``max_map_tasks`` tasks (unreadable anyway).
    """
    from delegation.render.mapplot import render_map

    out = Path(directory)
    written: list[Path] = []
    sources = list(dict.fromkeys(r.source for r in result.records))
    names: dict[str, str] = {}
    for source in sources:
        records = [r for r in result.records if r.source == source]
        name = slug(records[0].scenario)
        if name in names.values():  # two files with one scenario name
            name = f"{name}-{len(names)}"
        names[source] = name
        written.append(bar_chart(records, out / f"{name}-objective.png"))
        if not maps or records[0].tasks > max_map_tasks or source not in result.scenarios:
            continue
        _, units = result.scenarios[source]
        for (src, strategy, objective), plan in result.plans.items():
            if src != source:
                continue
            title = (
                f"{records[0].scenario}: {strategy} / {objective}, "
                f"makespan {plan.makespan:,.0f} s, total {plan.total_time:,.0f} s"
            )
            written.append(
                render_map(
                    plan, units, path=out / f"{name}-{strategy}-{objective}-map.png", title=title
                )
            )
    return written
