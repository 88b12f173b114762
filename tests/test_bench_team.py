"""The team-search family of ``delegation bench --generate`` (issue 21): valid cases, ``--no-split``
as the comparison, and the makespan over the search's lower bound in the records and tables."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest
import shapely
from shapely.geometry import Point, Polygon

from delegation.bench.generate import generate_scenario, save_scenarios
from delegation.bench.runner import run_bench, scenarios_from_dicts
from delegation.bench.team_search import DRONE_WIDTH, FRAME, team_scenario
from delegation.cli import main
from delegation.costs import search_polygons_xy
from delegation.errors import InputError
from delegation.scenario import load_scenario, scenario_from_dict
from delegation.tst import leaves


@pytest.mark.parametrize("seed", range(12))
def test_the_family_generates_valid_concave_searches_for_mixed_fleets(seed: int,
                                                                        tmp_path: Path) -> None:
    data = generate_scenario(family="team-search", seed=seed)
    assert data == team_scenario(seed)  # (the same seed, the same case)
    scenario = scenario_from_dict(data, source="generated")
    units, tree = scenario.units(), scenario.tree()
    assert 3 <= len(units) <= 6
    assert {u.agent_type for u in units} <= {"air", "surface"} and "air" in {
        u.agent_type for u in units}
    (search,) = leaves(tree)
    assert search.name == "search-area" and search.execunit == "*"
    area = Polygon(search_polygons_xy(search, FRAME)[0])
    assert area.is_valid
    assert 0.19e6 < area.area < 4.1e6
    assert area.area < 0.97 * shapely.convex_hull(area).area  # concave
    drones = [u for u in units if u.agent_type == "air"]
    if seed % 3 == 2:  # an endurance case: no drone alone, the fleet together with slack
        for u in drones:
            flight = area.distance(Point(FRAME.point_xy(u.position))) / u.speeds["standard"]
            assert u.endurance is not None
            assert u.endurance < flight + area.area / (DRONE_WIDTH * u.speeds["standard"])
        swept = [((u.endurance or 0.0) - area.distance(Point(FRAME.point_xy(u.position)))
                  / u.speeds["standard"]) * DRONE_WIDTH * u.speeds["standard"] for u in drones]
        assert sum(swept) > 1.09 * area.area
    else:
        assert all(u.endurance is None for u in units)
    (path,) = save_scenarios([data], tmp_path)
    again = load_scenario(path)
    assert [u.name for u in again.units()] == [u.name for u in units]


def test_an_unknown_family_is_named() -> None:
    with pytest.raises(InputError, match="family"):
        generate_scenario(family="teams")


def test_bench_reports_the_gap_to_the_search_bound_and_the_no_split_comparison() -> None:
    item = scenarios_from_dicts([team_scenario(1)])
    result = run_bench(item, strategies=["nearest", "auction"], objectives=["makespan"],
                       no_split=True)
    by = {r.strategy: r for r in result.records}
    assert sorted(by) == ["auction", "auction --no-split", "nearest"]
    assert not by["auction --no-split"].split and by["auction"].split
    for record in by.values():
        assert not record.problems
        assert record.search_bound and record.search_bound > 0.0
        assert record.vs_search_bound == pytest.approx(record.makespan / record.search_bound)
        assert record.vs_search_bound >= 1.0  # (a lower bound)
    assert by["auction"].vs_search_bound < by["auction --no-split"].vs_search_bound


@pytest.mark.slow
def test_the_cli_runs_a_team_case_and_writes_the_bound(tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    code = main(["bench", "--generate", "--family", "team-search", "--seed", "4",
                 "--strategies", "nearest,auction", "--objectives", "makespan", "--no-split",
                 "--in-process", "--no-maps", "--no-gantt", "--out", str(out)])
    assert code == 0
    text = capsys.readouterr().out
    assert "auction --no-split" in text and "vs srch" in text
    with (out / "results.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert [r["strategy"] for r in rows] == ["nearest", "auction", "auction --no-split"]
    assert all(float(r["vs_search_bound"]) >= 1.0 for r in rows)
    assert (out / "team-crescent-2km2-u4-s4-objective.png").is_file() or any(
        out.glob("team-*-objective.png"))
