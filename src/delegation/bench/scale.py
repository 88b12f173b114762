"""Scale sweep: every strategy on a grid of generated scenarios (units x tasks).

Shows where each strategy stops being usable. Cells run from small to large; once a strategy's
run takes longer than the budget (wall time, seconds), every cell with at least as many units
and at least as many tasks is *skipped* for that strategy and kept as a ``skipped`` record naming
the cell that exceeded, so nothing is silently dropped. ``optimal`` runs with the time limit it
is given. Each plan runs in a child process stopped at the budget, so a sweep takes at most
(cells that run) x budget.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from delegation.allocation.strategies import resolve_strategy
from delegation.bench.generate import GeneratorOptions, generate_scenario
from delegation.bench.isolate import Outcome
from delegation.bench.report import write_rows_csv
from delegation.bench.runner import (
    ProgressFn,
    RunRecord,
    check_choice,
    run_one,
    scenarios_from_dicts,
    warm_up,
)
from delegation.errors import InputError, InputProblem

if TYPE_CHECKING:
    from delegation.bench.executor import Executor

#: The default grid: runs in a few minutes on 2 cores with the default budget and time limit.
DEFAULT_UNITS: tuple[int, ...] = (5, 20, 50, 200)
DEFAULT_TASKS: tuple[int, ...] = (10, 30, 100, 300, 1000)
DEFAULT_BUDGET = 20.0

OK, OVER_BUDGET, SKIPPED, FAILED = "ok", "over-budget", "skipped", "failed"


@dataclass
class ScaleRecord:
    """One strategy on one grid cell; ``status`` says whether it ran, and how it went."""

    strategy: str
    objective: str
    units: int
    tasks: int
    seed: int
    status: str
    wall_time: float | None = None
    solve_time: float | None = None
    objective_value: float | None = None
    unassigned: int | None = None
    #: objective / the best strategy's on this cell, among plans with the fewest unassigned
    #: (None when fewer than two strategies produced such a plan).
    relative_to_best: float | None = None
    note: str = ""
    problems: list[str] = field(default_factory=list)
    #: what the strategy reported doing (``Plan.notes``)
    notes: list[str] = field(default_factory=list)
    #: the plan's digest, and the strategy listed before it whose plan this very plan is
    #: (optimal keeping the auction's): such a record is never "best"
    plan_digest: str = ""
    same_plan_as: str | None = None

    @property
    def size(self) -> int:
        """InputProblem size: units x tasks (the cost tables' size)."""
        return self.units * self.tasks

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "size": self.size}


SCALE_FIELDS: tuple[str, ...] = (*ScaleRecord.__dataclass_fields__, "size")


def grid(units: Sequence[int], tasks: Sequence[int]) -> list[tuple[int, int]]:
    """Cells ordered from small to large (by units x tasks, then units)."""
    problems = [
        InputProblem("scale", kind, f"sizes must be >= 1, not {v}")
        for kind, values in (("units", units), ("tasks", tasks))
        for v in values
        if v < 1
    ]
    if problems or not units or not tasks:
        raise InputError(problems or [InputProblem("scale", "", "needs at least one size of each")])
    cells = {(int(u), int(t)) for u in units for t in tasks}
    return sorted(cells, key=lambda c: (c[0] * c[1], c[0], c[1]))


