"""Searching as a team (DESIGN 3.11): one area shared among units, inside the allocation.

Pure logic: no clock, no network.
"""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest
import shapely

from delegation.allocation import check_invariants, plan_mission
from delegation.allocation.sharing import (
    MIN_SHARE,
    Sharer,
    band,
    divide,
    extent,
    fill_time,
    lower_bound,
    pieces_xy,
    region_of,
    shares,
    thinness,
)
from delegation.fleet import make_unit
from delegation.geo import GeoPoint, LocalFrame
from delegation.tst import leaves, make_node, walk
from delegation.tst.validate import validate_tree

FRAME = LocalFrame(57.76, 16.68)
TASKS = ("move-to", "move-path", "search-area", "search-areas", "search-around-position")

#: A comb (three teeth, 1 km2 at this scale) and a coastline-like polygon with two bays.
COMB = 200.0 * np.array([[0, 0], [5, 0], [5, 3], [4, 3], [4, 1], [3, 1], [3, 3], [2, 3], [2, 1],
                         [1, 1], [1, 3], [0, 3]], dtype=float)
_ANGLES = np.linspace(0.0, 2.0 * np.pi, 40, endpoint=False)
_RADII = 800.0 * (1.0 - 0.35 * np.exp(-((_ANGLES - 1.0) / 0.3) ** 2)
                  - 0.3 * np.exp(-((_ANGLES - 4.0) / 0.25) ** 2))
COAST = np.column_stack([1.3 * _RADII * np.cos(_ANGLES), _RADII * np.sin(_ANGLES)])
SHAPES = {"comb": COMB, "coast": COAST}


def geo(x: float, y: float, altitude: float = 40.0) -> dict[str, float]:
    lat, lon = FRAME.to_geo(x, y)
    return {"latitude": float(lat), "longitude": float(lon), "altitude": altitude}


def unit(name: str, kind: str, x: float, y: float, **kw: object):  # type: ignore[no-untyped-def]
    lat, lon = FRAME.to_geo(x, y)
    point = GeoPoint(latitude=float(lat), longitude=float(lon), altitude=0.0)
    return make_unit(name, kind, point, TASKS, **kw)  # type: ignore[arg-type]


def fleet(**kw: object) -> list:  # type: ignore[type-arg]
    drones = [unit(f"dji{i}", "air", -1600.0 + 150.0 * i, -1300.0, **kw) for i in range(4)]
    return [*drones, unit("usv0", "surface", -1200.0, 900.0, **kw)]


def search(poly: np.ndarray, execunit: str = "*", **extra: object):  # type: ignore[no-untyped-def]
    params = {"area": [geo(x, y) for x, y in poly], "speed": "standard", "target-size": 2.0,
              "target-type": "person", **extra}
    return make_node("search-area", execunit=execunit, params=params)


# --------------------------------------------------------------------------- how much


def test_equal_units_get_equal_shares_and_end_together() -> None:
    sharers = [Sharer(k, 0.0, 10.0) for k in range(4)]
    got = shares(4000.0, sharers)
    assert got == pytest.approx({k: 1000.0 for k in range(4)})
    assert fill_time(4000.0, sharers) == pytest.approx(100.0)


def test_a_unit_busy_elsewhere_gets_less_and_one_busy_too_long_none() -> None:
    sharers = [Sharer(0, 0.0, 10.0), Sharer(1, 50.0, 10.0), Sharer(2, 1000.0, 10.0)]
    got = shares(3000.0, sharers)
    t = fill_time(3000.0, sharers)
    assert t == pytest.approx(175.0)  # 10 (t) + 10 (t - 50) = 3000
    assert got[0] == pytest.approx(1750.0) and got[1] == pytest.approx(1250.0)
    assert 2 not in got


def test_endurance_caps_a_part_and_the_others_make_up_for_it() -> None:
    sharers = [Sharer(0, 0.0, 10.0, cap=500.0), Sharer(1, 0.0, 10.0)]
    got = shares(3000.0, sharers)
    assert got[0] == pytest.approx(500.0) and got[1] == pytest.approx(2500.0)
    assert shares(3000.0, [Sharer(0, 0.0, 10.0, cap=1000.0), Sharer(1, 0.0, 1.0, cap=1000.0)]) == {}


def test_no_sliver_part() -> None:
    # The slow unit would get 1 %: it is left out and the others share everything.
    got = shares(1e6, [Sharer(0, 0.0, 100.0), Sharer(1, 0.0, 100.0), Sharer(2, 0.0, 2.0)])
    assert set(got) == {0, 1}
    assert sum(got.values()) == pytest.approx(1e6)
    assert min(got.values()) >= MIN_SHARE * 1e6


