"""The simulated vehicle without MQTT: time advances only through step(dt)."""

from __future__ import annotations

import math

import pytest

from delegation.costs import task_path
from delegation.fleet import make_unit
from delegation.geo import GeoPoint, LocalFrame, distance_m, path_length_m
from delegation.sim.example_agent import EXAMPLE_AGENT_POLICY
from delegation.sim.vehicle import (
    ALREADY_RUNNING,
    BATTERY_EMPTY,
    INVALID_TASK_UUID,
    NOT_SUPPORTED,
    SimVehicle,
    TaskEvent,
    VehiclePolicy,
)
from delegation.tst.node import TstNode

START = GeoPoint(latitude=57.7605, longitude=16.6815, altitude=40.0)
FRAME = LocalFrame(START.latitude, START.longitude)
TASKS = [
    "move-to",
    "move-path",
    "search-area",
    "search-around-position",
    "observe-position",
    "look-at-position",
    "go-home",
    "take-off",
]


def at(east: float, north: float, alt: float = 40.0) -> GeoPoint:
    return FRAME.geopoint(east, north, alt)


def vehicle(example: bool = False, **kw) -> SimVehicle:
    unit = make_unit(
        "dji0", "air", START, TASKS, speeds={"slow": 2.0, "standard": 5.0, "fast": 10.0}, **kw
    )
    return SimVehicle(unit, EXAMPLE_AGENT_POLICY if example else VehiclePolicy())


def run_until(v: SimVehicle, seconds: float, dt: float = 0.1) -> list[TaskEvent]:
    events: list[TaskEvent] = []
    for _ in range(round(seconds / dt)):
        events.extend(v.step(dt))
    return events


def test_move_to_takes_distance_over_speed() -> None:
    v = vehicle()
    target = at(300.0, 400.0)  # 500 m away
    assert (
        v.start_task("move-to", {"waypoint": target.to_wire(), "speed": "standard"}, "t1") is None
    )
    assert v.busy and v.executing() == [("move-to", "t1")]
    assert run_until(v, 99.0) == []  # 500 m at 5 m/s is 100 s
    assert v.speed == 5.0
    assert v.heading == pytest.approx(math.degrees(math.atan2(300, 400)), abs=0.5)
    events = run_until(v, 1.5)
    assert events == [TaskEvent("t1", "finished")]
    assert distance_m(v.position, target) < 0.5
    assert not v.busy and v.speed == 0.0
    assert v.status_of("t1") == "success"  # query-status: the seed's word


def test_one_big_step_equals_many_small_ones() -> None:
    path = [at(100, 0).to_wire(), at(100, 100).to_wire(), at(0, 100).to_wire()]
    a, b = vehicle(), vehicle()
    for v in (a, b):
        assert v.start_task("move-path", {"waypoints": path, "speed": "fast"}, "p") is None
    a.step(17.3)
    run_until(b, 17.3, dt=0.01)
    assert distance_m(a.position, b.position) < 0.05
    assert a.odometer == pytest.approx(173.0, abs=0.1)


def test_move_path_flies_the_polyline() -> None:
    v = vehicle()
    pts = [at(0, 200), at(200, 200), at(200, 0)]
    v.start_task("move-path", {"waypoints": [p.to_wire() for p in pts], "speed": "slow"}, "p")
    length = path_length_m([START, *pts])
    assert run_until(v, length / 2.0 - 1.0) == []
    assert run_until(v, 2.0) == [TaskEvent("p", "finished")]
    assert v.odometer == pytest.approx(length, rel=0.005)


