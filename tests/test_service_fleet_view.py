"""The fleet view alone (`delegation.service.fleet_view`): the units a plan may use, busy units
planned from when and where they become free, speeds learnt from flights."""

from __future__ import annotations

import json

from delegation.fleet import FleetRegistry
from delegation.messages import (
    DirectExecutionInfo,
    HeartBeat,
    MissionStatus,
    StartTst,
    TaskAvailable,
    TstFeedback,
    encode,
)
from delegation.service.config import ServiceConfig
from delegation.service.engine_link import EngineLink
from delegation.service.fleet_view import FleetView
from delegation.service.missions import Mission, MissionBook, node_infos
from delegation.tst.node import parse_tree

PREFIX = "t"


def _topic(name: str, rest: str) -> str:
    return f"{PREFIX}/unit/air/simulation/{name}/{rest}"


def _view(**config: object) -> FleetView:
    c = ServiceConfig(prefix=PREFIX, **config)  # type: ignore[arg-type]
    fleet = FleetRegistry()
    return FleetView(c, fleet, MissionBook(), EngineLink(c, fleet), lambda now: now + 1000.0)


def _feed(view: FleetView, name: str, lat: float, now: float, battery: float | None = None
          ) -> None:
    hb = HeartBeat(agent_type="air", agent_uuid=f"uuid-{name}", name=name, rate=1.0, stamp=now,
                   levels=["sensor", "direct execution"])
    dei = DirectExecutionInfo(name=name, rate=1.0, stamp=now,
                              tasks_available=[TaskAvailable(name="move-to")])
    pos = {"latitude": lat, "longitude": 16.68, "altitude": 10.0}
    view.observe(_topic(name, "heartbeat"), encode(hb), now)
    view.observe(_topic(name, "direct_execution_info"), encode(dei), now)
    view.observe(_topic(name, "sensor/position"), json.dumps(pos).encode(), now)
    if battery is not None:
        view.observe(_topic(name, "sensor/battery"), json.dumps(battery).encode(), now)


def _busy_mission(view: FleetView, unit: str) -> None:
    tree = {"name": "move-to", "common_params": {"node-uuid": "t1", "execunit": f"/{unit}"},
            "params": {"waypoint": {"latitude": 57.8, "longitude": 16.7, "altitude": 20.0}}}
    plan = {"assignments": [{"node-uuid": "t1", "execunit": f"/{unit}", "end": 120.0}]}
    view.book.add(Mission(root_uuid="t1", source="delegate", created=1000.0, tst=tree, plan=plan,
                          nodes=node_infos(parse_tree(tree)), status=MissionStatus.RUNNING,
                          started_at=1000.0))


def test_units_leave_out_low_battery_and_excluded_ones_naming_them() -> None:
    view = _view(min_battery=0.3)
    for name, battery in (("u0", 0.9), ("u1", 0.1), ("u2", None)):
        _feed(view, name, 57.76, 0.0, battery)
    units, notes = view.plannable(1.0, exclude={"u2"})
    assert [u.name for u in units] == ["u0"]
    assert any("u1: left out, battery 10%" in n for n in notes)
    assert any(n.startswith("u2: left out (lost") for n in notes)
    assert view.ready({"u0", "u1"}, engine=False, now=1.0)
    assert not view.ready({"u0"}, engine=True, now=1.0)  # no engine heard


def test_a_busy_unit_is_planned_from_when_and_where_it_becomes_free() -> None:
    view = _view()  # commitments: wait
    _feed(view, "u0", 57.76, 0.0)
    _busy_mission(view, "u0")
    assert view.committed() == {"u0": "t1"} and view.committed(but="t1") == {}
    [unit], notes = view.plannable(20.0)
    # Started at epoch 1000, ends 120 s later; now is epoch 1020: free in 100 s, at its waypoint.
    assert unit.available_at == 100.0 and unit.position.latitude == 57.8
    assert "busy in mission t1, planned from when and where it becomes free" in notes[0]
    assert view.plannable(20.0, mission="t1")[0][0].available_at == 0.0  # its own mission


def test_when_a_busy_unit_becomes_free_follows_the_clock_and_its_mission() -> None:
    """What a mission says of its unit is kept between plans (issue 19), but the wait counts
    down with ``now`` and a task that ended moves it."""
    view = _view()
    _feed(view, "u0", 57.76, 0.0)
    _busy_mission(view, "u0")
    assert view.plannable(20.0)[0][0].available_at == 100.0
    assert view.plannable(50.0)[0][0].available_at == 70.0
    view.book.observe_feedback("t1", "running", True, "", 5.0)
    mission = view.book.find("t1")
    assert mission is not None
    mission.plan = {"assignments": [{"node-uuid": "t1", "execunit": "/u0", "end": 200.0}]}
    view.book.touch("t1")  # changed in place: said to the book
    assert view.plannable(50.0)[0][0].available_at == 150.0


