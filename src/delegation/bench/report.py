"""Results as files and as a table, all made from the same ``RunRecord``s.

The CSV and JSON carry every record field at full precision; the table shows the same values
through ``COLUMNS``' formatters (``format_cell``), so a cell can always be checked against the
files. Building a ``rich`` table prints nothing: the CLI prints it.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from rich.table import Table

from delegation.bench.runner import RECORD_FIELDS, BenchResult, RunRecord, ScenarioFailure
from delegation.bench.summary import Aggregate, StrategySummary, aggregate

#: Cell text for a value that is not known (no bound, no baseline).
MISSING = "-"


def _fixed(digits: int) -> Callable[[Any], str]:
    def fmt(value: Any) -> str:
        if value is None or (isinstance(value, float) and not math.isfinite(value)):
            return MISSING
        return f"{float(value):,.{digits}f}"

    return fmt


def _int(value: Any) -> str:
    return MISSING if value is None else str(int(value))


def _percent(value: Any) -> str:
    return MISSING if value is None else f"{100.0 * float(value):.1f}%"


def _ratio(value: Any) -> str:
    return MISSING if value is None else f"{float(value):.3f}"


def _text(value: Any) -> str:
    return str(value)


def _problems(value: Any) -> str:
    return "ok" if not value else f"{len(value)} violated"


@dataclass(frozen=True, slots=True)
class Column:
    """One table column: the record field it shows, its header and how a value is written."""

    field: str
    header: str
    fmt: Callable[[Any], str]
    numeric: bool = True


#: The table's columns, in order.
COLUMNS: tuple[Column, ...] = (
    Column("scenario", "scenario", _text, numeric=False),
    Column("objective", "objective", _text, numeric=False),
    Column("label", "strategy", _text, numeric=False),
    Column("repeat", "run", _int),
    Column("units", "units", _int),
    Column("tasks", "tasks", _int),
    Column("makespan", "makespan s", _fixed(1)),
    Column("total_time", "total time s", _fixed(1)),
    Column("total_distance", "distance m", _fixed(0)),
    Column("solve_time", "solve s", _fixed(3)),
    Column("unassigned", "unassigned", _int),
    Column("bound", "bound", _fixed(1)),
    Column("gap", "gap", _percent),
    Column("search_bound", "search bound", _fixed(1)),
    Column("vs_search_bound", "vs search bound", _ratio),
    Column("ratio_to_baseline", "vs baseline", _ratio),
    Column("best_known", "best known", _fixed(1)),
    Column("gap_to_best_known", "vs best known", _percent),
    Column("problems", "checks", _problems, numeric=False),
)


def format_cell(column: Column, record: Any) -> str:
    """The text a record shows in a column."""
    return column.fmt(getattr(record, column.field))


def table_rows(
    records: Sequence[Any], columns: Sequence[Column] = COLUMNS
) -> list[list[str]]:
    """The table's cells, one row per record, in record order."""
    return [[format_cell(c, r) for c in columns] for r in records]


#: Per-scenario terminal tables: scenario, units and tasks go in the title; short headers so a
#: table fits an 80-column terminal. The same columns as ``COLUMNS`` (one formatter each).
_TERMINAL_HEADERS: dict[str, str] = {
    "objective": "objective", "label": "strategy", "repeat": "run", "makespan": "makespan",
    "total_time": "total", "total_distance": "dist m", "solve_time": "solve s",
    "unassigned": "unasg", "bound": "bound", "gap": "gap", "ratio_to_baseline": "ratio",
    "gap_to_best_known": "vs best", "problems": "checks", "search_bound": "srch bound",
    "vs_search_bound": "vs srch",
}  # fmt: skip
TERMINAL_COLUMNS: tuple[Column, ...] = tuple(
    replace(c, header=_TERMINAL_HEADERS[c.field]) for c in COLUMNS if c.field in _TERMINAL_HEADERS
)

