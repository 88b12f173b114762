"""PNG plots of bench results: the objective per strategy, and each strategy's routes.

Figures are bare ``matplotlib.figure.Figure`` objects on the Agg canvas (no pyplot state), so
plotting works headless and off the main thread. Route maps reuse
``delegation.render.mapplot.render_map``.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from delegation.bench.runner import BenchResult, RunRecord
from delegation.bench.stats import describe
from delegation.bench.summary import StrategySummary

if TYPE_CHECKING:
    from matplotlib.artist import Artist
    from matplotlib.axes import Axes
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


def save_png(fig: Figure, path: str | Path) -> Path:
    """Write ``fig`` as a PNG at ``path``, its folder made if need be; returns the path."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, format="png")
    return out


def bar_chart(records: Sequence[RunRecord], path: str | Path, title: str | None = None) -> Path:
    """One scenario's objective per strategy: a panel per objective; the legend explains every
    mark: bar = mean over repeats, black whisker = the mean's 95 % CI (Student t), grey dots =
    the single runs, hatched = tasks left unassigned, thick black tick = CP-SAT's proven bound,
    dashed line = best known value, black dotted tick = a shared search's lower bound (DESIGN
    3.11) with the makespan over it. A strategy that returned another's plan is labelled so."""
    from delegation.bench.summary import strategy_label

    objectives = list(dict.fromkeys(r.objective for r in records))
    strategies = list(dict.fromkeys(r.strategy for r in records))
    fig = new_figure(max(5.0, 3.6 * len(objectives) + 1.0), 4.6)
    axes = fig.subplots(1, len(objectives), squeeze=False)[0]
    import matplotlib

    cmap = matplotlib.colormaps["tab10"]
    shown: set[str] = set()
    for ax, objective in zip(axes, objectives, strict=True):
        labels = []
        for i, strategy in enumerate(strategies):
            runs = [r for r in records if r.objective == objective and r.strategy == strategy]
            labels.append(strategy_label(strategy, runs) if runs else strategy)
            if runs:
                shown |= _strategy_bar(ax, i, runs, objective, cmap(i % 10))
        best = next((r.best_known for r in records
                     if r.objective == objective and r.best_known is not None), None)
        if best is not None:
            ax.axhline(best, color="tab:red", ls="--", lw=1)
            shown.add("best")
        ax.set_xticks(range(len(strategies)), labels, fontsize=8)
        ax.set_ylabel(OBJECTIVE_LABEL.get(objective, objective))
        ax.set_title(f"objective: {objective}", fontsize=10)
        ax.margins(y=0.15)
        ax.grid(True, axis="y", alpha=0.3)
    n = max(sum(1 for r in records if r.objective == objectives[0] and r.strategy == s)
            for s in strategies)
    handles = [h for k, h in _bar_chart_marks(n).items() if k in shown]
    fig.legend(handles=handles, loc="lower center", ncol=min(len(handles), 3), fontsize=8,
               frameon=False)
    fig.suptitle(title or records[0].scenario, fontsize=11)
    fig.tight_layout(rect=(0, 0.12 if len(handles) > 3 else 0.07, 1, 1))
    return save_png(fig, path)


def _strategy_bar(
    ax: Axes, i: int, runs: Sequence[RunRecord], objective: str, colour: Any
) -> set[str]:
    """One strategy's bar at ``i`` with its marks (`bar_chart`); returns the marks drawn, for
    the legend."""
    shown = {"bar"}
    stats = describe([r.objective_value for r in runs])
    unassigned = max(r.unassigned for r in runs)
    ax.bar(i, stats.mean, color=colour, edgecolor="black", hatch="//" if unassigned else None)
    if unassigned:
        shown.add("hatch")
    if stats.ci_low is not None and stats.ci_high is not None:
        ax.errorbar(i, stats.mean, yerr=[[stats.mean - stats.ci_low],
                                         [stats.ci_high - stats.mean]],
                    color="black", capsize=5, lw=1.2)
        shown.add("ci")
    if len(runs) > 1:
        ax.plot([i] * len(runs), [r.objective_value for r in runs], "o", ms=3,
                color="0.35", zorder=3)
        shown.add("runs")
    label = f"{stats.mean:,.0f}" + (f"\n{unassigned} unassigned" if unassigned else "")
    ax.annotate(label, (i, stats.mean), ha="center", va="bottom", fontsize=8,
                xytext=(8, 3), textcoords="offset points")
    searches = [r.search_bound for r in runs
                if r.search_bound is not None and objective == "makespan"]
    if searches:
        ax.plot([i - 0.4, i + 0.4], [max(searches)] * 2, color="black", lw=2, ls=":")
        best_vs = min((r.vs_search_bound for r in runs if r.vs_search_bound), default=None)
        if best_vs is not None:
            ax.annotate(f"{best_vs:.2f}x bound", (i, max(searches)), ha="center",
                        va="top", fontsize=7, color="black", xytext=(0, -3),
                        textcoords="offset points")
        shown.add("search")
    bounds = [r.bound for r in runs if r.bound is not None]
    if bounds:
        ax.plot([i - 0.4, i + 0.4], [max(bounds)] * 2, color="black", lw=3)
        shown.add("bound")
    return shown