def run_scale(
    strategies: Sequence[str] | None = None,
    *,
    objectives: Sequence[str] = ("makespan",),
    units: Sequence[int] = DEFAULT_UNITS,
    tasks: Sequence[int] = DEFAULT_TASKS,
    budget: float = DEFAULT_BUDGET,
    time_limit: float = 5.0,
    generator: GeneratorOptions | None = None,
    progress: ProgressFn | None = None,
    isolate: bool = True,
    executor: Executor | None = None,
) -> list[ScaleRecord]:
    """Run the sweep; one record per strategy x objective x cell, skipped cells included.

    With ``isolate`` (the default) each plan runs in a child process that is stopped when the
    budget is up, so one slow strategy cannot hold the sweep up for longer than its budget.
    A run starts once every smaller cell that could stop it (no more units and no more tasks)
    has finished for its strategy and objective, so an ``executor`` with several workers runs
    independent cells at once and the records are those of the one-by-one sweep.
    """
    from delegation.allocation import OBJECTIVES, STRATEGIES
    from delegation.bench.executor import LocalExecutor

    strategies = [resolve_strategy(s) for s in strategies or list(STRATEGIES)]
    strategies = check_choice("strategies", strategies, STRATEGIES)
    objectives = check_choice("objectives", objectives, OBJECTIVES)
    if not budget > 0:
        raise InputError(InputProblem("budget", "", f"must be > 0 seconds, not {budget}"))
    base = generator or GeneratorOptions()
    cells = grid(units, tasks)
    executor = executor or LocalExecutor(isolate)
    executor.prepare(warm_up, strategies, objectives)
    pairs = [(s, o) for o in objectives for s in strategies]
    records = {
        (cell, pair): ScaleRecord(pair[0], pair[1], cell[0], cell[1], base.seed, SKIPPED)
        for cell in cells for pair in pairs
    }
    sweep = _Sweep(cells, pairs, base, time_limit)
    total, done = len(records), 0
    settled: set[_Key] = set()
    try:
        while not sweep.finished:
            batch = sweep.ready(records, budget)
            for key in batch.skipped:
                settled.add(key)
                done += 1
                if progress:
                    progress(done, total, f"{_label(key)} skipped")
            if not batch.runs:
                continue
            timeout = budget if isolate else None
            for index, outcome in executor.run(_record_only, batch.kwargs, timeout):
                key = batch.runs[index]
                _fill(records[key], outcome, budget=budget, isolate=isolate)
                sweep.finish(key, records[key].status == OVER_BUDGET)
                settled.add(key)
                done += 1
                if progress:
                    progress(done, total, _label(key))
    except KeyboardInterrupt:
        raise ScaleInterrupted(_ordered(cells, pairs, records, settled)) from None
    return _ordered(cells, pairs, records, settled)


class ScaleInterrupted(KeyboardInterrupt):
    """Ctrl-C during the sweep, with the records of the runs that were settled by then."""

    def __init__(self, records: list[ScaleRecord]) -> None:
        super().__init__()
        self.records = records


def _label(key: _Key) -> str:
    (units, tasks), (strategy, objective) = key
    return f"{units}x{tasks} {strategy}/{objective}"


def _ordered(cells: list[tuple[int, int]], pairs: list[tuple[str, str]],
             records: dict[_Key, ScaleRecord], settled: set[_Key]) -> list[ScaleRecord]:
    """The settled records cell by cell (small to large), compared within each cell."""
    out: list[ScaleRecord] = []
    for cell in cells:
        mine = [records[(cell, pair)] for pair in pairs if (cell, pair) in settled]
        _relative(mine)
        _mark_copies(mine)
        out.extend(mine)
    return out


_Key = tuple[tuple[int, int], tuple[str, str]]


@dataclass
class _Batch:
    runs: list[_Key]
    kwargs: list[dict[str, Any]]
    skipped: list[_Key]


