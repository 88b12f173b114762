"""`delegation.learning`: speeds learnt per unit and class, notes on default figures, warnings."""

from __future__ import annotations

import pytest

from delegation.costs import task_geometry
from delegation.fleet import UnitState, make_unit
from delegation.geo import GeoPoint, great_circle_matrix_m
from delegation.learning import (
    FAR_M,
    SpeedLearner,
    input_warnings,
    speed_class,
    speed_notes,
)
from delegation.tst.node import TstNode, walk
from delegation.tst.validate import parse_and_validate

HERE = GeoPoint(latitude=57.76, longitude=16.68)
DJI = make_unit("dji0", "air", HERE, ["move-to"])  # air defaults: 1.5 / 3 / 6 m/s


def test_learns_only_while_a_task_of_the_class_runs() -> None:
    learner = SpeedLearner(alpha=0.5, min_samples=2)
    assert learner.observe_speed("dji0", 14.0, 0.0) is None  # no task: not a sample
    learner.task_started("dji0", "n1", "fast", 1.0)
    assert learner.observe_speed("dji0", 0.0, 1.5) is None  # standing still: not a sample
    assert learner.observe_speed("dji0", 14.0, 2.0) is None  # one sample: not used yet
    assert learner.learnt("dji0") == {}
    assert learner.observe_speed("dji0", 12.0, 3.0) == "fast"  # now usable
    assert learner.learnt("dji0") == {"fast": pytest.approx(13.0)}  # 14 + 0.5 (12 - 14)
    learner.task_ended("dji0", "n1", 4.0)
    assert learner.observe_speed("dji0", 2.0, 5.0) is None
    assert learner.learnt("dji0") == {"fast": pytest.approx(13.0)}


def test_a_late_end_of_another_task_does_not_stop_learning() -> None:
    learner = SpeedLearner(min_samples=1)
    learner.task_started("dji0", "n2", "standard", 0.0)
    learner.task_ended("dji0", "n1", 0.1)  # the previous task's final feedback, late
    assert learner.observe_speed("dji0", 8.0, 0.2) == "standard"


def test_unlearnt_classes_scale_with_the_learnt_ones() -> None:
    learner = SpeedLearner(min_samples=1)
    learner.task_started("dji0", "n1", "fast", 0.0)
    learner.observe_speed("dji0", 12.0, 1.0)  # twice the default fast (6)
    (unit,) = learner.apply([DJI])
    assert unit.speeds == {"slow": 3.0, "standard": 6.0, "fast": 12.0}
    assert learner.source("dji0", has_profile=True) == "learnt"
    assert learner.source("dji1", has_profile=True) == "profile"
    assert learner.source("dji1", has_profile=False) == "default"


def test_speed_class_of_a_node() -> None:
    tree = parse_and_validate({"name": "seq", "children": [
        {"name": "move-to", "params": {"waypoint": {"latitude": 57.7, "longitude": 16.6}}},
        {"name": "move-to", "params": {"speed": "fast",
                                       "waypoint": {"latitude": 57.7, "longitude": 16.6}}},
    ]})
    assert speed_class(tree) is None
    assert [speed_class(c) for c in tree.children] == ["standard", "fast"]


def test_notes_name_the_units_planned_with_defaults() -> None:
    usv = make_unit("usv0", "surface", HERE, ["move-to"])
    notes = speed_notes([DJI, usv], {"dji0": "default", "usv0": "profile"}, ["dji0", "usv0"])
    assert len(notes) == 1 and notes[0].startswith("unit /dji0: speeds are the air defaults")
    assert speed_notes([DJI], {"dji0": "default"}, []) == []  # not in the plan: no note


def test_warnings_for_a_bare_unit_name_and_far_away_tasks() -> None:
    tree = parse_and_validate({"name": "conc", "children": [
        {"name": "move-to", "common_params": {"execunit": "dji0"},
         "params": {"waypoint": {"latitude": 57.761, "longitude": 16.681}}},
        {"name": "move-to", "common_params": {"execunit": "scout"},
         "params": {"waypoint": {"latitude": 16.67, "longitude": 57.76}}},  # swapped
    ]})
    warnings = input_warnings(tree, [DJI])
    assert len(warnings) == 2
    assert "execunit 'dji0' is an alias" in warnings[0] and "'/dji0'" in warnings[0]
    assert "root/children[1]" in warnings[1] and "km from the nearest unit" in warnings[1]
    near = parse_and_validate({"name": "move-to", "common_params": {"execunit": "/dji0"},
                               "params": {"waypoint": {"latitude": 57.761, "longitude": 16.681}}})
    assert input_warnings(near, [DJI]) == []


def _far_tasks_one_matrix_each(tree: TstNode, units: list[UnitState]) -> list[float]:
    """The nearest-unit distance of every task with points, one distance matrix per task (as
    ``input_warnings`` first measured it)."""
    positions = [u.position for u in units]
    out = []
    for _, node in walk(tree):
        if node.is_control:
            continue
        g = task_geometry(node)
        points = [*g.points, *(p for a in g.areas for p in a)]
        if points:
            out.append(float(great_circle_matrix_m(points, positions).min()))
    return out