def test_the_bound_ignores_caps() -> None:
    sharers = [Sharer(0, 0.0, 10.0, cap=1.0), Sharer(1, 20.0, 10.0)]
    assert lower_bound(1000.0, sharers) == pytest.approx(60.0)  # 10 T + 10 (T - 20) = 1000


# --------------------------------------------------------------------------- where


@pytest.mark.parametrize("name", sorted(SHAPES))
@pytest.mark.parametrize("n", [2, 3, 5, 6])
def test_parts_cover_the_area_inside_without_overlap_or_slivers(name: str, n: int) -> None:
    region = region_of([SHAPES[name]])
    rng = np.random.default_rng(n)
    wanted = {k: float(w) for k, w in enumerate(rng.uniform(0.6, 1.4, n) * region.area / n)}
    points = {k: (float(x), float(y)) for k, (x, y) in enumerate(rng.uniform(-3e3, 3e3, (n, 2)))}
    parts = divide(region, wanted, points)
    assert set(parts) == set(wanted)
    union = shapely.union_all(list(parts.values()))
    assert abs(union.area - region.area) <= 0.005 * region.area
    assert shapely.difference(union, region.buffer(1e-6)).area <= 1e-6 * region.area
    assert sum(p.area for p in parts.values()) - union.area <= 1e-6 * region.area
    total = sum(wanted.values())
    for k, part in parts.items():
        assert part.area == pytest.approx(wanted[k] / total * region.area, rel=1e-3)
        assert thinness(part) >= 3 * 37.0  # thicker than three drone lanes
        assert len(pieces_xy(part)) <= 2  # contiguous, or (a cut through a tooth) two pieces


@pytest.mark.parametrize("angle", [0.0, 0.7, 2.0])
def test_cut_along_one_axis_in_a_given_order_gives_strips_in_that_order(angle: float) -> None:
    region = region_of([COAST])
    axis = np.array([math.cos(angle), math.sin(angle)])
    wanted = {0: 1.0, 1: 2.0, 2: 1.0, 3: 1.5}
    order = [2, 0, 3, 1]
    parts = divide(region, wanted, {k: (0.0, 0.0) for k in wanted}, axis=axis, order=order)
    spans = {k: (shapely.get_coordinates(p) @ axis) for k, p in parts.items()}
    for a, b in itertools.pairwise(order):  # each strip ends where the next begins
        assert spans[a].max() == pytest.approx(spans[b].min(), abs=1e-3)
    for k, part in parts.items():
        assert part.area == pytest.approx(wanted[k] / 5.5 * region.area, rel=1e-3)
    union = shapely.union_all(list(parts.values()))
    assert abs(union.area - region.area) <= 1e-6 * region.area


def test_a_band_is_the_area_between_two_lines_across_an_axis() -> None:
    region = region_of([COMB])
    axis = np.array([0.0, 1.0])
    lo, hi = extent(region, axis)
    assert (lo, hi) == (0.0, 600.0)
    assert band(region, axis, 0.0, 200.0).area == pytest.approx(1000.0 * 200.0)
    assert band(region, axis, lo - 5.0, hi + 5.0).area == pytest.approx(region.area)
    assert band(region, axis, hi + 1.0, hi + 2.0).is_empty


# --------------------------------------------------------------------------- in the allocation


@pytest.mark.parametrize("name", sorted(SHAPES))
@pytest.mark.parametrize("strategy", ["auction", "optimal"])
def test_a_free_search_is_shared_and_ends_near_the_bound(name: str, strategy: str) -> None:
    units = fleet()
    tree = search(SHAPES[name])
    alone = plan_mission(tree, units, strategy="nearest")
    plan = plan_mission(tree, units, strategy=strategy, time_limit=1.0)
    assert check_invariants(plan, tree, units) == []
    assert plan.feasible and len(plan.shared) == 1
    parts = plan.shared[0].parts
    assert len(parts) >= 3 and len(plan.assignments) == len(parts)
    assert plan.makespan < 0.5 * alone.makespan
    assert plan.makespan <= 1.5 * plan.shared[0].bound
    # The tree sent: a conc (the operator's uuid) of one search per unit, each valid for the
    # catalogue, every other parameter copied.
    conc = next(n for _, n in walk(plan.tst) if n.node_uuid == plan.shared[0].node_uuid)
    assert conc.name == "conc"
    assert sorted(p.execunit for p in conc.children) == sorted("/" + p.unit for p in parts)
    for part in conc.children:
        assert part.params["target-type"] == "person" and part.params["speed"] == "standard"
    validate_tree(plan.tst)


def test_no_split_keeps_one_unit_and_nearest_never_splits() -> None:
    units = fleet()
    tree = search(COMB)
    for plan in (plan_mission(tree, units, strategy="auction", split=False),
                 plan_mission(tree, units, strategy="nearest")):
        assert plan.shared == [] and len(plan.assignments) == 1
        assert check_invariants(plan, tree, units) == []