class _Sweep:
    """Which runs may start: those whose dominated cells (<= units and <= tasks) are settled."""

    def __init__(self, cells: list[tuple[int, int]], pairs: list[tuple[str, str]],
                 base: GeneratorOptions, time_limit: float) -> None:
        self.cells, self.pairs, self.base, self.time_limit = cells, pairs, base, time_limit
        self.pending = {(c, p) for c in cells for p in pairs}
        self.stopped: dict[tuple[str, str], list[tuple[int, int]]] = {}
        self._scenarios: dict[tuple[int, int], Any] = {}

    @property
    def finished(self) -> bool:
        return not self.pending

    def finish(self, key: _Key, over: bool) -> None:
        if over:
            self.stopped.setdefault(key[1], []).append(key[0])

    def _scenario(self, cell: tuple[int, int]) -> Any:
        if cell not in self._scenarios:
            options = GeneratorOptions(**{**self.base.__dict__, "units": cell[0],
                                          "tasks": cell[1]})
            item = scenarios_from_dicts([generate_scenario(options)])[0]
            self._scenarios[cell] = (item, item.scenario.tree(), item.scenario.units())
        return self._scenarios[cell]

    def ready(self, records: dict[_Key, ScaleRecord], budget: float) -> _Batch:
        batch = _Batch([], [], [])
        for key in sorted(self.pending, key=lambda k: (self.cells.index(k[0]),
                                                       self.pairs.index(k[1]))):
            (u, t), pair = key
            below = [k for k in self.pending if k[1] == pair and k != key
                     and k[0][0] <= u and k[0][1] <= t]
            if below:
                continue
            block = _blocker(self.stopped.get(pair, []), u, t)
            if block is not None:
                records[key].note = (f"skipped: exceeded the budget ({budget:g} s) at "
                                     f"{block[0]}x{block[1]}")
                batch.skipped.append(key)
                continue
            item, tree, unit_states = self._scenario((u, t))
            batch.runs.append(key)
            batch.kwargs.append(dict(item=item, tree=tree, units=unit_states, strategy=pair[0],
                                     objective=pair[1], time_limit=self.time_limit))
        for key in batch.runs + batch.skipped:
            self.pending.discard(key)
        return batch


def _record_only(**kwargs: Any) -> RunRecord:
    """``run_one`` without the plan (what a child process sends back)."""
    return run_one(**kwargs)[0]


def _fill(record: ScaleRecord, outcome: Outcome, *, budget: float, isolate: bool) -> None:
    """Fill ``record`` from a run's outcome: ok, over budget (finished late or stopped), failed."""
    if outcome.timed_out:
        record.status = OVER_BUDGET
        record.note = f"stopped at the budget ({budget:g} s)"
        return
    if not outcome.ok:
        record.status, record.note = FAILED, str(outcome.input_error or outcome.crashed)
        return
    run: RunRecord = outcome.value
    record.wall_time, record.solve_time = run.wall_time, run.solve_time
    record.objective_value, record.unassigned = run.objective_value, run.unassigned
    record.problems = run.problems
    record.notes = run.notes
    record.plan_digest = run.plan_digest
    record.status = OK
    if run.wall_time > budget:
        record.status = OVER_BUDGET
        record.note = f"took {run.wall_time:.1f} s > budget {budget:g} s"


def _blocker(blocks: list[tuple[int, int]], units: int, tasks: int) -> tuple[int, int] | None:
    """The first cell that exceeded the budget and is no larger than this one, if any."""
    return next((b for b in blocks if units >= b[0] and tasks >= b[1]), None)


def _mark_copies(records: Sequence[ScaleRecord]) -> None:
    """``same_plan_as`` within one cell: the first strategy (in order) with this very plan."""
    first: dict[tuple[str, str], str] = {}
    for r in records:
        if not r.plan_digest:
            continue
        owner = first.setdefault((r.objective, r.plan_digest), r.strategy)
        r.same_plan_as = owner if owner != r.strategy else None


def _relative(records: Sequence[ScaleRecord]) -> None:
    for objective in {r.objective for r in records}:
        ran = [
            r
            for r in records
            if r.objective == objective
            and r.status in (OK, OVER_BUDGET)
            and r.objective_value is not None
            and r.unassigned is not None
        ]
        if not ran:
            continue
        fewest = min(r.unassigned for r in ran if r.unassigned is not None)
        comparable = [r for r in ran if r.unassigned == fewest]
        if len(comparable) < 2:
            continue  # nothing to compare with: not "best" by default
        best = min(r.objective_value for r in comparable if r.objective_value is not None)
        for r in comparable:
            assert r.objective_value is not None
            r.relative_to_best = r.objective_value / best if best > 0 else 1.0


# --------------------------------------------------------------------------- output


def write_scale_csv(records: Sequence[ScaleRecord], path: str | Path) -> Path:
    return write_rows_csv(SCALE_FIELDS, (r.to_dict() for r in records), path)