def test_search_area_flies_the_coverage_sweep() -> None:
    v = vehicle()
    area = [at(0, 0, 0), at(200, 0, 0), at(200, 100, 0), at(0, 100, 0)]
    params = {"area": [p.to_wire() for p in area], "speed": "fast"}
    assert v.start_task("search-area", params, "s") is None
    sweep = task_path(TstNode("search-area", params=params), v.unit, FRAME)
    assert len(sweep) >= 4  # a real boustrophedon, several lanes
    expected = distance_m(START, sweep[0]) + path_length_m(sweep)
    events = run_until(v, expected / 10.0 + 1.0)
    assert events == [TaskEvent("s", "finished")]
    assert v.odometer == pytest.approx(expected, rel=0.005)
    assert distance_m(v.position, sweep[-1]) < 0.5


def test_one_vehicle_task_at_a_time_and_unknown_tasks() -> None:
    v = vehicle()
    far = {"waypoint": at(1000, 0).to_wire(), "speed": "standard"}
    assert v.start_task("move-to", far, "a") is None
    assert v.start_task("move-to", far, "b") == ALREADY_RUNNING
    assert v.start_task("navigate", {"waypoints": []}, "c") == NOT_SUPPORTED
    # A camera task does not move the platform: it runs alongside.
    look = {"geopoint": at(0, 50).to_wire()}
    assert v.start_task("look-at-position", look, "d") is None
    # The example agent runs one task of any kind.
    ex = vehicle(example=True)
    assert ex.start_task("move-to", far, "a") is None
    assert ex.start_task("look-at-position", look, "d") == ALREADY_RUNNING


def test_bad_parameters_are_refused_with_the_field() -> None:
    v = vehicle()
    reason = v.start_task("move-to", {"speed": "standard"}, "x")
    assert reason is not None and "waypoint" in reason
    reason = v.start_task("move-to", {"waypoint": at(1, 1).to_wire(), "speed": "warp"}, "y")
    assert reason is not None and "speed" in reason
    assert not v.busy


def test_pause_continue_abort() -> None:
    v = vehicle()
    v.start_task("move-to", {"waypoint": at(0, 1000).to_wire(), "speed": "standard"}, "t")
    run_until(v, 10.0)
    reason, event = v.signal("t", "$pause")
    assert reason is None and event == TaskEvent("t", "paused")
    here = v.position
    run_until(v, 20.0)
    assert distance_m(here, v.position) < 1e-6 and v.speed == 0.0
    assert v.signal("t", "$continue") == (None, TaskEvent("t", "running"))
    run_until(v, 10.0)
    assert distance_m(START, v.position) == pytest.approx(100.0, abs=0.5)
    assert v.signal("t", "$abort") == (None, TaskEvent("t", "aborted"))
    assert not v.busy and v.status_of("t") == "failed"  # query-status words (seed 12.1)
    assert v.signal("t", "$abort") == (INVALID_TASK_UUID, None)


def test_open_ended_tasks_end_with_enough() -> None:
    v = vehicle()
    v.start_task("look-at-position", {"geopoint": at(10, 10).to_wire()}, "l")
    assert run_until(v, 500.0) == []
    assert v.signal("l", "$enough") == (None, TaskEvent("l", "finished"))
    ex = vehicle(example=True)
    ex.start_task("look-at-position", {"geopoint": at(10, 10).to_wire()}, "l")
    assert ex.signal("l", "$enough") == (None, TaskEvent("l", "enough"))


def test_observe_position_travels_then_stays_for_duration() -> None:
    v = vehicle()
    params = {"geopoint": at(0, 100).to_wire(), "duration": 30, "speed": "standard"}
    v.start_task("observe-position", params, "o")
    assert run_until(v, 20.0 + 29.0) == []  # 100 m at 5 m/s, then 30 s
    assert run_until(v, 1.5) == [TaskEvent("o", "finished")]


def test_go_home_returns_home() -> None:
    home = at(-200, 0, 0)
    v = vehicle(home=home)
    v.start_task("go-home", {"speed": "fast"}, "h")
    assert run_until(v, 21.0) == [TaskEvent("h", "finished")]
    assert distance_m(v.position, home) < 0.5


