"""Bad trees get a specific problem naming the node (path or uuid) and the field; good trees pass.

One test per kind of bad input the Foundation issue lists; each checks where, field and message.
"""

from __future__ import annotations

import copy
from typing import Any

import pytest

from delegation.errors import InputError, InputProblem
from delegation.tst import (
    MAX_DEPTH,
    MAX_NODES,
    make_node,
    parse_and_validate,
    parse_tree,
    to_dict,
    with_defaults,
    with_uuids,
)


def gp(lat: float = 57.7611, lon: float = 16.6805, alt: float = 40.0) -> dict[str, Any]:
    return {"altitude": alt, "latitude": lat, "longitude": lon, "rostype": "GeoPoint"}


SQUARE = [gp(57.760, 16.680), gp(57.760, 16.682), gp(57.762, 16.682), gp(57.762, 16.680)]


def mission() -> dict[str, Any]:
    """seq(move-to, conc(search-area, move-path)) with uuids on every node."""
    return {
        "name": "seq",
        "common_params": {"node-uuid": "root-uuid"},
        "children": [
            {
                "name": "move-to",
                "common_params": {"execunit": "*", "node-uuid": "n-move"},
                "params": {"speed": "fast", "waypoint": gp()},
            },
            {
                "name": "conc",
                "common_params": {"node-uuid": "n-conc"},
                "children": [
                    {
                        "name": "search-area",
                        "common_params": {"execunit": "A", "node-uuid": "n-search"},
                        "params": {"area": copy.deepcopy(SQUARE), "target-size": 2.0},
                    },
                    {
                        "name": "move-path",
                        "common-params": {"execunit": "/dji0", "node-uuid": "n-path"},
                        "params": {"waypoints": [gp(57.761, 16.681), gp(57.762, 16.683)]},
                        "meta": {"note": "kept"},
                    },
                ],
            },
        ],
    }


def problems_of(data: Any) -> list[InputProblem]:
    with pytest.raises(InputError) as info:
        parse_and_validate(data)
    assert info.value.problems, "an InputError must carry problems"
    return info.value.problems


def only(data: Any) -> InputProblem:
    found = problems_of(data)
    assert len(found) == 1, found
    return found[0]


def test_a_good_mission_validates_and_round_trips() -> None:
    data = mission()
    tree = parse_and_validate(data)
    assert to_dict(tree) == data
    assert [n.name for n in tree.children] == ["move-to", "conc"]


def test_defaults_and_uuids_are_added_without_touching_the_rest() -> None:
    data = mission()
    del data["children"][0]["params"]["speed"]
    del data["children"][1]["common_params"]["node-uuid"]
    tree = with_uuids(with_defaults(parse_and_validate(data)), new_uuid=lambda: "made")
    out = to_dict(tree)
    assert out["children"][0]["params"]["speed"] == "standard"
    assert out["children"][1]["common_params"]["node-uuid"] == "made"
    assert out["children"][1]["children"][1]["meta"] == {"note": "kept"}
    assert out["children"][1]["children"][1]["common-params"]["node-uuid"] == "n-path"


def test_a_node_object_used_twice_is_filled_in_each_place() -> None:
    # Trees are values: code may put one node object in two places (make_node(children=[c, c])).
    step = make_node("move-to", params={"waypoint": gp()})
    tree = with_uuids(with_defaults(make_node("seq", children=[step, step])), iter("abr").__next__)
    assert tree.node_uuid == "r"
    assert [(n.node_uuid, n.params["speed"]) for n in tree.children] == [
        ("a", "standard"),
        ("b", "standard"),
    ]
    assert to_dict(make_node("seq", children=[step, step]))["children"] == [to_dict(step)] * 2


def test_unknown_task_names_node_and_field() -> None:
    data = mission()
    data["children"][1]["children"][0]["name"] = "search-everywhere"
    p = only(data)
    assert p.where == "root/children[1]/children[0] (search-everywhere n-search)"
    assert p.field == "name"
    assert "unknown task 'search-everywhere'" in p.message


def test_missing_required_parameter() -> None:
    data = mission()
    del data["children"][0]["params"]["waypoint"]
    p = only(data)
    assert p.where == "root/children[0] (move-to n-move)"
    assert p.field == "params.waypoint"
    assert p.message.startswith("missing")