def scale_plot(
    records: Sequence[ScaleRecord], path: str | Path, *, budget: float | None = None
) -> Path:
    """Two panels over the number of tasks (log x): wall time per plan (log-log), and objective
    relative to the best strategy on the same cell. Colour: strategy; marker: number of units.
    Over-budget runs are ringed in red (on the budget line when they were stopped there);
    skipped cells are an x on the budget line."""
    import matplotlib

    from delegation.bench.plots import new_figure, save_png

    fig = new_figure(12.0, 5.0)
    ax_time, ax_rel = fig.subplots(1, 2)
    cmap = matplotlib.colormaps["tab10"]
    strategies = list(dict.fromkeys(r.strategy for r in records))
    objectives = list(dict.fromkeys(r.objective for r in records))
    unit_counts = sorted({r.units for r in records})
    markers = dict(zip(unit_counts, "osD^vP*Xph", strict=False))
    for si, strategy in enumerate(strategies):
        for oi, objective in enumerate(objectives):
            for n_units in unit_counts:
                mine = sorted(
                    (r for r in records if r.strategy == strategy and r.objective == objective
                     and r.units == n_units),
                    key=lambda r: r.tasks,
                )
                look = {"ls": _STYLES[oi % len(_STYLES)], "marker": markers.get(n_units, "o"),
                        "color": cmap(si % 10)}
                _plot_cell_series(ax_time, ax_rel, mine, look, budget)
    handles = _legend_handles(cmap, strategies, objectives, unit_counts, markers)
    _style_time_axis(ax_time, records, handles, budget)
    _style_relative_axis(ax_rel, records, handles)
    fig.tight_layout()
    return save_png(fig, path)


_STYLES = ["-", "--", ":", "-."]


def _plot_cell_series(ax_time: Any, ax_rel: Any, mine: Sequence[ScaleRecord],
                      look: dict[str, Any], budget: float | None) -> None:
    """One strategy x objective x unit count: its times (with over-budget rings and skipped
    crosses) and its relative objective (with squares around copied plans)."""
    ls, marker, colour = look["ls"], look["marker"], look["color"]
    ran = [r for r in mine if r.wall_time is not None]
    ax_time.plot([r.tasks for r in ran], [r.wall_time for r in ran], ls, marker=marker, ms=5,
                 color=colour, alpha=0.85)
    over = [r for r in mine if r.status == OVER_BUDGET]
    ax_time.plot([r.tasks for r in over],
                 [r.wall_time if r.wall_time is not None else budget for r in over],
                 "o", ms=12, mfc="none", mec="red")
    skipped = [r for r in mine if r.status == SKIPPED]
    if skipped and budget:
        ax_time.plot([r.tasks for r in skipped], [budget] * len(skipped), "x", color=colour,
                     ms=7)
    copied = [r for r in mine if r.same_plan_as and r.relative_to_best is not None]
    ax_rel.plot([r.tasks for r in copied], [r.relative_to_best for r in copied], "s", ms=11,
                mfc="none", mec="black")
    rel = [r for r in mine if r.relative_to_best is not None]
    ax_rel.plot([r.tasks for r in rel], [r.relative_to_best for r in rel], ls, marker=marker,
                ms=5, color=colour, alpha=0.85)


def _legend_handles(cmap: Any, strategies: Sequence[str], objectives: Sequence[str],
                    unit_counts: Sequence[int], markers: dict[int, str]) -> list[Any]:
    """A legend entry per strategy (colour), objective (line style) and unit count (marker)."""
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], color=cmap(i % 10), lw=2, label=s) for i, s in enumerate(strategies)]
    if len(objectives) > 1:
        handles += [
            Line2D([], [], color="grey", ls=_STYLES[i % len(_STYLES)], label=o)
            for i, o in enumerate(objectives)
        ]
    handles += [
        Line2D([], [], color="grey", ls="", marker=markers.get(u, "o"), label=f"{u} units")
        for u in unit_counts
    ]
    return handles