_TERMINAL = {c.field: c for c in TERMINAL_COLUMNS}

#: The same per scenario when runs are repeated: the objective's statistics over the repeats
#: (the columns a run has too are the terminal table's, so the two tables read alike).
AGGREGATE_COLUMNS: tuple[Column, ...] = (
    _TERMINAL["objective"],
    _TERMINAL["label"],
    Column("runs", "n", _int),
    Column("mean", "mean", _fixed(1)),
    Column("median", "median", _fixed(1)),
    Column("std", "std", _fixed(1)),
    Column("ci95", "95% CI", _text),
    Column("span", "min-max", _text),
    Column("solve_time_mean", "solve s", _fixed(3)),
    _TERMINAL["unassigned"],
    _TERMINAL["bound"],
    _TERMINAL["ratio_to_baseline"],
    _TERMINAL["gap_to_best_known"],
)


def table_note(baseline: str) -> str:
    return (
        "makespan, total (travel + work of all units) and solve in seconds; unasg: tasks "
        "unassigned; bound/gap: proven by CP-SAT; ratio: the objective / "
        f"{baseline}'s on the same scenario (geometric mean over repeats); vs best: gap to the "
        "best known value of a standard instance; srch bound: the largest shared search's lower "
        "bound (DESIGN 3.11, s), vs srch: makespan / it; mean/median/std over repeats, 95% CI: the "
        "mean's Student-t interval; 'a (= b)': a returned b's plan; -: unknown"
    )


TABLE_NOTE = table_note("nearest")


def _useful(columns: Sequence[Column], records: Sequence[RunRecord]) -> tuple[Column, ...]:
    """``columns`` without those that say nothing here (one run each; every check ok)."""
    drop = set()
    if all(r.repeat == 1 for r in records):
        drop.add("repeat")
    if not any(r.problems for r in records):
        drop.add("problems")
    for name in ("best_known", "gap_to_best_known", "bound", "search_bound", "vs_search_bound"):
        if all(getattr(r, name) is None for r in records):
            drop.add(name)
    return tuple(c for c in columns if c.field not in drop)


def compact_table(title: str) -> Table:
    """A ``rich`` table for the terminal: no edge or padding, bold headers (bench's tables)."""
    from rich import box

    return Table(
        title=title,
        title_justify="left",
        box=box.SIMPLE_HEAD,
        show_edge=False,
        padding=(0, 0),
        pad_edge=False,
        header_style="bold",
    )


class _AggregateRow:
    """An ``Aggregate`` with the CI and min-max as one cell each (for the tables)."""

    def __init__(self, agg: Aggregate) -> None:
        self._agg = agg
        self.ci95 = (MISSING if agg.ci95_low is None or agg.ci95_high is None
                     else f"{agg.ci95_low:,.1f}..{agg.ci95_high:,.1f}")
        self.span = f"{agg.min:,.1f}..{agg.max:,.1f}"

    def __getattr__(self, name: str) -> Any:
        return getattr(self._agg, name)


def aggregate_rows(records: Sequence[RunRecord]) -> list[Any]:
    """The aggregates of ``records`` as rows for ``AGGREGATE_COLUMNS``."""
    return [_AggregateRow(a) for a in aggregate(records)]


def results_tables(records: Sequence[RunRecord]) -> list[Table]:
    """One compact ``rich`` table per scenario (numbers right-aligned, never cut): every run,
    or with repeats the statistics over them."""
    repeated = any(r.repeat > 1 for r in records)
    columns = _useful(AGGREGATE_COLUMNS if repeated else TERMINAL_COLUMNS, records)
    tables: list[Table] = []
    for source in dict.fromkeys(r.source for r in records):
        first = next(r for r in records if r.source == source)
        mine: Sequence[Any] = [r for r in records if r.source == source]
        if repeated:
            mine = aggregate_rows(mine)
        table = compact_table(
            f"[bold]{first.scenario}[/bold]: {first.units} units, {first.tasks} tasks"
        )
        rows = table_rows(mine, columns)
        for i, column in enumerate(columns):
            # Values are never folded or cut (headers may wrap on a narrow terminal).
            table.add_column(
                column.header,
                justify="right" if column.numeric else "left",
                overflow="fold",
                min_width=max(len(row[i]) for row in rows),
            )
        previous = None
        for record, row in zip(mine, rows, strict=True):
            if previous is not None and previous != record.objective:
                table.add_section()
            table.add_row(*row)
            previous = record.objective
        tables.append(table)
    return tables


