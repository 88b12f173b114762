"""The cost model (docs/plan.md §2): coverage paths, speeds, sweep widths, the cost tables."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from shapely.geometry import LineString, MultiPoint, Point, Polygon

from delegation.costs import (
    LAND_TIME_S,
    TAKE_OFF_TIME_S,
    cost_tables,
    coverage_length,
    coverage_path,
    sweep_width,
    task_path,
    unit_speed,
)
from delegation.coverage import (
    circle_polygon,
    coverage_estimate,
    flown_sweep,
    multi_coverage_path,
    path_length,
    sweep_axes,
    sweep_lanes,
)
from delegation.errors import InputError
from delegation.fleet import DEFAULT_SPEEDS, UnitState, make_unit
from delegation.geo import GeoPoint, LocalFrame, distance_m, haversine_m, path_length_m
from delegation.tst import make_node

GRANSO = LocalFrame(57.76, 16.68)

SQUARE_1KM = np.array([[0.0, 0.0], [1000.0, 0.0], [1000.0, 1000.0], [0.0, 1000.0]])
CONVEX = {
    "triangle": np.array([[0.0, 0.0], [800.0, 100.0], [300.0, 600.0]]),
    "pentagon": np.array(
        [[0.0, 0.0], [500.0, -200.0], [900.0, 300.0], [400.0, 700.0], [-100.0, 400.0]]
    ),
    "parallelogram": np.array([[0.0, 0.0], [2000.0, 300.0], [2100.0, 700.0], [100.0, 400.0]]),
    "circle": circle_polygon((250.0, -40.0), 300.0),
}


def rotate(poly: np.ndarray, degrees: float) -> np.ndarray:
    a = math.radians(degrees)
    r = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    return np.asarray(poly @ r.T)


def wire(x: float, y: float, alt: float = 0.0) -> dict[str, object]:
    return GRANSO.geopoint(x, y, alt).to_wire()


def unit(
    name: str = "dji0", x: float = 0.0, y: float = 0.0, tasks: tuple[str, ...] = (), **kw: object
) -> UnitState:
    offered = tasks or (
        "move-to",
        "move-path",
        "search-area",
        "search-areas",
        "search-around-position",
        "observe-position",
        "look-at-position",
        "go-home",
        "take-off",
        "land",
    )
    return make_unit(name, str(kw.pop("agent_type", "air")), GRANSO.geopoint(x, y), offered, **kw)  # type: ignore[arg-type]


# --------------------------------------------------------------------------- coverage geometry


def test_one_km_square_at_50_m_is_20950_m() -> None:
    length = coverage_length(SQUARE_1KM, 50.0)
    assert length == pytest.approx(20_950.0, rel=0.02)
    assert len(sweep_lanes(SQUARE_1KM, 50.0)) == 20


def test_one_km_square_through_the_cost_tables_in_a_real_frame() -> None:
    # A unit whose footprint is exactly 50 m: 2 h tan(30 deg) (1 - 0.2) = 50.
    h = 50.0 / (2.0 * math.tan(math.radians(30.0)) * 0.8)
    drone = unit(sweep_altitude=h, camera_fov_deg=60.0)
    assert sweep_width(drone, 2.0) == pytest.approx(50.0)
    area = [wire(100, 100), wire(1100, 100), wire(1100, 1100), wire(100, 1100)]
    node = make_node("search-area", params={"area": area, "speed": "standard", "target-size": 2.0})
    tables = cost_tables([drone], [node], frame=GRANSO)
    # As flown, turns 25 m inside the area (issue 21): 20 lanes of 950 m and 19 turns of 50 m.
    assert tables.work_distance[0, 0] == pytest.approx(19_950.0, rel=0.02)
    assert tables.work_time[0, 0] == pytest.approx(
        tables.work_distance[0, 0] / drone.speeds["standard"]
    )


@pytest.mark.parametrize("name", sorted(CONVEX))
def test_coverage_length_is_the_built_path_and_near_the_estimate(name: str) -> None:
    poly = CONVEX[name]
    for width in (5.0, 8.0):
        path = coverage_path(poly, width)
        assert coverage_length(poly, width) == pytest.approx(path_length(path), rel=1e-12)
        assert path_length(path) == pytest.approx(coverage_estimate(poly, width), rel=0.02)


@pytest.mark.parametrize("name", sorted(CONVEX))
@pytest.mark.parametrize("width", [10.0, 37.0])
def test_the_path_covers_the_polygon_and_stays_inside(name: str, width: float) -> None:
    poly = CONVEX[name]
    shape = Polygon(poly)
    path = coverage_path(poly, width)
    inside = shape.buffer(1e-6)
    assert all(inside.contains(Point(p)) for p in path)
    covered = LineString(path).buffer(width / 2.0 * 1.0001, cap_style="flat").intersection(shape)
    assert covered.area / shape.area > 0.99


def test_sweep_runs_along_the_long_axis_whatever_the_rotation() -> None:
    rect = np.array([[0.0, 0.0], [1000.0, 0.0], [1000.0, 200.0], [0.0, 200.0]])
    for degrees in (0.0, 30.0, 90.0, 137.0):
        lanes = sweep_lanes(rotate(rect, degrees), 40.0)
        assert len(lanes) == 5  # 200 m across / 40 m, not 1000 / 40
        lengths = np.hypot(*(lanes[:, 1] - lanes[:, 0]).T)
        assert lengths == pytest.approx(np.full(5, 1000.0), rel=1e-9)
        assert coverage_length(rotate(rect, degrees), 40.0) == pytest.approx(5 * 1000.0 + 4 * 40.0)


def test_path_alternates_direction_and_starts_and_ends_on_lane_ends() -> None:
    lanes = sweep_lanes(SQUARE_1KM, 250.0)
    path = coverage_path(SQUARE_1KM, 250.0)
    assert len(path) == 2 * len(lanes)
    assert path[0] == pytest.approx(lanes[0][0])
    assert path[1] == pytest.approx(lanes[0][1])
    assert path[2] == pytest.approx(lanes[1][1])  # second lane flown backwards
    assert path[-1] == pytest.approx(lanes[-1][1] if len(lanes) % 2 else lanes[-1][0])


def test_width_wider_than_the_area_gives_one_lane() -> None:
    path = coverage_path(SQUARE_1KM, 5000.0)
    assert len(path) == 2
    assert path_length(path) == pytest.approx(1000.0)


def test_bad_widths_and_polygons_are_input_errors() -> None:
    with pytest.raises(InputError, match="width"):
        coverage_path(SQUARE_1KM, 0.0)
    with pytest.raises(InputError, match="width"):
        coverage_length(SQUARE_1KM, float("nan"))
    with pytest.raises(InputError, match="at least 3"):
        coverage_path(np.array([[0.0, 0.0], [1.0, 1.0]]), 10.0)
    with pytest.raises(InputError, match="too small"):
        coverage_path(SQUARE_1KM * 100.0, 0.1)


def test_closed_rings_are_accepted() -> None:
    closed = np.vstack([SQUARE_1KM, SQUARE_1KM[:1]])
    assert coverage_length(closed, 50.0) == pytest.approx(coverage_length(SQUARE_1KM, 50.0))


def test_multi_area_path_joins_the_areas() -> None:
    a = SQUARE_1KM / 10.0
    b = a + np.array([500.0, 0.0])
    path = multi_coverage_path([a, b], 20.0)
    alone = coverage_length(a, 20.0) + coverage_length(b, 20.0)
    assert path_length(path) > alone  # plus the connector between them
    assert path_length(path) < alone + 500.0 + 100.0
    assert path[0] == pytest.approx(coverage_path(a, 20.0)[0])


# --------------------------------------------------------------------------- speeds and widths


def test_unit_speed_classes_explicit_and_defaults() -> None:
    u = unit(speeds={"slow": 2.0, "standard": 5.0, "fast": 9.0})
    assert unit_speed(u, "slow") == 2.0
    assert unit_speed(u, "fast") == 9.0
    assert unit_speed(u, None) == 5.0
    assert unit_speed(u, 7.0) == 7.0
    assert unit_speed(u, [7.0]) == 7.0  # the seed's observe-position example
    assert unit_speed(u, 50.0) == 9.0  # capped at fast
    for bad in ("warp", -1.0, True, {"x": 1}):
        with pytest.raises(InputError, match="speed"):
            unit_speed(u, bad)


def test_default_speeds_per_type_fill_missing_classes() -> None:
    assert unit(agent_type="ground").speeds == DEFAULT_SPEEDS["ground"]
    scaled = unit(speeds={"standard": 6.0})  # air default standard is 3.0: twice as fast
    assert scaled.speeds == {"slow": 3.0, "standard": 6.0, "fast": 12.0}


def test_sweep_width_from_footprint_and_target_size() -> None:
    drone = unit(sweep_altitude=40.0, camera_fov_deg=60.0)
    footprint = 2 * 40.0 * math.tan(math.radians(30.0)) * 0.8
    assert sweep_width(drone, 2.0) == pytest.approx(footprint)
    assert sweep_width(drone, 0.25) == pytest.approx(0.25 * 1280 / 16)  # detection-limited
    higher = unit(sweep_altitude=80.0, camera_fov_deg=60.0)
    assert sweep_width(higher, 2.0) == pytest.approx(2 * footprint)
    with pytest.raises(InputError, match="target-size"):
        sweep_width(drone, 0.0)


# --------------------------------------------------------------------------- the tables


def test_distances_match_pymap3d_geodesics() -> None:
    rng = np.random.default_rng(3)
    units = [unit(f"u{i}", *rng.uniform(-15000, 15000, 2)) for i in range(5)]
    tasks = [
        make_node("move-to", params={"waypoint": wire(*rng.uniform(-15000, 15000, 2))})
        for _ in range(7)
    ]
    tables = cost_tables(units, tasks)
    d = tables.dist_unit_to_start()
    for i, u in enumerate(units):
        for j, t in enumerate(tasks):
            geo = distance_m(u.position, GeoPoint.model_validate(t.params["waypoint"]))
            assert d[i, j] == pytest.approx(geo, rel=1e-3)
    between = tables.dist_end_to_start()
    for i, a in enumerate(tasks):
        for j, b in enumerate(tasks):
            pa, pb = (GeoPoint.model_validate(n.params["waypoint"]) for n in (a, b))
            assert between[i, j] == pytest.approx(distance_m(pa, pb), rel=1e-3, abs=1e-6)
            # and the spherical cross-check agrees to the ellipsoid's flattening
            assert between[i, j] == pytest.approx(
                haversine_m(pa.latitude, pa.longitude, pb.latitude, pb.longitude),
                rel=5e-3,
                abs=1e-6,
            )


def test_work_per_task_type() -> None:
    drone = unit(home=GRANSO.geopoint(-300, 0), speeds={"slow": 2.0, "standard": 4.0, "fast": 8.0})
    path_pts = [wire(0, 100), wire(300, 100), wire(300, 500)]
    tasks = [
        make_node("move-to", params={"waypoint": wire(400, 300), "speed": "fast"}),
        make_node("move-path", params={"waypoints": path_pts, "speed": "standard"}),
        make_node("observe-position", params={"geopoint": wire(10, 10), "duration": 45}),
        make_node("observe-position", params={"geopoint": wire(10, 10), "duration": -1}),
        make_node("look-at-position", params={"geopoint": wire(900, 900)}),
        make_node("go-home", params={"speed": "slow"}),
        make_node("take-off"),
        make_node("land", params={"p": wire(50, 0)}),
        make_node("search-around-position", params={"geopoint": wire(-500, -500), "radius": 100.0}),
    ]
    t = cost_tables([drone], tasks, frame=GRANSO)
    # move-to: no work, travel at fast
    assert t.work_time[0, 0] == 0.0 and t.speed[0, 0] == 8.0
    assert t.dist_unit_to_start()[0, 0] == pytest.approx(500.0, rel=1e-4)
    # move-path: polyline length / speed; starts at the first, ends at the last waypoint
    assert t.work_distance[0, 1] == pytest.approx(700.0, rel=1e-4)
    assert t.work_time[0, 1] == pytest.approx(700.0 / 4.0, rel=1e-4)
    assert t.start_xy[1] == pytest.approx([0.0, 100.0], abs=0.01)
    assert t.end_xy[1] == pytest.approx([300.0, 500.0], abs=0.01)
    # observe-position: duration, or open-ended
    assert t.work_time[0, 2] == 45.0 and not t.open_ended[2]
    assert t.open_ended[3] and t.work_time[0, 3] == 0.0
    # look-at: no travel, open-ended
    assert not t.travels[4] and t.open_ended[4]
    assert t.dist_unit_to_start()[0, 4] == 0.0
    assert t.start_for(0, 4) is None
    # go-home: travel to the unit's home
    assert t.dist_unit_to_start()[0, 5] == pytest.approx(300.0, rel=1e-4)
    assert t.end_for(0, 5) == pytest.approx([-300.0, 0.0], abs=0.01)
    assert t.speed[0, 5] == 2.0
    # take-off in place, land at p
    assert t.work_time[0, 6] == TAKE_OFF_TIME_S and not t.travels[6]
    assert t.work_time[0, 7] == LAND_TIME_S and t.travels[7]
    # search-around-position: a sweep of the circle, starting and ending on the sweep
    circle = circle_polygon((-500.0, -500.0), 100.0)
    w = sweep_width(drone, 2.0)
    assert t.work_distance[0, 8] == pytest.approx(path_length(flown_sweep([circle], w)), rel=1e-3)
    assert Polygon(circle).buffer(0.5).contains(Point(t.start_xy[8]))
    assert t.capable.all()


@pytest.mark.parametrize(
    ("flags", "open_ended"),
    [({}, False), ({"loop-flag": False, "hold-flag": False}, False),
     ({"continue-flag": True}, False), ({"loop-flag": True}, True), ({"hold-flag": True}, True),
     ({"loop-flag": True, "hold-flag": True}, True)],
    ids=["plain", "flags-false", "continue", "loop", "hold", "both"],
)
def test_navigate_loops_or_holds_until_enough(flags: dict[str, bool], open_ended: bool) -> None:
    """Seed 9.14: navigate with loop-flag loops the waypoints, with hold-flag holds after them,
    until $enough: open-ended (travel to the first waypoint counts), not done at the last."""
    drone = unit(tasks=("navigate",), speeds={"slow": 2.0, "standard": 4.0, "fast": 8.0})
    pts = [wire(0, 100), wire(300, 100), wire(300, 500)]
    t = cost_tables([drone], [make_node("navigate", params={"waypoints": pts, **flags})],
                    frame=GRANSO)
    assert bool(t.open_ended[0]) is open_ended
    assert t.dist_unit_to_start()[0, 0] == pytest.approx(100.0, rel=1e-4)
    if open_ended:
        assert t.work_time[0, 0] == 0.0
    else:
        assert t.work_time[0, 0] == pytest.approx(700.0 / 4.0, rel=1e-4)


def test_dist_semantics_for_in_place_and_home_tasks() -> None:
    drone = unit(home=GRANSO.geopoint(100, 0))
    tasks = [
        make_node("move-to", params={"waypoint": wire(0, 200)}),
        make_node("look-at-position", params={"geopoint": wire(0, 0)}),
        make_node("go-home"),
    ]
    t = cost_tables([drone], tasks, frame=GRANSO)
    between = t.dist_end_to_start()
    assert between.shape == (3, 3)
    assert between[0, 1] == 0.0  # a look-at starts where the unit is
    assert np.isnan(between[1, 0])  # after a look-at the unit is where it was before
    assert np.isnan(between[0, 2])  # go-home's start depends on the unit
    home = t.dist_end_to_home()
    assert home.shape == (3, 1)
    assert home[0, 0] == pytest.approx(math.hypot(100.0, 200.0), rel=1e-4)
    assert home[2, 0] == 0.0


def test_capability_reasons() -> None:
    units = [
        unit("dji0", tasks=("move-to",)),
        unit("dji1", alive=False),
        unit("dji2", battery=0.1, endurance=1000.0),  # 100 s at 3 m/s: 300 m
        unit("dji3", busy=True),
        unit("dji4", battery=0.5, endurance=1000.0, home=GRANSO.geopoint(0, -400)),
    ]
    near = make_node("move-to", params={"waypoint": wire(0, 250)})
    far = make_node("move-to", params={"waypoint": wire(0, 600)})
    search = make_node("search-area", params={"area": [wire(0, 0), wire(50, 0), wire(50, 50)]})
    t = cost_tables(units, [near, far, search], frame=GRANSO)
    assert t.capable[0, 0] and not t.capable[0, 2]
    assert "does not offer search-area" in (t.reason(0, 2) or "")
    assert "not alive" in (t.reason(1, 0) or "")
    assert t.capable[2, 0] and not t.capable[2, 1]
    assert "endurance" in (t.reason(2, 1) or "")
    assert t.capable[3, 0]  # busy units may be planned offline ...
    busy = cost_tables(units, [near], frame=GRANSO, exclude_busy=True)
    assert not busy.capable[3, 0] and "busy" in (busy.reason(3, 0) or "")  # ... not live
    # dji4: 500 s at 3 m/s = 1500 m; 600 out and 1000 back is too far, 250 + 650 is fine
    assert t.capable[4, 0] and not t.capable[4, 1]
    assert "way home" in (t.reason(4, 1) or "")
    assert t.need_time[4, 1] == pytest.approx((600.0 + 1000.0) / 3.0, rel=1e-3)
    assert t.reason(0, 0) is None


def test_task_path_for_simulators_matches_the_tables() -> None:
    drone = unit()
    area = [wire(100, 100, 40.0), wire(400, 120, 40.0), wire(380, 300, 40.0), wire(90, 280, 40.0)]
    node = make_node("search-area", params={"area": area, "target-size": 2.0})
    pts = task_path(node, drone)
    geo_len = path_length_m(pts)
    t = cost_tables([drone], [node])
    assert geo_len == pytest.approx(t.work_distance[0, 0], rel=2e-3)
    assert distance_m(pts[0], t.frame.geopoint(*t.start_xy[0])) < 1.0
    assert all(p.altitude == 40.0 for p in pts)
    path = make_node("move-path", params={"waypoints": area[:2]})
    assert task_path(path, drone) == [GeoPoint.model_validate(a) for a in area[:2]]


def test_search_width_depends_on_the_unit() -> None:
    low = unit("low", sweep_altitude=20.0)
    high = unit("high", sweep_altitude=80.0)
    area = [wire(0, 0), wire(600, 0), wire(600, 400), wire(0, 400)]
    t = cost_tables([low, high], [make_node("search-area", params={"area": area})], frame=GRANSO)
    assert t.width[0, 0] == pytest.approx(t.width[1, 0] / 4.0)
    assert t.work_distance[0, 0] > 3.0 * t.work_distance[1, 0]
    # the narrowest sweep fixes the task's start and end points
    low_path = flown_sweep(
        [GRANSO.points_xy([GeoPoint.model_validate(a) for a in area])], t.width[0, 0]
    )
    assert t.end_xy[0] == pytest.approx(low_path[-1], abs=0.01)


def test_each_unit_starts_a_search_where_its_own_sweep_starts() -> None:
    """Issue 21: the plan's travel to a search is to where that unit's sweep starts (its width
    sets the lanes), and the checker, which rebuilds the tables from the tree sent, agrees."""
    from delegation.allocation import check_invariants, plan_mission
    from delegation.allocation.problem import build_problem
    from delegation.allocation.schedule import evaluate

    low = unit("low", x=-300.0, y=-200.0, sweep_altitude=20.0)
    high = unit("high", x=900.0, y=700.0, sweep_altitude=80.0)
    area = [wire(0, 0, 30.0), wire(600, 0, 30.0), wire(600, 410, 30.0), wire(0, 410, 30.0)]
    node = make_node("search-area", params={"area": area})
    t = cost_tables([low, high], [node], frame=GRANSO)
    for u, who in enumerate((low, high)):
        path = GRANSO.points_xy(task_path(node, who, GRANSO))
        assert t.start_for(u, 0) == pytest.approx(path[0], abs=0.01)
        assert t.end_for(u, 0) == pytest.approx(path[-1], abs=0.01)
    assert float(np.hypot(*(t.end_for(0, 0) - t.end_for(1, 0)))) > 20.0  # the ends differ
    problem = build_problem(make_node("seq", children=[node]), [low, high], t)
    schedule = evaluate(problem, np.array([1]), [[], [0]])
    want = float(np.hypot(*(t.start_for(1, 0) - t.unit_xy[1]))) / float(t.speed[1, 0])
    assert schedule.travel_time[0] == pytest.approx(want, rel=1e-9)
    fixed = make_node("seq", children=[make_node("search-area", params={"area": area},
                                                 execunit="/high")])
    plan = plan_mission(fixed, [low, high], strategy="auction")
    assert plan.feasible and check_invariants(plan, fixed, [low, high]) == []


def test_a_task_costed_for_one_unit_alone() -> None:
    """``cost_tables(only=...)`` (a shared search's part, fixed to its unit; issue 21): that
    unit's figures are those of the full tables, its sweep's ends are the task's reference
    points, no other unit is swept or may take it, and the reason says why."""
    low = unit("low", x=-300.0, y=-200.0, sweep_altitude=20.0)
    high = unit("high", x=900.0, y=700.0, sweep_altitude=80.0)
    area = [wire(0, 0, 30.0), wire(600, 0, 30.0), wire(600, 410, 30.0), wire(0, 410, 30.0)]
    tasks = [make_node("search-area", params={"area": area}),
             make_node("move-to", params={"waypoint": wire(100, 100)})]
    full = cost_tables([low, high], tasks, frame=GRANSO)
    one = cost_tables([low, high], tasks, frame=GRANSO, only={0: 1})
    for table in ("work_distance", "work_time", "need_time", "capable"):
        assert getattr(one, table)[1, 0] == getattr(full, table)[1, 0], table
        np.testing.assert_array_equal(getattr(one, table)[:, 1], getattr(full, table)[:, 1])
    assert one.capable[1, 0] and full.capable[0, 0] and not one.capable[0, 0]
    assert one.work_distance[0, 0] == math.inf and one.need_time[0, 0] == math.inf
    np.testing.assert_array_equal(one.start_for(1, 0), full.start_for(1, 0))
    np.testing.assert_array_equal(one.end_for(1, 0), full.end_for(1, 0))
    # (the full tables' reference points are the narrowest sweep's, low's; these high's own)
    np.testing.assert_array_equal(one.start_xy[0], full.start_for(1, 0))
    assert not np.allclose(full.end_xy[0], full.end_for(1, 0))
    np.testing.assert_array_equal(one.width, full.width)
    assert one.reason(0, 0) == "low was not costed for search-area: it is high's alone"
    assert one.reason(1, 0) is None and full.only == {} and one.only == {0: 1}


def test_large_tables_are_consistent() -> None:
    rng = np.random.default_rng(0)
    units = [
        unit(
            f"u{i}",
            *rng.uniform(-3000, 3000, 2),
            tasks=("move-to",) if i % 2 else ("move-to", "move-path"),
        )
        for i in range(200)
    ]
    tasks = [
        make_node("move-to", params={"waypoint": wire(*rng.uniform(-5000, 5000, 2))})
        for _ in range(995)
    ]
    tasks += [
        make_node("move-path", params={"waypoints": [wire(0, 0), wire(100, 0)], "speed": "fast"})
        for _ in range(5)
    ]
    t = cost_tables(units, tasks, frame=GRANSO)
    assert t.speed.shape == t.capable.shape == (200, 1000)
    assert t.capable[:, :995].all()
    assert (t.capable[:, 995:] == np.array([i % 2 == 0 for i in range(200)])[:, None]).all()
    d = t.dist_unit_to_start()
    assert d[17, 420] == pytest.approx(float(np.hypot(*(t.unit_xy[17] - t.start_xy[420]))))


@settings(max_examples=60, deadline=None)
@given(
    # (Millimetres: GEOS's minimum_rotated_rectangle, the reference below, collapses a hull with
    # vertices 1e-246 m apart to a zero-width rectangle; hypothesis found it.)
    points=st.lists(st.tuples(*[st.floats(-2000, 2000).map(lambda v: round(v, 3))] * 2),
                    min_size=3, max_size=12),
    width=st.floats(5.0, 400.0),
)
def test_coverage_properties_on_random_convex_polygons(
    points: list[tuple[float, float]], width: float
) -> None:
    hull = MultiPoint(points).convex_hull
    assume(isinstance(hull, Polygon) and hull.area > 1000.0)
    poly = np.asarray(hull.exterior.coords)[:-1]
    long_axis = sweep_axes(poly)[0]
    lanes = sweep_lanes(poly, width, along=long_axis)
    path = coverage_path(poly, width, along=long_axis)
    # the chosen direction is never worse than the long axis, and covers the polygon as well
    chosen = coverage_path(poly, width)
    assert path_length(chosen) <= path_length(path) + 1e-6
    assert all(hull.buffer(1e-6).contains(Point(p)) for p in chosen)
    # along the long axis: as many lanes as strips of at most `width` across the minimum rotated
    # rectangle
    rect = hull.minimum_rotated_rectangle.exterior.coords
    sides = sorted(math.dist(rect[i], rect[i + 1]) for i in range(2))
    assert len(lanes) == max(1, math.ceil(sides[0] / width - 1e-9))
    # every lane ends on the boundary and the path never leaves the polygon
    ends = lanes.reshape(-1, 2)
    assert max(hull.exterior.distance(Point(p)) for p in ends) < 1e-6
    assert all(hull.buffer(1e-6).contains(Point(p)) for p in path)
    # lanes are parallel and the length is the path's
    directions = lanes[:, 1] - lanes[:, 0]
    long_enough = np.hypot(*directions.T) > 1e-6
    unit_dirs = directions[long_enough] / np.hypot(*directions[long_enough].T)[:, None]
    assert np.allclose(np.abs(unit_dirs @ unit_dirs[0]), 1.0)
    assert coverage_length(poly, width, along=long_axis) == pytest.approx(path_length(path))


def test_route_costs_use_each_units_own_search_ends() -> None:
    """Issue 21: the auction's first bids, its insertion costs, the routes' times and the
    schedule agree where searches start and end per unit."""
    from delegation.allocation.auction import auction
    from delegation.allocation.auction.improve import route_time
    from delegation.allocation.problem import build_problem
    from delegation.allocation.routes import first_insertion_costs, insertion_costs
    from delegation.bench.generate import generate_scenario
    from delegation.scenario import scenario_from_dict
    from delegation.tst import with_defaults, with_uuids

    scenario = scenario_from_dict(generate_scenario(units=10, tasks=30, seed=0,
                                                    structure="mixed"))
    problem = build_problem(with_defaults(with_uuids(scenario.tree())), scenario.units())
    assert problem.unit_start_xy is not None  # some unit's sweep starts elsewhere
    first = first_insertion_costs(problem)
    assert first is not None
    for u in range(problem.n_units):
        alone = insertion_costs(problem, u, [], np.arange(problem.n_tasks))[0]
        assert first[u] == pytest.approx(alone, rel=1e-9, abs=1e-9)
    schedule = auction(problem, "makespan")
    # Each sweep flown as from the unit's position (the insertion costs' estimate).
    fixed = dataclasses.replace(problem, sweep_ways={}, cache={})
    rng = np.random.default_rng(0)
    for u, route in enumerate(schedule.orders):
        spent = sum(float(schedule.travel_time[t] + schedule.work_time[t]) for t in route)
        home = 0.0
        if route and problem.has_home[u]:
            assert schedule.end_xy is not None
            home = float(np.hypot(*(problem.home_xy[u] - schedule.end_xy[route[-1]]))
                         / problem.home_speed[u])
        assert route_time(problem, u, list(route)) == pytest.approx(spent + home, abs=1e-6)
        for t in rng.choice(np.flatnonzero(problem.vehicle), 5).tolist():
            if t in route:
                continue
            k = int(rng.integers(len(route) + 1))
            added = route_time(fixed, u, [*route[:k], t, *route[k:]]) - route_time(
                fixed, u, list(route))
            cost = insertion_costs(problem, u, list(route), np.array([t]))[k, 0]
            assert added == pytest.approx(cost, abs=1e-6)