@pytest.mark.parametrize(
    ("param", "value", "field", "text"),
    [
        ("speed", 7, None, None),  # m/s is accepted (seed 10.1.6)
        ("speed", "warp", "params.speed", "'warp' is not one of slow, standard, fast"),
        ("speed", True, "params.speed", "must be one of"),
        ("waypoint", "57.7,16.6", "params.waypoint", "must be a GeoPoint object, not str"),
        (
            "waypoint",
            {"latitude": "57.7", "longitude": 16.6},
            "params.waypoint.latitude",
            "must be a number, not '57.7'",
        ),
        ("waypoint", {"latitude": 57.7}, "params.waypoint.longitude", "missing"),
    ],
)
def test_parameter_of_the_wrong_type(
    param: str, value: Any, field: str | None, text: str | None
) -> None:
    data = mission()
    data["children"][0]["params"][param] = value
    if field is None:
        parse_and_validate(data)
        return
    p = only(data)
    assert (p.where, p.field) == ("root/children[0] (move-to n-move)", field)
    assert text is not None and text in p.message


@pytest.mark.parametrize(
    ("task", "param", "value", "field", "text"),
    [
        ("search-area", "target-size", "big", "params.target-size", "must be a number"),
        ("search-area", "target-size", -1.0, "params.target-size", "greater than 0"),
        ("observe-position", "duration", 2.5, "params.duration", "must be an integer"),
        ("observe-position", "duration", 2**31, "params.duration", "outside the int32 range"),
        ("observe-position", "duration", 10**400, "params.duration", "outside the int32 range"),
        ("observe-position", "distance", 10**400, "params.distance", "must be a number"),
        (
            "look-at-bearing",
            "use-absolute-bearing",
            "yes",
            "params.use-absolute-bearing",
            "must be true or false",
        ),
        ("navigate", "speed", ["fast", 3], "params.speed", "must be a list of strings"),
    ],
)
def test_wrong_types_per_param_type(
    task: str, param: str, value: Any, field: str, text: str
) -> None:
    base: dict[str, dict[str, Any]] = {
        "search-area": {"area": SQUARE},
        "observe-position": {"geopoint": gp()},
        "look-at-bearing": {},
        "navigate": {"waypoints": [gp()]},
    }
    data = {"name": task, "params": {**base[task], param: value}}
    p = only(data)
    assert (p.where, p.field) == (f"root ({task})", field)
    assert text in p.message


@pytest.mark.parametrize(
    ("lat", "lon", "field"),
    [
        (90.5, 16.0, "latitude"),
        (-91.0, 16.0, "latitude"),
        (57.0, 180.01, "longitude"),
        (57.0, -181.0, "longitude"),
    ],
)
def test_latitude_longitude_out_of_range(lat: float, lon: float, field: str) -> None:
    data = mission()
    data["children"][1]["children"][1]["params"]["waypoints"][1] = gp(lat, lon)
    p = only(data)
    assert p.where == "root/children[1]/children[1] (move-path n-path)"
    assert p.field == f"params.waypoints[1].{field}"
    assert "outside" in p.message
    assert ("[-90, 90]" if field == "latitude" else "[-180, 180]") in p.message


def test_limits_are_inclusive() -> None:
    data = {"name": "move-to", "params": {"waypoint": gp(90.0, -180.0)}}
    assert parse_and_validate(data).params["waypoint"]["latitude"] == 90.0


def test_search_polygon_with_fewer_than_three_points() -> None:
    data = mission()
    data["children"][1]["children"][0]["params"]["area"] = SQUARE[:2]
    p = only(data)
    assert p.where == "root/children[1]/children[0] (search-area n-search)"
    assert p.field == "params.area"
    assert "at least 3 points, got 2" in p.message


def test_search_polygon_that_crosses_itself() -> None:
    data = mission()
    a, b, c, d = SQUARE
    data["children"][1]["children"][0]["params"]["area"] = [a, c, b, d]  # a bow tie
    p = only(data)
    assert (p.where, p.field) == (
        "root/children[1]/children[0] (search-area n-search)",
        "params.area",
    )
    assert "crosses itself" in p.message


@pytest.mark.parametrize(
    ("area", "refused"),
    [
        # three points on a line in degrees: 1e-18 deg² by float rounding, not exactly zero
        ([gp(57.760, 16.680), gp(57.761, 16.6813), gp(57.762, 16.6826)], True),
        # a sliver a few cm wide and 100 m long
        ([gp(57.760, 16.680), gp(57.7609, 16.680), gp(57.760, 16.6800001)], True),
        # the same point three times
        ([gp(57.760, 16.680)] * 3, True),
        # a triangle 11 m by 6 m (mean width 2.2 m) is a (small) area
        ([gp(57.760, 16.680), gp(57.7601, 16.680), gp(57.760, 16.6801)], False),
        (SQUARE, False),
        # the one-element-list form of a point is read as the point
        ([[p] for p in SQUARE], False),
    ],
    ids=["collinear", "sliver", "one-point", "tiny-triangle", "square", "wrapped-points"],
)
def test_search_polygon_area_is_judged_in_metres(area: list[Any], refused: bool) -> None:
    data = {"name": "search-area", "params": {"area": area, "target-size": 2.0}}
    if not refused:
        assert parse_and_validate(data).name == "search-area"
        return
    found = problems_of(data)
    assert [(p.field, "has no area" in p.message) for p in found] == [("params.area", True)]
    assert "m²" in found[0].message and "1 m wide" in found[0].message