def test_battery_drains_and_fails_the_task() -> None:
    v = vehicle(battery=0.5, endurance=100.0)
    v.start_task("move-to", {"waypoint": at(0, 10_000).to_wire(), "speed": "standard"}, "t")
    assert run_until(v, 40.0) == []
    assert v.battery == pytest.approx(0.1, abs=0.01)
    events = run_until(v, 11.0)
    assert events == [TaskEvent("t", "failed", BATTERY_EMPTY)]
    assert v.start_task("move-to", {"waypoint": at(0, 0).to_wire()}, "u") == BATTERY_EMPTY


def test_a_unit_of_unknown_endurance_flies_what_the_planner_plans() -> None:
    # The planner gives a unit that reports no endurance no limit (docs/plan.md §2.5): a task of
    # 5,000 s is feasible for it. The simulator agrees: its battery never drains (it drained as
    # if the unit had 3,600 s, and the planned task failed with "battery depleted").
    from delegation.costs import cost_tables
    from delegation.tst import make_node

    v = vehicle()
    far = at(0, 25_000)  # 5,000 s at 5 m/s
    node = make_node("move-to", params={"waypoint": far.to_wire(), "speed": "standard"})
    tables = cost_tables([v.unit], [node], frame=FRAME)
    assert tables.capable[0, 0] and tables.need_time[0, 0] == pytest.approx(5000.0, rel=1e-3)
    v.start_task("move-to", {"waypoint": far.to_wire(), "speed": "standard"}, "t")
    events = run_until(v, 5010.0, dt=1.0)
    assert events == [TaskEvent("t", "finished")]
    assert v.battery == 1.0


def test_a_unit_with_endurance_fails_where_the_planner_refuses() -> None:
    from delegation.costs import cost_tables
    from delegation.tst import make_node

    v = vehicle(endurance=4000.0)
    far = at(0, 25_000)
    node = make_node("move-to", params={"waypoint": far.to_wire(), "speed": "standard"})
    assert not cost_tables([v.unit], [node], frame=FRAME).capable[0, 0]
    v.start_task("move-to", {"waypoint": far.to_wire(), "speed": "standard"}, "t")
    events = run_until(v, 4010.0, dt=1.0)
    assert events == [TaskEvent("t", "failed", BATTERY_EMPTY)]


ALL = [
    ("move-to", {"waypoint": at(100, 0).to_wire()}, False),
    ("move-path", {"waypoints": [at(0, 50).to_wire(), at(50, 50).to_wire()]}, False),
    (
        "search-area",
        {"area": [at(0, 0, 0).to_wire(), at(80, 0, 0).to_wire(), at(0, 80, 0).to_wire()]},
        False,
    ),
    (
        "search-areas",
        {
            "areas": [
                [at(0, 0, 0).to_wire(), at(60, 0, 0).to_wire(), at(0, 60, 0).to_wire()],
                [at(200, 0, 0).to_wire(), at(260, 0, 0).to_wire(), at(200, 60, 0).to_wire()],
            ]
        },
        False,
    ),
    ("search-around-position", {"geopoint": at(100, 100).to_wire(), "radius": 40.0}, False),
    ("observe-position", {"geopoint": at(30, 0).to_wire(), "duration": 5}, False),
    ("observe-position", {"geopoint": at(30, 0).to_wire(), "duration": -1}, True),
    ("look-at-position", {"geopoint": at(30, 0).to_wire()}, True),
    ("look-at-positions", {"geopoints": [at(30, 0).to_wire()]}, True),
    ("look-at-bearing", {"bearing": 90.0}, True),
    ("take-off", {"height-above-takeoff": 20.0}, False),
    ("land", {"land-at-current-position-flag": True}, False),
    ("go-home", {}, False),
]


