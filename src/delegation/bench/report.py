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
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rich.table import Table

from delegation.bench.runner import RECORD_FIELDS, RunRecord, ScenarioFailure

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
    Column("strategy", "strategy", _text, numeric=False),
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
    Column("ratio_to_nearest", "vs nearest", _ratio),
    Column("problems", "checks", _problems, numeric=False),
)


def format_cell(column: Column, record: RunRecord) -> str:
    """The text a record shows in a column."""
    return column.fmt(getattr(record, column.field))


def table_rows(
    records: Sequence[RunRecord], columns: Sequence[Column] = COLUMNS
) -> list[list[str]]:
    """The table's cells, one row per record, in record order."""
    return [[format_cell(c, r) for c in columns] for r in records]


#: Per-scenario terminal tables: scenario, units and tasks go in the title; short headers so a
#: table fits an 80-column terminal.
TERMINAL_COLUMNS: tuple[Column, ...] = (
    Column("objective", "objective", _text, numeric=False),
    Column("strategy", "strategy", _text, numeric=False),
    Column("repeat", "run", _int),
    Column("makespan", "makespan", _fixed(1)),
    Column("total_time", "total", _fixed(1)),
    Column("total_distance", "dist m", _fixed(0)),
    Column("solve_time", "solve s", _fixed(3)),
    Column("unassigned", "unasg", _int),
    Column("bound", "bound", _fixed(1)),
    Column("gap", "gap", _percent),
    Column("ratio_to_nearest", "ratio", _ratio),
    Column("problems", "checks", _problems, numeric=False),
)

TABLE_NOTE = (
    "makespan, total (travel + work of all units) and solve in seconds; unasg: tasks unassigned; "
    "bound/gap: proven by CP-SAT; ratio: the objective / nearest's on the same scenario; "
    "-: unknown"
)


def _useful(columns: Sequence[Column], records: Sequence[RunRecord]) -> tuple[Column, ...]:
    """``columns`` without those that say nothing here (one run each; every check ok)."""
    drop = set()
    if all(r.repeat == 1 for r in records):
        drop.add("repeat")
    if not any(r.problems for r in records):
        drop.add("problems")
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


def results_tables(records: Sequence[RunRecord]) -> list[Table]:
    """One compact ``rich`` table per scenario (numbers right-aligned, never cut)."""
    columns = _useful(TERMINAL_COLUMNS, records)
    tables: list[Table] = []
    for source in dict.fromkeys(r.source for r in records):
        mine = [r for r in records if r.source == source]
        first = mine[0]
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


def markdown_table(records: Sequence[RunRecord], columns: Sequence[Column] = COLUMNS) -> str:
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
) -> Path:
    """``{"meta": ..., "records": [...], "failures": [...]}`` with the records' fields as keys."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    data = {
        "meta": dict(meta or {}),
        "records": [r.to_dict() for r in records],
        "failures": [{"source": f.source, "message": f.message} for f in failures],
    }
    out.write_text(json.dumps(data, indent=2, allow_nan=False) + "\n", encoding="utf-8")
    return out
