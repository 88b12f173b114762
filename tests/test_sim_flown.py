"""Searches flown by simulated units stay in their parts and take the planned time (issue 21).

The parts are flown in process (``delegation.sim.flown``: the `SimVehicle` that ``delegation sim``
runs, stepped in simulated seconds); figures over the whole family are benchmarks/flown.py's.
"""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from shapely.geometry import Polygon

from delegation.allocation import plan_mission
from delegation.allocation.sharing import region_of
from delegation.bench.team_search import FRAME, concave_polygons, fleet, search_node, unit_at
from delegation.costs import search_polygons_xy, sweep_width
from delegation.coverage import (
    flown_sweep,
    flown_ways,
    path_length,
    pick_way,
    sweep_cells,
    transitions_inside,
    turns_inside,
)
from delegation.render.mapplot import planned_route
from delegation.sim.flown import fly_plan, footprint, outside, swept
from delegation.tst import leaves, make_node, with_uuids

RECT = np.array([[0.0, 0.0], [800.0, 0.0], [800.0, 300.0], [0.0, 300.0]])


def test_turns_are_inside_a_rectangle_and_its_footprint_covers_it_exactly() -> None:
    # 800 x 300 m at 37 m: 22 lanes of 300 m across (the shortest path), each end pulled back
    # w/2 = 18.5 m, so the turns run 18.5 m inside the long sides.
    path = flown_sweep([RECT], 37.0)
    area = Polygon(RECT)
    assert path_length(path) == pytest.approx(22 * (300.0 - 37.0) + 21 * 800.0 / 22, rel=1e-9)
    assert path[:, 1].min() == pytest.approx(18.5) and path[:, 1].max() == pytest.approx(281.5)
    seen = footprint(path, 37.0)
    assert shapely.difference(area, seen).area < 1e-6 * area.area  # covered
    assert shapely.difference(seen, area).area < 0.01 * area.area  # (the outer lanes' margins)
    margin = area.buffer(37.0 / 2 - 800.0 / 44 + 1e-6, join_style="mitre")
    assert shapely.difference(seen, margin).area == pytest.approx(0.0, abs=1e-6)


def test_a_lane_shorter_than_its_pull_backs_shrinks_to_its_middle() -> None:
    cell = np.array([[[0.0, 0.0], [20.0, 0.0]], [[0.0, 30.0], [20.0, 30.0]]])
    out = turns_inside([cell], 37.0)[0]
    assert out[0, 0] == pytest.approx(out[0, 1])  # one point, inside the lane
    assert 0.0 < out[0, 0, 0] < 20.0
    assert len(turns_inside(sweep_cells(RECT, 37.0), 37.0)) == 1


def _parts(plan):  # type: ignore[no-untyped-def]
    return {n.node_uuid: region_of(search_polygons_xy(n, FRAME)) for n in leaves(plan.planned)}


def test_a_shared_rectangle_is_flown_inside_each_part_in_the_planned_time() -> None:
    units = [unit_at(f"dji{i}", "air", x, -1500.0) for i, x in enumerate((-800.0, 400.0, 1600.0))]
    poly = RECT * 2.0  # 1.6 km x 600 m: worth sharing among three drones
    tree = with_uuids(search_node(poly))
    plan = plan_mission(tree, units, strategy="auction")
    assert len(plan.shared) == 1 and len(plan.shared[0].parts) == 3
    parts = _parts(plan)
    flown = fly_plan(plan, units, FRAME)
    assert len(flown) == 3
    prints = []
    for f in flown:
        assert f.state == "finished"
        assert f.flown_s == pytest.approx(f.planned_s, rel=0.05)
        assert outside(f.track_xy, parts[f.node_uuid], 1.0) == 0.0  # within 1 m of its part
        prints.append(footprint(f.track_xy, sweep_width(units[0], 2.0)))
    cover, twice = swept(Polygon(poly), prints)
    assert cover > 0.995
    assert twice < 0.01


@pytest.mark.parametrize("name", ["U-0.5km2", "comb-1km2", "coast4-0.5km2"])
def test_concave_parts_are_flown_inside_in_the_planned_time(name: str) -> None:
    polys = concave_polygons()
    k = list(polys).index(name)
    units = fleet(10 * k, polys[name])
    tree = with_uuids(search_node(polys[name]))
    plan = plan_mission(tree, units, strategy="auction")
    assert plan.shared, "the family's areas are worth sharing"
    parts = _parts(plan)
    by_name = {u.name: u for u in units}
    for f in fly_plan(plan, units, FRAME):
        assert f.state == "finished"
        assert f.flown_s == pytest.approx(f.planned_s, rel=0.05)
        w = sweep_width(by_name[f.unit], 2.0)
        length = shapely.LineString(f.track_xy).length
        if f.name == "search-area":  # one piece: lanes, turns and transitions inside
            assert outside(f.track_xy, parts[f.node_uuid], 1.0) <= 1e-3 * length
        else:  # several pieces: the unit flies from one to the next
            assert outside(f.track_xy, parts[f.node_uuid], w / 2.0) <= 0.06 * length