@pytest.mark.parametrize("execunit", ["/dji2", "team"])
def test_a_fixed_unit_or_an_alias_is_never_shared(execunit: str) -> None:
    units = fleet()
    tree = search(COMB, execunit=execunit)
    plan = plan_mission(tree, units, strategy="auction")
    assert plan.shared == [] and len(plan.assignments) == 1


def test_an_area_too_big_for_any_one_unit_becomes_feasible() -> None:
    # Each drone flies 2,500 s: the comb (1 km2 at 37 m lanes and 8 m/s, about 3,700 s of sweep)
    # is more than any one can do; the fleet's total (4 x 2,500 s) is enough with slack.
    units = fleet(endurance=2500.0)[:4]
    tree = search(COMB)
    alone = plan_mission(tree, units, strategy="nearest")
    assert not alone.feasible
    plan = plan_mission(tree, units, strategy="auction")
    assert plan.feasible, plan.unassigned
    assert check_invariants(plan, tree, units) == []  # (battery included)
    for route in plan.routes.values():
        assert sum(a.travel_time + a.work_time for a in route) <= 2500.0


def test_a_unit_busy_first_gets_a_smaller_part_and_precedence_holds() -> None:
    # seq(move-to, conc(search, move-path for dji0)): dji0 flies a long path first and gets a
    # smaller part (or none); the parts start after the move-to ends.
    units = fleet()
    path = make_node("move-path", execunit="/dji0", params={
        "waypoints": [geo(-1500, -1300), geo(1500, -1300), geo(1500, 1300)],
        "speed": "standard"})
    first = make_node("move-to", execunit="*", params={"waypoint": geo(0, -1400),
                                                       "speed": "standard"})
    tree = make_node("seq", children=[first, make_node("conc", children=[search(COMB), path])])
    plan = plan_mission(tree, units, strategy="auction")
    assert check_invariants(plan, tree, units) == []
    assert len(plan.shared) == 1
    parts = {p.unit: p.area_m2 for p in plan.shared[0].parts}
    others = [v for k, v in parts.items() if k.startswith("dji") and k != "dji0"]
    assert parts.get("dji0", 0.0) < min(others)
    moved = next(a for a in plan.assignments if a.name == "move-to")
    for a in plan.assignments:
        if a.name.startswith("search"):
            assert a.start >= moved.end - 1e-6


def test_the_check_catches_a_part_left_out() -> None:
    units = fleet()
    tree = search(COAST)
    plan = plan_mission(tree, units, strategy="auction")
    assert check_invariants(plan, tree, units) == []
    search_ = plan.shared[0]
    broken = dataclasses.replace(search_, parts=search_.parts[1:])
    plan.shared = [broken]
    problems = check_invariants(plan, tree, units)
    assert any("uncovered" in p for p in problems), problems


def test_a_search_around_position_is_shared_as_search_areas_parts() -> None:
    units = fleet()
    tree = make_node("search-around-position", execunit="*", params={
        "geopoint": geo(0.0, 0.0), "radius": 600.0, "speed": "standard"})
    plan = plan_mission(tree, units, strategy="auction")
    assert check_invariants(plan, tree, units) == []
    assert len(plan.shared) == 1
    names = {n.name for n in leaves(plan.tst)}
    assert names <= {"search-area", "search-areas"}
    area = sum(p.area_m2 for p in plan.shared[0].parts)
    assert area == pytest.approx(plan.shared[0].area_m2)
    assert area == pytest.approx(math.pi * 600.0**2, rel=0.01)  # (the 64-gon for the circle)


# --------------------------------------------------------------------------- switching it off


def _scenario_file(tmp_path, poly: np.ndarray):  # type: ignore[no-untyped-def]
    import yaml

    agents = [{"name": u.name, "type": u.agent_type,
               "position": u.position.model_dump(), "tasks": sorted(u.tasks)} for u in fleet()]
    mission = search(poly).to_dict()
    path = tmp_path / "team.yaml"
    path.write_text(yaml.safe_dump({"name": "team", "agents": agents, "mission": mission}))
    return path


