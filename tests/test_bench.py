"""The bench runner, its files and table, and its plots, on tiny generated scenarios."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest

from delegation.bench.generate import generate_scenario, save_scenarios
from delegation.bench.report import (
    TERMINAL_COLUMNS,
    Column,
    markdown_columns,
    markdown_table,
    read_csv,
    results_tables,
    table_rows,
    write_csv,
    write_json,
)
from delegation.bench.runner import (
    RECORD_FIELDS,
    BenchResult,
    load_scenarios,
    run_bench,
    scenarios_from_dicts,
)
from delegation.errors import InputError

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
TIME_LIMIT = 0.5


@pytest.fixture(scope="module")
def result() -> BenchResult:
    """Two tiny scenarios, every strategy x objective, two repeats (one shared run per module)."""
    data = [
        generate_scenario(seed=1, units=3, tasks=6),
        generate_scenario(seed=2, units=2, tasks=5, homes=True, structure="seq"),
    ]
    return run_bench(scenarios_from_dicts(data), repeat=2, time_limit=TIME_LIMIT)


def test_every_combination_is_reported(result: BenchResult) -> None:
    from delegation.allocation import OBJECTIVES, STRATEGIES

    assert not result.failures
    assert len(result.records) == 2 * len(STRATEGIES) * len(OBJECTIVES) * 2
    seen = {(r.scenario, r.strategy, r.objective, r.repeat) for r in result.records}
    assert len(seen) == len(result.records)
    for r in result.records:
        expected = r.makespan if r.objective == "makespan" else r.total_time
        assert r.objective_value == expected
        assert r.assigned + r.unassigned == r.tasks
        assert r.solve_time >= 0 and r.wall_time >= 0
        if r.strategy == "nearest":
            assert r.ratio_to_baseline == 1.0


def test_every_reported_plan_passes_the_invariant_checks(result: BenchResult) -> None:
    from delegation.allocation import check_invariants

    assert all(r.problems == [] for r in result.records)
    assert len(result.plans) == 2 * 3 * 2
    for (source, _strategy, _objective), plan in result.plans.items():
        scenario, units = result.scenarios[source]
        assert check_invariants(plan, scenario.tree(), units) == []


@pytest.mark.slow  # bench runs
def test_ratio_compares_with_nearest_on_the_same_scenario(result: BenchResult) -> None:
    by_key = {(r.source, r.strategy, r.objective, r.repeat): r for r in result.records}
    for r in result.records:
        base = by_key[(r.source, "nearest", r.objective, r.repeat)]
        if r.unassigned == base.unassigned:
            assert r.ratio_to_baseline == pytest.approx(r.objective_value / base.objective_value)
        else:
            assert r.ratio_to_baseline is None


def _number(text: str) -> float:
    return float(text.replace(",", "").rstrip("%"))


@pytest.mark.slow  # bench runs
def test_csv_json_and_table_carry_the_same_numbers(result: BenchResult, tmp_path: Path) -> None:
    records = result.records
    csv_rows = read_csv(write_csv(records, tmp_path / "results.csv"))
    data = json.loads(write_json(records, tmp_path / "results.json").read_text())
    assert len(csv_rows) == len(data["records"]) == len(records)
    for row, obj, record in zip(csv_rows, data["records"], records, strict=True):
        assert list(obj) == list(RECORD_FIELDS)
        assert row == obj == record.to_dict()

    # The terminal tables (one per scenario) of single runs, rendered from the same records, show
    # these values (with repeats they show the statistics over them: test_bench_stats.py).
    single = [r for r in records if r.repeat == 1]
    tables = results_tables(single)
    assert len(tables) == len({r.source for r in records})
    rendered: list[list[str]] = []
    for table in tables:
        columns = [[str(c) for c in column.cells] for column in table.columns]
        rendered += [list(row) for row in zip(*columns, strict=True)]
    headers = [column.header for column in tables[0].columns]
    shown = [c for c in TERMINAL_COLUMNS if c.header in headers]
    assert [c.header for c in shown] == headers
    assert "run" not in headers and "checks" not in headers  # one run each; every check passed
    assert rendered == table_rows(single, shown)
    _same_values(shown, rendered, [row for row in csv_rows if row["repeat"] == 1])
    for table, source in zip(tables, dict.fromkeys(r.source for r in records), strict=True):
        first = next(r for r in records if r.source == source)
        assert first.scenario in str(table.title) and f"{first.units} units" in str(table.title)

    # The markdown table (docs) shows them too.
    md_columns = markdown_columns(records)
    md = markdown_table(records, md_columns).splitlines()
    assert len(md) == 2 + len(records)
    md_rows = [[c.strip() for c in line.strip("|").split(" | ")] for line in md[2:]]
    assert md_rows == table_rows(records, md_columns)
    _same_values(md_columns, md_rows, csv_rows)


def _same_values(columns: Sequence[Column], rows: list[list[str]], csv_rows: list[dict]) -> None:
    """Each cell shows the CSV's value, to the digits the cell has."""
    assert len(rows) == len(csv_rows)
    for row, csv_row in zip(rows, csv_rows, strict=True):
        for column, cell in zip(columns, row, strict=True):
            if column.field == "label":  # the strategy, and whose plan it returned if not its own
                same = csv_row["same_plan_as"]
                assert cell == csv_row["strategy"] + (f" (= {same})" if same else "")
                continue
            value = csv_row[column.field]
            if column.field == "problems":
                assert cell == ("ok" if not value else f"{len(value)} violated")
            elif value is None:
                assert cell == "-"
            elif isinstance(value, str):
                assert cell == value
            else:
                number = _number(cell)
                if column.field == "gap":
                    value = 100.0 * value
                digits = len(cell.rstrip("%").split(".")[1]) if "." in cell else 0
                assert number == pytest.approx(value, abs=0.51 * 10.0**-digits)