def _bar_chart_marks(n: int) -> dict[str, Artist]:
    """The legend's entry for each mark `bar_chart` may draw, in legend order (``n``: runs
    per bar)."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    return {
        "bar": Patch(facecolor="0.8", edgecolor="black", label=f"mean of {n} run(s)"),
        "ci": Line2D([], [], color="black", marker="_", ms=10, label="95% CI of the mean"),
        "runs": Line2D([], [], color="0.35", marker="o", ls="", ms=3, label="single runs"),
        "hatch": Patch(facecolor="white", edgecolor="black", hatch="//",
                       label="tasks left unassigned"),
        "bound": Line2D([], [], color="black", lw=3, label="proven lower bound (CP-SAT)"),
        "best": Line2D([], [], color="tab:red", ls="--", label="best known value"),
        "search": Line2D([], [], color="black", ls=":", lw=2,
                         label="search's lower bound (DESIGN 3.11), makespan / it"),
    }


def summary_plot(rows: Sequence[StrategySummary], path: str | Path) -> Path:
    """Across scenarios, a panel per objective: the geometric mean ratio to the baseline per
    strategy (bar; 1 = the baseline, dotted), with its wins, ties, copied plans and failures
    written above it (explained in the legend)."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    objectives = list(dict.fromkeys(r.objective for r in rows)) or ["-"]
    fig = new_figure(max(5.0, 3.8 * len(objectives) + 1.0), 4.4)
    axes = fig.subplots(1, len(objectives), squeeze=False)[0]
    import matplotlib

    cmap = matplotlib.colormaps["tab10"]
    strategies = list(dict.fromkeys(r.strategy for r in rows))
    baseline = rows[0].baseline if rows else "-"
    for ax, objective in zip(axes, objectives, strict=True):
        mine = [r for r in rows if r.objective == objective]
        for row in mine:
            i = strategies.index(row.strategy)
            value = row.geomean_ratio
            if value is not None:
                ax.bar(i, value, color=cmap(i % 10), edgecolor="black")
            ax.annotate(
                f"{'-' if value is None else f'{value:.3f}'}\n"
                f"W{row.wins} T{row.ties} C{row.same_plan} F{row.failed_runs}",
                (i, value or 0.0), ha="center", va="bottom", fontsize=8, xytext=(0, 3),
                textcoords="offset points")
        ax.axhline(1.0, color="black", ls=":", lw=1)
        ax.set_xticks(range(len(strategies)), strategies, fontsize=8)
        ax.set_ylabel(f"geometric mean of objective / {baseline}'s")
        ax.set_title(f"objective: {objective}", fontsize=10)
        ax.margins(y=0.2)
        ax.grid(True, axis="y", alpha=0.3)
    handles = [
        Patch(facecolor="0.8", edgecolor="black", label="geometric mean ratio over scenarios"),
        Line2D([], [], color="black", ls=":", label=f"1 = as good as {baseline}"),
        Patch(color="none", label="W wins, T ties, C copied another's plan, F failed runs"),
    ]
    fig.legend(handles=handles, loc="lower center", ncol=3, fontsize=8, frameon=False)
    fig.suptitle("Strategies across scenarios", fontsize=11)
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    return save_png(fig, path)


def write_plots(
    result: BenchResult,
    directory: str | Path,
    *,
    maps: bool = True,
    gantt: bool = True,
    max_map_tasks: int = 150,
) -> list[Path]:
    """Per scenario: ``<name>-objective.png``, and per strategy x objective (first repeat)
    ``<name>-<strategy>-<objective>-map.png`` and ``-gantt.png``.

    Maps and Gantt charts are skipped for scenarios with more than ``max_map_tasks`` tasks
    (unreadable anyway).
    """
    from delegation.render.gantt import render_gantt
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
        if records[0].tasks > max_map_tasks or source not in result.scenarios:
            continue
        _, units = result.scenarios[source]
        for (src, strategy, objective), plan in result.plans.items():
            if src != source:
                continue
            title = (
                f"{records[0].scenario}: {strategy} / {objective}, "
                f"makespan {plan.makespan:,.0f} s, total {plan.total_time:,.0f} s"
            )
            stem = f"{name}-{slug(strategy)}-{objective}"
            if maps:
                written.append(render_map(plan, units, path=out / f"{stem}-map.png", title=title))
            if gantt:
                written.append(render_gantt(plan, out / f"{stem}-gantt.png", title=title))
    return written