def test_commitments_follow_every_change_of_the_book() -> None:
    """`committed` is kept between changes: a task ending, a mission ending or forgotten, a
    new one, each shows at once."""
    view = _view()
    _busy_mission(view, "u0")
    assert view.committed() == {"u0": "t1"}
    view.book.observe_feedback("t1", "running", True, "", 5.0)
    assert view.committed() == {"u0": "t1"}
    view.book.observe_feedback("t1", "succeeded", True, "", 6.0)  # the task (the mission) ended
    assert view.committed() == {}
    assert view.book.forget_ended(10_000.0) == ["t1"] and view.committed() == {}
    _busy_mission(view, "u1")
    assert view.committed() == {"u1": "t1"}
    view.book.set_status("t1", MissionStatus.FAILED, 7.0)
    assert view.committed() == {}


def test_commitments_follow_a_task_moved_and_a_start_sent() -> None:
    """Per mission too: a rebind moves its unit; a mission planned only holds nobody until
    its start-tst is on its way to the engine."""
    view = _view()
    _busy_mission(view, "u0")
    mission = view.book.find("t1")
    assert mission is not None and view.committed() == {"u0": "t1"}
    view.book.rebind(mission, {"t1": "/u1"})
    assert view.committed() == {"u1": "t1"}
    tree = {"name": "move-to", "common_params": {"node-uuid": "p1", "execunit": "/u2"},
            "params": {"waypoint": {"latitude": 57.8, "longitude": 16.7, "altitude": 20.0}}}
    view.book.add(Mission(root_uuid="p1", source="delegate", created=1000.0, tst=tree, plan={},
                          nodes=node_infos(parse_tree(tree))))
    assert view.committed() == {"u1": "t1"}  # planned only
    hb = HeartBeat(agent_type="ground", agent_uuid="e", levels=["tst execution"], name="op0",
                   rate=1.0, stamp=1.0)
    view.fleet.observe(f"{PREFIX}/unit/ground/simulation/op0/heartbeat", hb, 1.0)
    view.engine.send("start", ("tst", "c"), "tst", StartTst(receiver="op0", tst=tree), 1.0,
                     "p1")
    assert view.committed() == {"u1": "t1", "u2": "p1"}


def test_a_unit_a_task_was_moved_onto_is_left_out_its_end_being_unknown() -> None:
    view = _view()
    _feed(view, "u0", 57.76, 0.0)
    tree = {"name": "conc", "common_params": {"node-uuid": "t1"}, "children": [
        {"name": "move-to", "common_params": {"node-uuid": f"k{i}", "execunit": f"/{u}"},
         "params": {"waypoint": {"latitude": 57.8, "longitude": 16.7, "altitude": 20.0}}}
        for i, u in enumerate(("u0", "u1"))]}
    plan = {"assignments": [{"node-uuid": "k0", "execunit": "/u0", "end": 120.0},
                            {"node-uuid": "k1", "execunit": "/u1", "end": 300.0}]}
    mission = Mission(root_uuid="t1", source="delegate", created=1000.0, tst=tree, plan=plan,
                      nodes=node_infos(parse_tree(tree)), status=MissionStatus.RUNNING,
                      started_at=1000.0)
    view.book.add(mission)
    assert view.plannable(20.0)[0][0].available_at == 100.0
    view.book.rebind(mission, {"k1": "/u0"})  # u1 lost: its task moved onto u0 in place
    assert view.plannable(20.0) == ((), ("u0: left out, busy in mission t1",))


def test_exclude_commitments_leave_the_busy_unit_out() -> None:
    view = _view(commitments="exclude")
    _feed(view, "u0", 57.76, 0.0)
    _busy_mission(view, "u0")
    assert view.plannable(20.0) == ((), ("u0: left out, busy in mission t1",))


def test_a_task_flown_teaches_its_speed_class() -> None:
    view = _view()
    _feed(view, "u0", 57.76, 0.0)
    tree = parse_tree({"name": "move-to", "common_params": {"node-uuid": "n1", "execunit": "/u0"},
                       "params": {"speed": "fast", "waypoint": {"latitude": 57.77,
                                                                "longitude": 16.68,
                                                                "altitude": 10.0}}})
    view.planned(tree)
    view.task_feedback(TstFeedback(node_uuid="n1", status="running"), 1.0)
    for t in range(2, 40):  # the speed sensor while it flies
        view.observe(_topic("u0", "sensor/speed"), json.dumps(9.5).encode(), float(t))
    view.task_feedback(TstFeedback(node_uuid="n1", status="succeeded"), 40.0)
    _feed(view, "u0", 57.76, 40.0)  # still live
    assert view.speed_sources(view.units(40.0)) == {"u0": "learnt"}
    [row] = view.agents(40.0)
    assert row["name"] == "u0" and row["speeds-source"] == "learnt"