@pytest.mark.slow
def test_plots_are_valid_pngs(result: BenchResult, tmp_path: Path) -> None:
    import matplotlib.image
    from PIL import Image

    from delegation.bench.plots import write_plots

    # The makespan plans only: the total-time ones are drawn by the same code (the full set was
    # 26 PNGs, 24 s of matplotlib on a loaded machine; these are 14).
    makespan = {key: plan for key, plan in result.plans.items() if key[2] == "makespan"}
    paths = write_plots(dataclasses.replace(result, plans=makespan), tmp_path)
    names = {p.name for p in paths}
    scenarios = {r.scenario for r in result.records}
    expected = {f"{name}-objective.png" for name in scenarios} | {
        f"{name}-{strategy}-makespan-{kind}.png" for name in scenarios
        for strategy in ("nearest", "auction", "optimal") for kind in ("map", "gantt")}
    assert names == expected
    for path in paths:
        assert path.read_bytes()[:8] == PNG_SIGNATURE
        with Image.open(path) as image:
            image.verify()
        pixels = matplotlib.image.imread(path)
        assert pixels.ndim == 3 and pixels.shape[0] > 100 and pixels.shape[1] > 100
        assert float(np.std(pixels)) > 0.0  # not a blank image


def test_bad_scenario_in_a_folder_is_named_and_the_others_run(tmp_path: Path) -> None:
    folder = tmp_path / "scenarios"
    save_scenarios([generate_scenario(seed=4, units=2, tasks=3)], folder)
    (folder / "broken-yaml.yaml").write_text("name: [unclosed\n", encoding="utf-8")
    bad = generate_scenario(seed=5, units=2, tasks=3)
    bad["mission"]["children"][0]["name"] = "teleport"
    (folder / "unknown-task.json").write_text(json.dumps(bad), encoding="utf-8")

    loaded, failures = load_scenarios([folder, tmp_path / "missing.yaml"])
    failed = {Path(f.source).name: f.message for f in failures}
    assert [Path(s.source).name for s in loaded if s.source.endswith("s4.yaml")]
    assert "broken-yaml.yaml" in failed
    assert "missing.yaml" in failed and "no such file" in failed["missing.yaml"]
    # The unknown task is found when the file loads, or at the latest when it is planned.
    result = run_bench(loaded, strategies=["nearest"], objectives=["makespan"])
    failed.update({Path(f.source).name: f.message for f in result.failures})
    assert "teleport" in failed["unknown-task.json"]
    assert {r.scenario for r in result.records} == {"gen-granso-u2-t3-s4"}