def test_a_transition_across_a_notch_goes_round_it_inside_the_area() -> None:
    u = np.array([[0, 0], [300, 0], [300, 300], [200, 300], [200, 100], [100, 100], [100, 300],
                  [0, 300]], dtype=float)
    path = np.array([[50.0, 250.0], [50.0, 50.0], [250.0, 50.0], [250.0, 250.0], [50.0, 280.0]])
    routed = transitions_inside(path, u)
    area = Polygon(u)
    assert area.buffer(1e-6).covers(shapely.LineString(routed))
    # the last leg (across the notch) bends at the notch's two inner corners
    assert routed[-3:-1].tolist() == [[200.0, 100.0], [100.0, 100.0]]
    assert routed[:4].tolist() == path[:4].tolist()  # legs inside are kept
    assert transitions_inside(path[:4], u).tolist() == path[:4].tolist()


def test_a_sweep_starts_at_the_end_nearest_the_unit() -> None:
    # Issue 21: not at a fixed corner. From near each corner of the rectangle the sweep starts
    # at that corner's lane end; every way has the same lanes, so the same length.
    ways = flown_ways([RECT], 37.0)
    assert len(ways) == 4
    lengths = {round(path_length(w), 6) for w in ways}
    assert len(lengths) == 1
    for corner in RECT:
        here = corner + np.sign(corner - RECT.mean(axis=0)) * 500.0
        path = flown_sweep([RECT], 37.0, near=here)
        starts = [np.hypot(*(w[0] - here)) for w in ways]
        assert np.hypot(*(path[0] - here)) == pytest.approx(min(starts))
        assert np.hypot(*(path[0] - corner)) < 37.0 * 1.5  # (its lane end, pulled inside)


def test_the_way_costs_least_flight_there_plus_sweep() -> None:
    ends = [(0.0, 0.0, 9.0, 9.0, 1000.0), (100.0, 0.0, 9.0, 9.0, 1000.0),
            (100.0, 0.0, 9.0, 9.0, 900.0)]
    assert pick_way(ends, (100.0, 0.0)) == 2  # nearer and shorter
    assert pick_way(ends, (-200.0, 0.0)) == 0  # 200 m nearer than the 100 m shorter one
    assert pick_way(ends, None) == 2  # from nowhere: the shortest
    tie = [(0.0, 0.0, 0.0, 0.0, 1000.0), (0.0, 0.0, 0.0, 0.0, 999.5)]
    assert pick_way(tie, (5.0, 5.0)) == 0  # (within WAY_TIE_M: the first listed)


def test_a_unit_sweeping_two_areas_flies_each_from_where_it_is_as_planned() -> None:
    # One drone, two searches in a seq: the second sweep starts at the way nearest to where
    # the first one ended (not where the drone was at the start), in the plan and in flight.
    drone = unit_at("dji0", "air", -2000.0, -1500.0)
    west, east = RECT + np.array([-400.0, 0.0]), RECT + np.array([500.0, -1400.0])
    tree = with_uuids(make_node("seq", children=[search_node(west), search_node(east)]))
    plan = plan_mission(tree, [drone], strategy="auction")
    assert plan.feasible and len(plan.assignments) == 2
    flown = fly_plan(plan, [drone], FRAME)
    for f, a in zip(flown, plan.routes["dji0"], strict=True):
        assert f.state == "finished"
        assert f.flown_s == pytest.approx(f.planned_s, rel=1e-3)
        assert f.flown_travel_s == pytest.approx(a.travel_time, rel=1e-3, abs=0.5)
    # the second sweep starts at the way nearest to the first one's end
    first_end = flown[0].track_xy[-1]
    ways = flown_ways([east], sweep_width(drone, 2.0))
    nearest = min(ways, key=lambda w: float(np.hypot(*(w[0] - first_end))))
    assert np.hypot(*(flown[1].track_xy[0] - nearest[0])) < 1.0
    # (which is not the way it would fly from where it started: its top end, not its bottom)
    start = FRAME.point_xy(drone.position)
    assert np.hypot(*(nearest[0] - min(ways, key=lambda w: float(np.hypot(*(w[0] - start))))[0])
                    ) > 200.0


def test_the_map_draws_each_sweep_from_where_the_unit_flies_it() -> None:
    # The map's planned route (render.mapplot.planned_route) draws the second of two searches
    # from the end the unit flies it from (where the first search left it, not where it
    # started): the route drawn is as long as the plan's distances, connector included.
    drone = unit_at("dji0", "air", -2000.0, -1500.0)
    west, east = RECT + np.array([-400.0, 0.0]), RECT + np.array([500.0, -1400.0])
    tree = with_uuids(make_node("seq", children=[search_node(west), search_node(east)]))
    data = plan_mission(tree, [drone], strategy="auction").to_json()
    nodes = {n.node_uuid: n for n in leaves(tree)}
    route = planned_route(data["assignments"], drone, nodes)
    if drone.home is not None:
        route = route[:-1]
    drawn = path_length(np.array([FRAME.point_xy(p) for p in route]))
    assert drawn == pytest.approx(sum(a["distance"] for a in data["assignments"]), abs=1.0)