def markdown_columns(records: Sequence[RunRecord]) -> tuple[Column, ...]:
    """The full table's columns without those that say nothing here."""
    return _useful(COLUMNS, records)


def markdown_table(records: Sequence[Any], columns: Sequence[Column] = COLUMNS) -> str:
    """The same cells as a GitHub markdown table (for ``docs/results.md``)."""
    head = "| " + " | ".join(c.header for c in columns) + " |"
    rule = "|" + "|".join("---:" if c.numeric else "---" for c in columns) + "|"
    body = ["| " + " | ".join(format_cell(c, r) for c in columns) + " |" for r in records]
    return "\n".join([head, rule, *body])


# --------------------------------------------------------------------------- files


def _csv_value(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, list):
        return " | ".join(str(v) for v in value)
    return repr(value) if isinstance(value, float) else str(value)


def write_rows_csv(
    fields: Sequence[str], rows: Iterable[Mapping[str, Any]], path: str | Path
) -> Path:
    """A header of ``fields``, then one line per row (the results and the scale sweep share it)."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    with out.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(fields)
        for row in rows:
            writer.writerow([_csv_value(row[f]) for f in fields])
    return out


def write_csv(records: Sequence[RunRecord], path: str | Path) -> Path:
    """One row per record, every field, floats at full precision (empty cell: unknown)."""
    return write_rows_csv(RECORD_FIELDS, (r.to_dict() for r in records), path)


def read_csv(path: str | Path) -> list[dict[str, Any]]:
    """Read ``results.csv`` back into typed values (the inverse of ``write_csv``)."""
    types = {f.name: f.type for f in RunRecord.__dataclass_fields__.values()}
    rows: list[dict[str, Any]] = []
    with Path(path).open(newline="", encoding="utf-8") as handle:
        for raw in csv.DictReader(handle):
            row: dict[str, Any] = {}
            for name, text in raw.items():
                kind = str(types[name])
                if name in ("problems", "notes"):
                    row[name] = [p for p in text.split(" | ") if p] if text else []
                elif text == "":
                    row[name] = None
                elif kind == "bool":
                    row[name] = text == "true"
                elif kind == "int":
                    row[name] = int(text)
                elif "float" in kind:
                    row[name] = float(text)
                else:
                    row[name] = text
            rows.append(row)
    return rows


def write_json(
    records: Sequence[RunRecord],
    path: str | Path,
    *,
    failures: Sequence[ScenarioFailure] = (),
    meta: Mapping[str, Any] | None = None,
    extra: Mapping[str, Any] | None = None,
) -> Path:
    """``{"meta": ..., "records": [...], "failures": [...], **extra}`` with the records' fields
    as keys."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    data = {
        "meta": dict(meta or {}),
        "records": [r.to_dict() for r in records],
        "failures": [{"source": f.source, "message": f.message} for f in failures],
        **dict(extra or {}),
    }
    out.write_text(json.dumps(data, indent=2, allow_nan=False) + "\n", encoding="utf-8")
    return out


# --------------------------------------------------------------------------- summary


SUMMARY_NOTE = (
    "ratio: geometric mean over scenarios of the mean objective / the baseline's (where both "
    "left the same tasks unassigned); wins: scenarios where it alone was best (fewest "
    "unassigned, then lowest mean); ties: best together with another; copied: scenarios where "
    "its plan was another strategy's (never a win); failed: runs that crashed or timed out"
)