def test_unknown_strategy_or_objective_is_an_input_error() -> None:
    scenarios = scenarios_from_dicts([generate_scenario(seed=0, units=1, tasks=1)])
    with pytest.raises(InputError, match="greedy"):
        run_bench(scenarios, strategies=["greedy"])
    with pytest.raises(InputError, match="cheapest"):
        run_bench(scenarios, objectives=["cheapest"])
    with pytest.raises(InputError, match="repeat"):
        run_bench(scenarios, repeat=0)


def _abort() -> None:
    import faulthandler
    import os

    faulthandler.disable()  # in this child only: a real native abort, without pytest's dump
    os.abort()


def _wait(seconds: float) -> str:
    import threading

    threading.Event().wait(seconds)
    return "late"


def _reject() -> None:
    raise InputError("no such unit")


def test_isolated_runs_survive_crashes_and_are_stopped_at_their_deadline() -> None:
    from delegation.bench.isolate import call_isolated

    assert call_isolated(_wait, {"seconds": 0.0}).value == "late"
    crashed = call_isolated(_abort, {})
    assert not crashed.ok and "SIGABRT" in str(crashed.crashed)
    late = call_isolated(_wait, {"seconds": 30.0}, timeout=0.2)
    assert late.timed_out and late.value is None
    rejected = call_isolated(_reject, {})
    assert rejected.input_error is not None and "no such unit" in rejected.input_error


def test_isolated_bench_gives_the_same_plans(result: BenchResult) -> None:
    data = [generate_scenario(seed=1, units=3, tasks=6)]
    isolated = run_bench(
        scenarios_from_dicts(data), strategies=["nearest", "auction"], isolate=True, run_timeout=120
    )
    assert not isolated.failures
    key = ("strategy", "objective", "makespan", "total_time", "total_distance", "unassigned")
    mine = [tuple(getattr(r, k) for k in key) for r in isolated.records]
    theirs = [
        tuple(getattr(r, k) for k in key)
        for r in result.records
        if r.scenario == data[0]["name"] and r.repeat == 1 and r.strategy != "optimal"
    ]
    assert mine == theirs
    assert set(isolated.plans) == {
        (f"generated:{data[0]['name']}", s, o)
        for s in ("nearest", "auction")
        for o in ("makespan", "total")
    }


def test_a_run_past_its_timeout_is_a_named_failure_and_the_rest_go_on() -> None:
    from delegation.allocation import STRATEGIES

    # A run that never answers, not a quick one given 1 us: the timeout starts once the child
    # is started, and on a loaded machine a 3-task run could answer before its parent looked.
    stuck = "bench_crash_strategy:stuck"
    data = [
        generate_scenario(seed=1, units=2, tasks=3),
        generate_scenario(seed=2, units=2, tasks=3),
    ]
    try:
        result = run_bench(
            scenarios_from_dicts(data),
            strategies=[stuck],
            objectives=["makespan"],
            isolate=True,
            run_timeout=0.3,
        )
    finally:
        STRATEGIES.unregister(stuck)  # registered in this process by the spec
    assert result.records == []
    assert [f.source for f in result.failures] == [f"generated:{d['name']}" for d in data]
    assert all(f"{stuck}/makespan run 1: stopped after" in f.message for f in result.failures)
