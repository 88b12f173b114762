"""Gantt charts: lanes per unit from a plan, waits for earlier tasks found, flown lanes from a
followed mission's feedback."""

from __future__ import annotations

from pathlib import Path

import matplotlib.image

from delegation.allocation import plan_mission
from delegation.bench.generate import generate_scenario
from delegation.render.gantt import Bar, _waits, flown_bars, plan_bars, render_gantt
from delegation.render.progress import MissionProgress
from delegation.scenario import scenario_from_dict


def _png(path: Path) -> tuple[int, int]:
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    image = matplotlib.image.imread(path)
    return image.shape[0], image.shape[1]


def test_waits_are_the_gaps_before_each_task() -> None:
    bars = [Bar("a", "move-to", 10.0, 20.0, 5.0), Bar("a", "move-to", 0.0, 4.0),
            Bar("a", "look-at-position", 30.0, 30.0)]
    assert _waits(bars) == [(4.0, 10.0)]


def test_a_sequential_mission_shows_units_waiting_for_each_other(tmp_path: Path) -> None:
    scenario = scenario_from_dict(generate_scenario(units=3, tasks=8, seed=4, structure="seq"))
    plan = plan_mission(scenario.tree(), scenario.units(), strategy="auction")
    bars = plan_bars(plan)
    assert {b.unit for b in bars} == {a.execunit.lstrip("/") for a in plan.assignments}
    units_used = {b.unit for b in bars if b.end > b.start}
    assert len(units_used) >= 2  # in a seq, a second unit waits for the first one's tasks
    assert any(_waits([b for b in bars if b.unit == u]) for u in units_used)
    assert plan_bars(plan.to_json()) == bars  # the plan's JSON gives the same chart
    height, width = _png(render_gantt(plan, tmp_path / "g.png", title="seq"))
    assert width > 800 and height > 150


def test_flown_lanes_come_from_the_missions_feedback(tmp_path: Path) -> None:
    scenario = scenario_from_dict(generate_scenario(units=2, tasks=3, seed=1))
    plan = plan_mission(scenario.tree(), scenario.units(), strategy="auction").to_json()
    progress = MissionProgress(plan, speedup=2.0)
    first, second = list(progress.rows)[:2]
    progress.on_node(progress.root_uuid, "running", 100.0)
    progress.on_node(first, "running", 100.0)
    progress.on_node(first, "succeeded", 105.0)
    progress.on_node(second, "running", 101.0)
    flown = flown_bars(progress.rows.values(), now=20.0)
    assert [(b.start, b.end) for b in flown] == [(0.0, 10.0), (2.0, 20.0)]  # x2: mission seconds
    _png(render_gantt(plan, tmp_path / "flown.png", flown=flown))
