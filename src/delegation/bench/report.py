"""Results as files and as a table, all made from the same ``RunRecord``s.

The CSV and JSON carry every record field at full precision; the table shows the same values
through ``COLUMNS``' formatters (``format_cell``), so a cell can always be checked against the
files. Building a ``rich`` table prints nothing: the CLI prints it.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Callable, Mapping, Sequence
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


def table_rows(records: Sequence[RunRecord]) -> list[list[str]]:
    """The table's cells, one row per record, in record order."""
    return [[format_cell(c, r) for c in COLUMNS] for r in records]


def results_table(
    records: Sequence[RunRecord], title: str | None = "Allocation benchmark"
) -> Table:
    """A ``rich`` table of the records (numbers right-aligned)."""
    table = Table(title=title, header_style="bold")
    for column in COLUMNS:
        # Fold rather than cut: a narrow terminal must never hide digits.
        table.add_column(
            column.header, justify="right" if column.numeric else "left", overflow="fold"
        )
    previous: tuple[str, str] | None = None
    for record, row in zip(records, table_rows(records), strict=True):
        key = (record.source, record.objective)
        table.add_row(*row, end_section=False)
        if previous is not None and previous != key and table.rows:
            # A rule between scenarios/objectives keeps groups readable.
            table.rows[-2].end_section = True
        previous = key
    return table


def markdown_columns(records: Sequence[RunRecord]) -> tuple[Column, ...]:
    """The table's columns without those that say nothing here (one run; every check ok)."""
    drop = set()
    if all(r.repeat == 1 for r in records):
        drop.add("repeat")
    if not any(r.problems for r in records):
        drop.add("problems")
    return tuple(c for c in COLUMNS if c.field not in drop)


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


def write_csv(records: Sequence[RunRecord], path: str | Path) -> Path:
    """One row per record, every field, floats at full precision (empty cell: unknown)."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    with out.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(RECORD_FIELDS)
        for record in records:
            writer.writerow([_csv_value(getattr(record, f)) for f in RECORD_FIELDS])
    return out


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