@pytest.mark.parametrize(
    ("name", "params", "open_ended"), ALL, ids=[f"{a[0]}-{i}" for i, a in enumerate(ALL)]
)
def test_every_task_runs_to_its_end(name: str, params: dict, open_ended: bool) -> None:
    unit = make_unit("u", "air", START, [name], speeds={"standard": 10.0})
    v = SimVehicle(unit)
    assert v.start_task(name, params, "t") is None
    events = run_until(v, 600.0, dt=0.5)
    if open_ended:
        assert events == [] and v.status_of("t") == "running"
        assert v.signal("t", "$enough") == (None, TaskEvent("t", "finished"))
    else:
        assert events == [TaskEvent("t", "finished")]
    if name == "take-off":
        assert v.altitude == pytest.approx(START.altitude + 20.0)
    if name == "land":
        assert v.altitude == 0.0
    if name.startswith("search"):
        assert v.odometer > 150.0  # it flew a sweep, not a straight line


@pytest.mark.parametrize(
    ("how", "word"),
    [
        ("running", "running"),
        ("paused", "running"),  # still on the unit: the seed has no "paused" for query-status
        ("finished", "success"),
        ("enough", "success"),  # the example agent's $enough
        ("aborted", "failed"),
        ("battery", "failed"),
        ("never", "unknown"),
    ],
)
def test_query_status_answers_in_the_seeds_words(how: str, word: str) -> None:
    """Seed 12.1: query-status returns "the status of the task (running, failed, success,
    unknown)", whatever words the feedback used."""
    drains = {"battery": 0.001, "endurance": 3600.0} if how == "battery" else {}
    v = vehicle(example=how == "enough", **drains)  # a unit of unknown endurance never drains
    north = 10.0 if how == "finished" else 5000.0
    go = {"waypoint": at(0.0, north).to_wire(), "speed": "standard"}
    if how != "never":
        assert v.start_task("move-to", go, "t") is None
    if how in ("paused", "aborted", "enough"):
        v.signal("t", {"paused": "$pause", "aborted": "$abort", "enough": "$enough"}[how])
    elif how == "finished":
        assert [e.status for e in run_until(v, 5.0)] == ["finished"]
    elif how == "battery":
        run_until(v, 30.0, dt=1.0)
        assert "t" not in v.tasks
    assert v.status_of("t") == word


@pytest.mark.parametrize(
    ("flags", "ends"),
    [({}, True), ({"hold-flag": True}, False), ({"loop-flag": True}, False),
     ({"loop-flag": False, "hold-flag": False}, True)],
    ids=["plain", "hold", "loop", "flags-false"],
)
def test_navigate_loops_or_holds_until_enough(flags: dict[str, bool], ends: bool) -> None:
    """Seed 9.14: navigate ends at its last waypoint unless loop-flag (round the waypoints again)
    or hold-flag (stay at the last) keeps it on until $enough."""
    unit = make_unit("dji0", "air", START, ["navigate"], speeds={"standard": 10.0})
    v = SimVehicle(unit)
    square = [at(0.0, 100.0), at(100.0, 100.0), at(100.0, 0.0), at(0.0, 0.0)]  # 400 m round
    params = {"waypoints": [p.to_wire() for p in square], "speed": ["standard"], **flags}
    assert v.start_task("navigate", params, "n") is None
    events = run_until(v, 45.0, dt=0.5)  # 41 s for the waypoints at 10 m/s
    if ends:
        assert [e.status for e in events] == ["finished"]
        return
    assert events == [] and v.status_of("n") == "running"
    here = v.position
    if "hold-flag" in flags:
        assert distance_m(here, square[-1]) < 0.5 and v.speed == 0.0
    else:  # round again: 45 s at 10 m/s is 450 m, 50 m into the second round, going north
        assert distance_m(here, at(0.0, 50.0)) < 0.5 and v.speed == 10.0
        assert v.tasks["n"].travelled == pytest.approx(450.0, abs=2.0)
    run_until(v, 200.0, dt=1.0)
    assert v.status_of("n") == "running"
    assert v.signal("n", "$enough")[1] == TaskEvent("n", "finished")