def test_the_cli_shares_unless_no_split(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    import json

    from delegation.cli import main

    path = _scenario_file(tmp_path, COMB)
    runs = {}
    for flags in ([], ["--no-split"]):
        assert main(["plan", str(path), "--format", "json", *flags]) == 0
        runs[bool(flags)] = json.loads(capsys.readouterr().out)
    assert len(runs[False]["assignments"]) >= 3
    assert len(runs[True]["assignments"]) == 1
    assert runs[False]["makespan"] < 0.5 * runs[True]["makespan"]


def test_delegate_reads_split_strictly_and_the_options_carry_it() -> None:
    from pydantic import ValidationError

    from delegation.messages import Delegate
    from delegation.service.jobs import PlanOptions, plan_options

    base = {"com-uuid": "c", "command": "delegate", "tst": {"name": "seq"}}
    assert Delegate.model_validate(base).split is True
    assert Delegate.model_validate({**base, "split": False}).split is False
    with pytest.raises(ValidationError):
        Delegate.model_validate({**base, "split": "no"})
    options = plan_options(None, None, None, defaults=PlanOptions("auction", "makespan", 1.0),
                           max_time_limit=5.0, split=False)
    assert options.split is False


# --------------------------------------------------------------------------- what the operator sees


def _conc_tree():  # type: ignore[no-untyped-def]
    def move(x: float, y: float, execunit: str = "*"):  # type: ignore[no-untyped-def]
        return make_node("move-to", execunit=execunit,
                         params={"waypoint": geo(x, y), "speed": "standard"})

    return make_node("conc", children=[search(COMB), move(3000, 0), move(-3000, 0, "/dji1")])


def test_the_plan_json_lists_the_parts_the_bound_and_the_gap() -> None:
    units = fleet()
    plan = plan_mission(_conc_tree(), units, strategy="auction")
    data = plan.to_json()
    (shared,) = data["shared-searches"]
    assert shared["name"] == "search-area" and shared["node-uuid"] == plan.shared[0].node_uuid
    assert shared["area"] == pytest.approx(sum(p["area"] for p in shared["parts"]))
    assert 0.0 < shared["bound"] <= shared["end"] and 0.0 <= shared["gap"] < 1.0
    assert shared["gap"] == pytest.approx((shared["end"] - shared["bound"]) / shared["end"])
    assigned = {a["node-uuid"]: a for a in data["assignments"]}
    for part in shared["parts"]:
        a = assigned[part["node-uuid"]]
        assert (part["execunit"], part["start"], part["end"]) == (a["execunit"], a["start"],
                                                                  a["end"])
        assert part["sweep-length"] > part["area"] / 40.0  # (no drone lane is 40 m wide)
    assert shared["end"] == max(p["end"] for p in shared["parts"])


def test_the_operator_sees_the_search_follow_its_parts() -> None:
    from delegation.service.missions import _part_map
    from delegation.service.operator_view import OperatorView

    units = fleet()
    plan = plan_mission(_conc_tree(), units, strategy="auction")
    search_uuid = plan.shared[0].node_uuid
    parts = [p.node_uuid for p in plan.shared[0].parts]
    sent = {n.node_uuid for _, n in walk(plan.tst)}
    assert search_uuid not in sent  # (this tree regroups the parts' conc away)
    assert plan.source is not None
    for view in (OperatorView.of(plan.source, plan.tst, plan.part_map()),
                 OperatorView.of(plan.source, plan.tst, _part_map(plan.to_json()))):
        assert search_uuid in view and not view.relayed(parts[0]) and view.tracked(parts[0])
        statuses = {parts[0]: "running"}
        assert (search_uuid, "running") in view.changes(parts[0], statuses)
        for p in parts:
            statuses[p] = "succeeded"
        assert (search_uuid, "succeeded") in view.changes(parts[-1], statuses)


def test_where_the_conc_is_kept_its_feedback_is_the_searchs() -> None:
    from delegation.service.operator_view import OperatorView

    units = fleet()
    first = make_node("move-to", execunit="*", params={"waypoint": geo(0, -1400),
                                                       "speed": "standard"})
    tree = make_node("seq", children=[first, search(COMB)])
    plan = plan_mission(tree, units, strategy="auction")
    search_uuid = plan.shared[0].node_uuid
    kept = [n for _, n in walk(plan.tst) if n.node_uuid == search_uuid]
    assert plan.source is not None
    view = OperatorView.of(plan.source, plan.tst, plan.part_map())
    if kept:  # the engine computes the conc: relayed as it is
        assert kept[0].name == "conc" and view.relayed(search_uuid)
    else:
        assert not view.relayed(search_uuid)
    assert not view.relayed(plan.shared[0].parts[0].node_uuid)


def test_the_table_shows_each_shared_search(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    from delegation.cli import main

    path = _scenario_file(tmp_path, COMB)
    assert main(["plan", str(path)]) == 0
    out = capsys.readouterr().out
    assert "shared:" in out and "bound" in out and "gap" in out
    assert out.count("/dji") >= 6  # the assignments and the parts


def test_a_small_search_stays_whole() -> None:
    # 60 x 40 m: the flight there dominates; sharing could not end it much sooner.
    units = fleet()
    small = np.array([[0.0, 0.0], [60.0, 0.0], [60.0, 40.0], [0.0, 40.0]])
    plan = plan_mission(search(small), units, strategy="auction")
    assert plan.shared == [] and len(plan.assignments) == 1