def test_search_areas_names_the_bad_area() -> None:
    a, b, c, d = SQUARE
    data = {"name": "search-areas", "params": {"areas": [SQUARE, [a, c, b, d], SQUARE[:1]]}}
    found = problems_of(data)
    assert [
        (p.field, "crosses itself" in p.message or "at least 3" in p.message) for p in found
    ] == [("params.areas[1]", True), ("params.areas[2]", True)]


def test_duplicate_node_uuids_name_both_nodes() -> None:
    data = mission()
    data["children"][1]["children"][1]["common-params"]["node-uuid"] = "n-move"
    p = only(data)
    assert p.where == "root/children[1]/children[1] (move-path n-move)"
    assert p.field == "common_params.node-uuid"
    assert "duplicate node-uuid 'n-move'" in p.message
    assert "root/children[0]" in p.message


def test_task_node_with_children() -> None:
    data = mission()
    data["children"][0]["children"] = [{"name": "move-to", "params": {"waypoint": gp()}}]
    p = only(data)
    assert p.where == "root/children[0] (move-to n-move)"
    assert p.field == "children"
    assert "task node 'move-to' cannot have children" in p.message


@pytest.mark.parametrize("children", [{"name": "move-to"}, "move-to", 3, True])
def test_children_that_is_not_a_list(children: Any) -> None:
    data = mission()
    data["children"][1]["children"] = children
    p = only(data)
    assert (p.where, p.field) == ("root/children[1]", "children")
    assert p.message.startswith("must be a list, not")


@pytest.mark.parametrize(
    ("node", "field", "text"),
    [
        ([1, 2], "", "a node must be a JSON object, not a list"),
        ({"params": {}}, "name", "missing"),
        ({"name": ""}, "name", "must be a non-empty string"),
        ({"name": "move-to", "params": [1]}, "params", "must be an object"),
        ({"name": "move-to", "common_params": "x"}, "common_params", "must be an object"),
        (
            {"name": "move-to", "common_params": {}, "common-params": {}},
            "common_params",
            "both common_params and common-params",
        ),
        (
            {"name": "move-to", "params": {"waypoint": gp()}, "common_params": {"node-uuid": 7}},
            "common_params.node-uuid",
            "must be a string",
        ),
        (
            {"name": "move-to", "params": {"waypoint": gp()}, "common_params": {"execunit": 7}},
            "common_params.execunit",
            "execunit must be a string",
        ),
    ],
)
def test_malformed_nodes(node: Any, field: str, text: str) -> None:
    data = {"name": "seq", "children": [{"name": "move-to", "params": {"waypoint": gp()}}, node]}
    p = only(data)
    assert p.where.startswith("root/children[1]")
    assert p.field == field
    assert text in p.message


def nested(depth: int) -> dict[str, Any]:
    node: dict[str, Any] = {"name": "move-to", "params": {"waypoint": gp()}}
    for _ in range(depth - 1):
        node = {"name": "seq", "children": [node]}
    return node


def test_depth_limit() -> None:
    assert parse_and_validate(nested(MAX_DEPTH)).name == "seq"
    p = only(nested(MAX_DEPTH + 1))
    assert p.where == "root" + "/children[0]" * MAX_DEPTH
    assert p.field == "children"
    assert f"deeper than {MAX_DEPTH} levels" in p.message


def test_size_limit() -> None:
    leaf = {"name": "move-to", "params": {"waypoint": gp()}}
    assert (
        len(parse_tree({"name": "conc", "children": [leaf] * (MAX_NODES - 1)}).children)
        == MAX_NODES - 1
    )
    p = only({"name": "conc", "children": [leaf] * MAX_NODES})
    assert p.where == "root"
    assert f"more than {MAX_NODES} nodes" in p.message


def test_every_problem_is_reported_in_tree_order() -> None:
    data = mission()
    data["children"][0]["params"]["waypoint"] = gp(95.0, 16.0)
    data["children"][1]["children"][0]["name"] = "nope"
    data["children"][1]["children"][1]["params"]["speed"] = "warp"
    found = problems_of(data)
    assert [p.where.split(" ")[0] for p in found] == [
        "root/children[0]",
        "root/children[1]/children[0]",
        "root/children[1]/children[1]",
    ]
    assert "root/children[0] (move-to n-move): params.waypoint.latitude" in str(InputError(found))
