"""The scale sweep: every cell reported, budget stops a strategy, CSV and PNG written."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

from delegation.bench.generate import GeneratorOptions
from delegation.bench.scale import (
    OK,
    OVER_BUDGET,
    SKIPPED,
    grid,
    run_scale,
    scale_plot,
    summary_rows,
    write_scale_csv,
)
from delegation.errors import InputError

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
UNITS, TASKS = (1, 2), (2, 4)


def test_grid_runs_small_to_large() -> None:
    cells = grid([5, 1], [10, 2])
    assert cells == [(1, 2), (1, 10), (5, 2), (5, 10)]  # by size, then units
    with pytest.raises(InputError):
        grid([0], [1])


@pytest.mark.slow  # a whole scale sweep
def test_generous_budget_runs_every_cell(tmp_path: Path) -> None:
    records = run_scale(
        ["nearest", "auction"],
        units=UNITS,
        tasks=TASKS,
        budget=120.0,
        time_limit=0.5,
        generator=GeneratorOptions(seed=3),
    )
    assert len(records) == len(grid(UNITS, TASKS)) * 2
    assert all(r.status == OK for r in records)
    assert all(r.problems == [] for r in records)
    for cell in grid(UNITS, TASKS):
        mine = [r for r in records if (r.units, r.tasks) == cell]
        rel = [r.relative_to_best for r in mine if r.relative_to_best is not None]
        assert rel and min(rel) == pytest.approx(1.0)
        assert all(v >= 1.0 - 1e-9 for v in rel)

    csv_path = write_scale_csv(records, tmp_path / "scale.csv")
    with csv_path.open() as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == len(records)
    assert [float(r["wall_time"]) for r in rows] == [r.wall_time for r in records]
    assert [int(r["size"]) for r in rows] == [r.units * r.tasks for r in records]

    png = scale_plot(records, tmp_path / "scale.png", budget=120.0)
    assert png.read_bytes()[:8] == PNG_SIGNATURE
    import matplotlib.image

    assert matplotlib.image.imread(png).shape[0] > 100


@pytest.mark.slow  # a scale sweep, per isolation
@pytest.mark.parametrize("isolate", [True, False])
def test_a_strategy_over_budget_skips_larger_sizes_and_says_so(
    tmp_path: Path, isolate: bool
) -> None:
    # Any plan takes longer than a nanosecond: the first cell exceeds, every later one is skipped.
    records = run_scale(
        ["nearest"], units=UNITS, tasks=TASKS, budget=1e-9, time_limit=0.5, isolate=isolate
    )
    cells = grid(UNITS, TASKS)
    assert [(r.units, r.tasks) for r in records] == cells
    assert records[0].status == OVER_BUDGET
    assert "budget" in records[0].note
    for r in records[1:]:
        assert r.status == SKIPPED
        assert r.wall_time is None
        assert "1x2" in r.note and "budget" in r.note
    (row,) = summary_rows(records)
    assert row["exceeded_at"] == "1x2"
    assert row["skipped"] == len(cells) - 1
    png = scale_plot(records, tmp_path / "scale.png", budget=1e-9)
    assert png.read_bytes()[:8] == PNG_SIGNATURE


def test_only_cells_at_least_as_large_in_both_dimensions_are_skipped() -> None:
    from delegation.bench.scale import _blocker

    blocks = [(5, 200)]
    assert _blocker(blocks, 5, 1000) == (5, 200)
    assert _blocker(blocks, 200, 200) == (5, 200)
    assert _blocker(blocks, 200, 50) is None  # more units but fewer tasks: still runs
    assert _blocker(blocks, 1, 1000) is None
    assert _blocker([(5, 200), (50, 10)], 200, 50) == (50, 10)