def test_one_distance_matrix_warns_as_a_matrix_per_task() -> None:
    """Far and near tasks of every geometry (points, paths, areas, in place), aliases between
    them: the same warnings, in the tree's order, with the same distances as task by task."""
    far = {"latitude": 16.67, "longitude": 57.76}  # swapped
    near = {"latitude": 57.761, "longitude": 16.681}
    tree = parse_and_validate({"name": "seq", "children": [
        {"name": "move-to", "common_params": {"execunit": "dji0"}, "params": {"waypoint": far}},
        {"name": "conc", "children": [
            {"name": "move-path", "params": {"waypoints": [near, far]}},
            {"name": "search-area", "common_params": {"execunit": "dji0"},
             "params": {"area": [far, {"latitude": 16.68, "longitude": 57.76},
                                 {"latitude": 16.68, "longitude": 57.77}]}},
            {"name": "take-off", "common_params": {"execunit": "dji0"}, "params": {}},
            {"name": "move-to", "params": {"waypoint": near}},
        ]},
        {"name": "move-to", "params": {"waypoint": {"latitude": 59.0, "longitude": 18.0}}},
    ]})
    usv = make_unit("usv0", "surface", GeoPoint(latitude=57.7, longitude=16.6), ["move-to"])
    warnings = input_warnings(tree, [DJI, usv])
    assert [w.split(":")[0] for w in warnings] == [
        "root/children[0] (move-to)", "root/children[0] (move-to)",  # alias, far
        "root/children[1]/children[1] (search-area)", "root/children[1]/children[1] (search-area)",
        "root/children[1]/children[2] (take-off)",  # alias (in place: never far)
    ]  # (the move-path has a near point; the last move-to is 150 km away)
    distances = _far_tasks_one_matrix_each(tree, [DJI, usv])
    far_ones = [f"{d / 1000:,.0f} km from the nearest unit" for d in distances if d > FAR_M]
    assert [w.split(": ", 1)[1].split(";")[0] for w in warnings if "km from" in w] == far_ones


def test_the_service_plans_with_what_it_learnt() -> None:
    """Message by message through `ServiceCore`: the first plan uses the air defaults and says
    so; dji0 reports 12 m/s while it runs a standard-speed move-to; the next plan uses 12 m/s
    and says the speeds were learnt."""
    import json

    from delegation.messages import TstFeedback, encode
    from delegation.service import ServiceConfig, ServiceCore
    from test_service_core import (
        BASE,
        ENGINE,
        PREFIX,
        _unit_topic,
        engine_answers,
        feed_engine,
        feed_unit,
        on,
        run_jobs,
        start_tst,
    )

    core = ServiceCore(ServiceConfig(prefix=PREFIX))
    feed_unit(core, "dji0", 57.7605, 16.6815, ["move-to"], 100.0)
    feed_engine(core, 100.0)

    def mission(root: str, com: str, now: float) -> dict[str, object]:
        tree = {"name": "move-to", "common_params": {"execunit": "/dji0", "node-uuid": root},
                "params": {"waypoint": {"latitude": 57.7625, "longitude": 16.6815}}}
        planned = run_jobs(core, core.on_message(f"{BASE}/tst/command", start_tst(tree, com), now),
                           now)
        engine_answers(core, planned, "started", now)
        return on(planned, "op0/tst/command")[0]

    first = mission("m1", "c1", 101.0)
    (a,) = core.book.get("m1").plan["assignments"]
    assert a["travel-time"] == pytest.approx(222.6 / 3.0, rel=0.01)  # air default standard
    assert any("speeds are the air defaults" in n for n in core.book.get("m1").plan["notes"])
    assert first["tst"]["common_params"]["node-uuid"] == "m1"

    core.on_message(f"{ENGINE}/tst/feedback",
                    encode(TstFeedback(node_uuid="m1", root_flag=True, status="running")), 102.0)
    for t in (103.0, 104.0, 105.0):
        core.on_message(_unit_topic("dji0", "sensor/speed"), json.dumps({"value": 12.0}).encode(),
                        t)
    core.on_message(f"{ENGINE}/tst/feedback",
                    encode(TstFeedback(node_uuid="m1", root_flag=True, status="succeeded")),
                    120.0)

    feed_unit(core, "dji0", 57.7605, 16.6815, ["move-to"], 121.0)  # back home, still live
    feed_engine(core, 121.0)
    mission("m2", "c2", 121.0)
    (b,) = core.book.get("m2").plan["assignments"]
    assert b["travel-time"] == pytest.approx(222.6 / 12.0, rel=0.01)
    assert any("speeds learnt" in n for n in core.book.get("m2").plan["notes"])
    row = next(r for r in core.agents(121.0) if r["name"] == "dji0")
    assert row["speeds"]["standard"] == pytest.approx(12.0) and row["speeds-source"] == "learnt"