def _style_time_axis(ax: Any, records: Sequence[ScaleRecord], handles: list[Any],
                     budget: float | None) -> None:
    from matplotlib.lines import Line2D

    time_handles = list(handles)
    if budget:
        ax.axhline(budget, color="red", lw=0.8, ls="--")
        time_handles += [
            Line2D([], [], color="red", ls="--", lw=0.8, label=f"budget {budget:g} s"),
            Line2D([], [], color="red", ls="", marker="o", mfc="none", ms=10, label="over budget"),
            Line2D([], [], color="grey", ls="", marker="x", label="skipped"),
        ]
    ax.set_xscale("log")
    times = [r.wall_time for r in records if r.wall_time is not None] + ([budget] if budget else [])
    if times and min(times) > 0:
        ax.set_ylim(min(times) / 2.0, max(times) * 2.0)
    ax.set_yscale("log")
    ax.set_xlabel("tasks")
    ax.set_ylabel("wall time per plan (s)")
    ax.set_title("planning time", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(handles=time_handles, fontsize=7, loc="upper left", ncol=2)


def _style_relative_axis(ax: Any, records: Sequence[ScaleRecord], handles: list[Any]) -> None:
    from matplotlib.lines import Line2D

    ax.set_xscale("log")
    values = [r.relative_to_best for r in records if r.relative_to_best is not None]
    if values and max(values) / max(min(values), 1e-9) > 10:
        ax.set_yscale("log")
    ax.axhline(1.0, color="black", lw=0.8)
    ax.set_xlabel("tasks")
    ax.set_ylabel("objective / best strategy's on the same scenario")
    ax.set_title("plan quality (1 = best; plans with the fewest unassigned)", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    rel_handles = [*handles, Line2D([], [], color="black", ls="", marker="s", mfc="none", ms=9,
                                    label="returned an earlier strategy's plan")]
    ax.legend(handles=rel_handles, fontsize=7, loc="upper left")


def _strictly_best(records: Sequence[ScaleRecord], record: ScaleRecord) -> bool:
    """True when ``record`` beat every other strategy on its cell (same objective); a plan that
    was another strategy's is not its own, so it neither wins nor ties."""
    if record.same_plan_as or record.relative_to_best is None:
        return False
    if record.relative_to_best > 1.0 + 1e-9:
        return False
    rivals = [
        r
        for r in records
        if (r.units, r.tasks, r.objective) == (record.units, record.tasks, record.objective)
        and r is not record
        and r.relative_to_best is not None
        and not r.same_plan_as
    ]
    return bool(rivals) and all(
        r.relative_to_best is not None and r.relative_to_best > 1.0 + 1e-9 for r in rivals
    )


def summary_rows(records: Sequence[ScaleRecord]) -> list[dict[str, Any]]:
    """Per strategy x objective: the largest cell it ran within budget, and where it stopped."""
    rows = []
    keys = list(dict.fromkeys((r.strategy, r.objective) for r in records))
    for strategy, objective in keys:
        mine = [r for r in records if r.strategy == strategy and r.objective == objective]
        ok = [r for r in mine if r.status == OK]
        largest = max(ok, key=lambda r: (r.size, r.units), default=None)
        over = [r for r in mine if r.status == OVER_BUDGET]
        rel = [r.relative_to_best for r in ok if r.relative_to_best is not None]
        rows.append(
            {
                "strategy": strategy,
                "objective": objective,
                "largest_within_budget": f"{largest.units}x{largest.tasks}" if largest else "",
                "largest_time": largest.wall_time if largest else None,
                "exceeded_at": ", ".join(f"{r.units}x{r.tasks}" for r in over),
                "skipped": sum(r.status == SKIPPED for r in mine),
                "failed": sum(r.status == FAILED for r in mine),
                "median_relative": float(np.median(rel)) if rel else None,
                "compared": len(rel),
                "strictly_best": sum(_strictly_best(records, r) for r in ok),
                "copied": sum(1 for r in mine if r.same_plan_as),
            }
        )
    return rows