def test_a_node_is_found_in_the_stored_tree_under_either_common_key() -> None:
    from delegation.service.fleet_view import _node_in

    tree = {"name": "seq", "common-params": {"node-uuid": "r"}, "children": [
        {"name": "move-path", "common-params": {"node-uuid": "p"},
         "params": {"waypoints": [1, 2]}}]}
    assert _node_in(tree, "p") == ("move-path", {"waypoints": [1, 2]})
    assert _node_in(tree, "r") == ("seq", {}) and _node_in(tree, "x") == ("", {})


def test_commitments_read_per_change_match_a_walk_of_the_whole_book() -> None:
    """`committed` reads only the missions changed since it was last asked (issue 19); after
    every change it names what a walk of every mission in book order names."""
    from delegation.service.fleet_view import _held_units

    def walked(view: FleetView, but: str = "") -> dict[str, str]:
        busy: dict[str, str] = {}
        for m in view.book:
            for unit in _held_units(m, view.engine.starting(m.root_uuid)):
                if m.root_uuid != but:
                    busy.setdefault(unit, m.root_uuid)
        return busy

    view = _view()
    for i, unit in enumerate(("u0", "u1", "u0", "u2", "u1", "u0")):
        tree = {"name": "move-to", "common_params": {"node-uuid": f"m{i}", "execunit": f"/{unit}"},
                "params": {"waypoint": {"latitude": 57.8, "longitude": 16.7, "altitude": 20.0}}}
        view.book.add(Mission(root_uuid=f"m{i}", source="delegate", created=1000.0, tst=tree,
                              plan={}, nodes=node_infos(parse_tree(tree)),
                              status=MissionStatus.RUNNING, started_at=1000.0))
        assert view.committed() == walked(view) and view.committed("m0") == walked(view, "m0")
    changes = [lambda: view.book.observe_feedback("m0", "succeeded", True, "", 6.0),
               lambda: view.book.set_status("m2", MissionStatus.FAILED, 7.0),
               lambda: view.book.rebind(view.book.find("m4"), {"m4": "/u2"}),  # type: ignore[arg-type]
               lambda: view.book.forget_ended(10_000.0)]
    for change in changes:
        change()
        assert view.committed() == walked(view) and view.committed("m1") == walked(view, "m1")
    assert view.committed() == {"u1": "m1", "u2": "m3", "u0": "m5"}


def test_a_repeated_payload_is_heard_again_and_a_new_one_read() -> None:
    """The same bytes again (a unit at rest) are not decoded again but still keep the unit
    alive; new bytes on the topic are read (the position moves, a change of state shows)."""
    view = _view()
    _feed(view, "u1", 57.70, now=0.0)
    first = view.units(0.0)
    assert view.units(0.0) == first and view.units(0.0)[0] is first[0]  # nothing changed
    pos = json.dumps({"latitude": 57.70, "longitude": 16.68, "altitude": 10.0}).encode()
    for now in (4.0, 8.0, 12.0):  # past the 5 s timeout without these: still alive
        view.observe(_topic("u1", "sensor/position"), pos, now)
    assert view.fleet.last_seen("u1") == 12.0
    (unit,) = view.units(12.0)
    assert unit.position.latitude == 57.70
    view.observe(_topic("u1", "sensor/position"), pos.replace(b"57.7", b"57.8"), 13.0)
    assert view.units(13.0)[0].position.latitude == 57.80
    view.observe(_topic("u1", "sensor/battery"), b"0.5", 13.0)
    assert view.units(13.0)[0].battery == 0.5


def test_units_follow_what_is_learnt_of_their_speeds_at_every_reading() -> None:
    view = _view()
    _feed(view, "u1", 57.70, now=0.0)
    prior = view.units(0.0)[0].speeds["standard"]
    view.learner.task_started("u1", "n1", "standard", 0.0)
    for value in (4.0, 4.0):
        view.learner.observe_speed("u1", value, 0.0)
    assert view.units(0.0)[0].speeds["standard"] == 4.0 != prior
    assert view.units(0.0)[0] is view.units(0.0)[0]  # nothing changed: the same state
    view.learner.observe_speed("u1", 5.0, 0.0)
    assert view.units(0.0)[0].speeds["standard"] == view.learner.learnt("u1")["standard"] > 4.0
