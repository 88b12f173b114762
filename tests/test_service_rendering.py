"""The progress model (fed feedback by hand) and the map renderer (on an offline plan)."""

from __future__ import annotations

from pathlib import Path

from rich.console import Console

from delegation.allocation import plan_mission
from delegation.cli.inputs import find_scenario
from delegation.render.mapplot import render_map
from delegation.render.progress import MissionProgress
from delegation.scenario import load_scenario


def _plan() -> tuple[dict, list]:
    scenario = load_scenario(find_scenario("demo"))
    units = scenario.units()
    plan = plan_mission(scenario.tree(), units, strategy="auction")
    return plan.to_json(), units


def test_progress_follows_feedback_in_mission_seconds() -> None:
    plan, _ = _plan()
    progress = MissionProgress(plan, speedup=10.0)
    assert progress.root_uuid == plan["tst"]["common_params"]["node-uuid"]
    assert len(progress.rows) == len(plan["assignments"])
    open_ended = {a["node-uuid"] for a in plan["assignments"] if a["name"] == "look-at-position"}
    assert progress.open_ended == open_ended

    progress.on_mission("started", "", 100.0)
    for uid in progress.rows:
        progress.on_node(uid, "running", 100.0)
    closed = [uid for uid in progress.rows if uid not in open_ended]
    assert progress.due_for_enough(110.0) == []  # others still running
    for i, uid in enumerate(closed):
        progress.on_node(uid, "succeeded", 101.0 + i)
    assert progress.due_for_enough(100.5) == []  # running for less than the dwell
    assert sorted(progress.due_for_enough(110.0)) == sorted(open_ended)
    last = closed[-1]
    assert progress.rows[last].ended == (101.0 + len(closed) - 1 - 100.0) * 10.0
    for uid in open_ended:
        progress.on_node(uid, "succeeded", 120.0)
    progress.on_mission("succeeded", "", 121.0)
    assert progress.done and progress.succeeded and progress.elapsed == 210.0
    summary = {u["unit"]: u for u in progress.unit_summary()}
    assert sum(u["tasks"] for u in summary.values()) == len(plan["assignments"])
    # Open-ended tasks do not make a unit's actual end.
    assert max(u["actual-end"] for u in summary.values()) == progress.rows[last].ended

    console = Console(record=True, width=100)
    console.print(progress.table())
    console.print(progress.summary_table())
    text = console.export_text()
    assert "search-area" in text and "succeeded" in text and "/dji0" in text


def test_failed_mission_keeps_its_reason() -> None:
    plan, _ = _plan()
    progress = MissionProgress(plan)
    progress.on_mission("failed", "root/children[1] failed", 5.0)
    progress.on_mission("succeeded", "", 6.0)  # nothing moves a mission after its end
    assert progress.done and not progress.succeeded
    assert progress.fail_reason == "root/children[1] failed"


def test_render_map_writes_a_png_for_a_plan_object_and_json(tmp_path: Path) -> None:
    import matplotlib.image

    scenario = load_scenario(find_scenario("demo"))
    units = scenario.units()
    plan = plan_mission(scenario.tree(), units, strategy="nearest")
    tracks = {units[0].name: [units[0].position, scenario.units()[1].position]}
    for source, name in ((plan, "a.png"), (plan.to_json(), "b.png")):
        path = render_map(source, units, tracks, tmp_path / name)
        assert path.read_bytes()[:4] == b"\x89PNG"
        image = matplotlib.image.imread(path)
        assert image.shape[0] > 300 and image.shape[1] > 300