def _summary_cells(row: StrategySummary) -> list[str]:
    return [
        row.objective, row.strategy, str(row.scenarios),
        MISSING if row.geomean_ratio is None else f"{row.geomean_ratio:.3f} ({row.compared})",
        str(row.wins), str(row.ties), str(row.same_plan), str(row.infeasible),
        str(row.failed_runs),
    ]


_SUMMARY_HEADERS = ("objective", "strategy", "scenarios", "ratio (n)", "wins", "ties", "copied",
                    "infeasible", "failed")


def summary_table(rows: Sequence[StrategySummary]) -> Table:
    """Strategies across scenarios, against the baseline (always printed)."""
    baseline = rows[0].baseline if rows else "-"
    table = compact_table(f"[bold]Across scenarios[/bold] (baseline: {baseline})")
    cells = [_summary_cells(r) for r in rows]
    for i, header in enumerate(_SUMMARY_HEADERS):
        table.add_column(header, justify="left" if i < 2 else "right",
                         min_width=max((len(c[i]) for c in cells), default=0))
    for row in cells:
        table.add_row(*row)
    return table


def summary_markdown(rows: Sequence[StrategySummary]) -> str:
    head = "| " + " | ".join(_SUMMARY_HEADERS) + " |"
    rule = "|---|---|" + "---:|" * (len(_SUMMARY_HEADERS) - 2)
    body = ["| " + " | ".join(_summary_cells(r)) + " |" for r in rows]
    return "\n".join([head, rule, *body])


# --------------------------------------------------------------------------- all outputs


def write_outputs(
    result: BenchResult,
    out: str | Path,
    *,
    meta: Mapping[str, Any],
    plots: bool = True,
    maps: bool = True,
    gantt: bool = True,
    max_map_tasks: int = 150,
) -> list[Path]:
    """results.csv/json (every run), aggregates.csv, summary.csv, results.md and the PNGs.

    Writes nothing when there is no record (an empty result file reads as a result)."""
    from delegation.bench.summary import AGGREGATE_FIELDS, SUMMARY_FIELDS, summarise

    if not result.records:
        return []
    folder = Path(out)
    aggregates = aggregate(result.records)
    summary = summarise(result)
    written = [
        write_csv(result.records, folder / "results.csv"),
        write_rows_csv(AGGREGATE_FIELDS, (a.to_dict() for a in aggregates),
                       folder / "aggregates.csv"),
        write_rows_csv(SUMMARY_FIELDS, (s.to_dict() for s in summary), folder / "summary.csv"),
        write_json(result.records, folder / "results.json", failures=result.failures,
                   meta={**meta, "baseline": result.baseline,
                         "interrupted": result.interrupted,
                         "runs_finished": len(result.records), "runs_asked": result.total_runs},
                   extra={"aggregates": [a.to_dict() for a in aggregates],
                          "summary": [s.to_dict() for s in summary]}),
    ]
    repeated = any(r.repeat > 1 for r in result.records)
    if repeated:
        rows: Sequence[Any] = aggregate_rows(result.records)
        table_md = markdown_table(rows, _useful(AGGREGATE_COLUMNS, result.records))
    else:
        table_md = markdown_table(result.records, markdown_columns(result.records))
    md = folder / "results.md"
    md.write_text(
        ("**Interrupted: partial results.**\n\n" if result.interrupted else "")
        + table_md + "\n\n" + summary_markdown(summary) + "\n\n" + SUMMARY_NOTE + ".\n",
        encoding="utf-8",
    )
    written.append(md)
    if plots:
        from delegation.bench.plots import summary_plot, write_plots

        written += write_plots(result, folder, maps=maps, gantt=gantt,
                               max_map_tasks=max_map_tasks)
        written.append(summary_plot(summary, folder / "summary.png"))
    return written
