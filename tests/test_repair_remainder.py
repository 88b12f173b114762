"""A lost unit's search is not flown again whole (issue 22 item 3, issue 21 item 4; docs/protocol.md
§11 and §12.6), in the service core: what its reported positions swept is subtracted, and the
remainder replaces its task within the running tree (``rebind-tst-nodes`` ``subtrees``), planned
among the live units; the other unit's search is not touched. With ``repair_sweep: whole`` the
part moves whole (the comparison of benchmarks/faults.py).

Fed with explicit times, planning jobs run with the real planner, no broker."""

from __future__ import annotations

import json
from typing import Any

import shapely
from shapely.geometry import Polygon

from delegation.geo import GeoPoint, LocalFrame
from delegation.service import ServiceConfig, ServiceCore
from delegation.tst.node import parse_tree, walk
from test_service_core import (
    PREFIX,
    _unit_topic,
    engine_answers,
    feed_engine,
    feed_unit,
    on,
    run_jobs,
)
from test_service_redelegation import _tree, feedback, started_mission

TASKS = ["move-to", "search-area", "search-areas"]
LAT0, LON0, DLAT, DLON = 57.7610, 16.6800, 0.0018, 0.0030  # u1's area: 200 m x 180 m


def area(lon0: float) -> list[dict[str, float]]:
    return [{"latitude": a, "longitude": b, "altitude": 20.0}
            for a, b in ((LAT0, lon0), (LAT0 + DLAT, lon0), (LAT0 + DLAT, lon0 + DLON),
                         (LAT0, lon0 + DLON))]


def search(uid: str, unit: str, lon0: float) -> dict[str, Any]:
    return {"name": "search-area", "common_params": {"execunit": unit, "node-uuid": uid},
            "params": {"area": area(lon0), "speed": "standard"}}


def units(core: ServiceCore, now: float, names: tuple[str, ...] = ("u0", "u1", "u2")) -> None:
    for name in names:
        feed_unit(core, name, LAT0 - 0.001, 16.6800 + 0.004 * int(name[1:]), TASKS, now)
    feed_engine(core, now)


def fly_two_lanes(core: ServiceCore, t0: float) -> float:
    """u1 reports positions along the two westmost lanes of its area (about 40 % of it)."""
    t = t0
    for lon, lats in ((LON0 + 0.00031, (LAT0, LAT0 + DLAT)), (LON0 + 0.00093, (LAT0 + DLAT, LAT0))):
        for k in range(11):
            lat = lats[0] + (lats[1] - lats[0]) * k / 10
            pos = {"latitude": lat, "longitude": lon, "altitude": 20.0}
            core.on_message(_unit_topic("u1", "sensor/position"), json.dumps(pos).encode(), t)
            t += 0.05
    return t


def lost_u1(config: ServiceConfig) -> tuple[ServiceCore, Any]:
    core = ServiceCore(config)
    units(core, 100.0)
    started_mission(core, _tree("conc", "root-1", search("s0", "/u0", LON0 + 0.008),
                                search("s1", "/u1", LON0)))
    feedback(core, "s0", "running", 101.5)
    feedback(core, "s1", "running", 101.5)
    t = fly_two_lanes(core, 101.6)
    units(core, t + 2.0, ("u0", "u2"))
    lost = core.on_tick(t + 3.0)
    assert len(lost.jobs) == 1
    return core, run_jobs(core, lost, t + 3.2)


def region(polys: list[list[dict[str, float]]], frame: LocalFrame) -> shapely.Geometry:
    return shapely.union_all([Polygon([frame.point_xy(_gp(p)) for p in poly])
                              for poly in polys])


def _gp(p: dict[str, float]) -> GeoPoint:
    return GeoPoint.model_validate(p)


def test_only_the_unswept_remainder_moves_and_the_other_search_is_untouched() -> None:
    core, planned = lost_u1(ServiceConfig(prefix=PREFIX))
    [cmd] = on(planned, "op0/tst/command")  # no $abort, no start-tst: one rebind
    assert cmd["command"] == "rebind-tst-nodes"
    assert cmd["execunits"] == {} and list(cmd["subtrees"]) == ["s1"]
    sub = parse_tree(cmd["subtrees"]["s1"])
    assert sub.name == "conc" and sub.node_uuid == "s1"
    parts = [n for _, n in walk(sub) if not n.is_control]
    assert parts and all(p.execunit in ("/u0", "/u2") for p in parts)
    assert all(p.name in ("search-area", "search-areas") for p in parts)
    frame = LocalFrame(LAT0, LON0)
    whole = region([area(LON0)], frame)
    left = region([ring for p in parts for ring in (
        [p.params["area"]] if p.name == "search-area" else p.params["areas"])], frame)
    # Two lanes of about 37 m were swept of 180 m: 30-50 % is credited, the rest moves.
    assert 0.5 * whole.area < left.area < 0.7 * whole.area
    assert left.difference(whole).area < 0.005 * whole.area
    # The swept lanes are not in the remainder; the far side is.
    west = shapely.box(*frame.point_xy(_gp({"latitude": LAT0, "longitude": LON0})),
                       *frame.point_xy(_gp({"latitude": LAT0 + DLAT, "longitude": LON0 + 0.0009})))
    assert left.intersection(west).area < 0.05 * west.area
    done = engine_answers(core, planned, "ok", 200.0)
    [moved] = on(done, "delegation/feedback")
    assert moved["status"] == "re-delegated" and "/u1 lost" in moved["fail-reason"]
    assert {t["replaces"] for t in moved["tasks"]} == {"s1"}
    assert all(0.3 < t["swept"] < 0.5 for t in moved["tasks"])
    assert {t["node-uuid"] for t in moved["tasks"]} == {p.node_uuid for p in parts}
    mission = core.book.get("root-1")
    sent = {n.node_uuid: n for _, n in walk(parse_tree(mission.current_tst))}
    assert sent["s1"].name == "conc" and sent["s0"].execunit == "/u0"
    assert sent["s0"].params["area"] == area(LON0 + 0.008)  # untouched
    for p in parts:
        assert mission.nodes[p.node_uuid or ""].path.startswith(mission.nodes["s1"].path + "/")
    # The parts end, then the mission.
    for p in parts:
        feedback(core, p.node_uuid or "", "succeeded", 210.0)
    feedback(core, "s1", "succeeded", 210.0)
    feedback(core, "s0", "succeeded", 211.0)
    end = feedback(core, "root-1", "succeeded", 211.0, root=True)
    assert [f["status"] for f in on(end, "delegation/feedback")] == ["succeeded"]


def test_with_repair_sweep_whole_the_part_moves_whole() -> None:
    core, planned = lost_u1(ServiceConfig(prefix=PREFIX, repair_sweep="whole"))
    [cmd] = on(planned, "op0/tst/command")
    assert cmd["command"] == "rebind-tst-nodes"
    # Planned again whole: moved to one unit, or shared whole among the live ones.
    if cmd["execunits"]:
        assert list(cmd["execunits"]) == ["s1"] and not cmd.get("subtrees")
        return
    parts = [n for _, n in walk(parse_tree(cmd["subtrees"]["s1"])) if not n.is_control]
    frame = LocalFrame(LAT0, LON0)
    whole = region([area(LON0)], frame)
    left = region([ring for p in parts for ring in (
        [p.params["area"]] if p.name == "search-area" else p.params["areas"])], frame)
    assert left.area > 0.995 * whole.area
    done = engine_answers(core, planned, "ok", 200.0)
    [moved] = on(done, "delegation/feedback")
    assert not [t for t in moved["tasks"] if "swept" in t]


def test_query_mission_shows_the_tree_that_runs_once_a_remainder_runs_in_place() -> None:
    """The operator page draws a re-shared part's pieces (issue 21): ``query-mission`` carries
    ``current-tst`` once the tree running differs from the one sent, and only then."""
    from test_service_core import delegation

    def query(core: ServiceCore, com: str) -> dict[str, Any]:
        [answer] = on(delegation(core, {"command": "query-mission", "root-uuid": "root-1"},
                                 now=300.0, com=com), "delegation/response")
        assert answer["response"] == "ok"
        return dict(answer["mission"])

    core, planned = lost_u1(ServiceConfig(prefix=PREFIX))
    assert "current-tst" not in query(core, "q1")  # (the rebind is not answered yet)
    [cmd] = on(planned, "op0/tst/command")
    engine_answers(core, planned, "ok", 200.0)
    mission = query(core, "q2")
    running = {n.node_uuid: n for _, n in walk(parse_tree(mission["current-tst"]))}
    assert running["s1"].name == "conc" and running["s1"].children
    assert {c.node_uuid for c in running["s1"].children} == {
        n.node_uuid for _, n in walk(parse_tree(cmd["subtrees"]["s1"])) if not n.is_control}
    assert mission["tst"]["children"][1]["name"] == "search-area"  # the tree sent, as sent
