"""Property tests (hypothesis): catalogue trees round-trip exactly and validate; any JSON given to
the tree parser yields a tree or an ``InputError``, never another exception."""

from __future__ import annotations

import json
import math
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from delegation.errors import InputError
from delegation.messages.check import check_data
from delegation.tst import (
    CATALOGUE,
    ParamType,
    TaskSpec,
    TstNode,
    parse_and_validate,
    parse_tree,
    to_dict,
    walk,
    with_defaults,
    with_uuids,
)
from delegation.tst.node import stored_nodes
from delegation.tst.validate import INT32_MAX, INT32_MIN

SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])

finite = st.floats(allow_nan=False, allow_infinity=False, min_value=-1e6, max_value=1e6)


@st.composite
def geopoints(draw: st.DrawFn) -> dict[str, Any]:
    point = {
        "latitude": draw(st.floats(-90, 90)),
        "longitude": draw(st.floats(-180, 180)),
    }
    if draw(st.booleans()):
        point["altitude"] = draw(st.floats(-100, 10_000))
    marker = draw(st.sampled_from(["rostype", "type", None]))
    if marker:
        point[marker] = "GeoPoint"
    return point


@st.composite
def polygons(draw: st.DrawFn) -> list[dict[str, Any]]:
    """A simple (star-shaped) polygon: points at increasing angles around a centre."""
    lat0 = draw(st.floats(-60, 60))
    lon0 = draw(st.floats(-170, 170))
    n = draw(st.integers(3, 8))
    radius = draw(st.floats(50, 2000))
    points = []
    for k in range(n):
        jitter = draw(st.floats(-0.4, 0.4))
        angle = 2 * math.pi * (k + jitter) / n
        r = radius * draw(st.floats(0.5, 1.0))
        points.append(
            {
                "altitude": 40.0,
                "latitude": lat0 + r * math.sin(angle) / 111_000,
                "longitude": lon0 + r * math.cos(angle) / (111_000 * math.cos(math.radians(lat0))),
                "rostype": "GeoPoint",
            }
        )
    return points


def value_for(task: str, name: str, ptype: ParamType, choices: tuple[str, ...] | None) -> Any:
    if choices:
        return st.sampled_from(choices)
    if name in ("radius", "target-size"):
        return st.floats(0.1, 1e4)
    # Physical ranges (tst.validate.Limits): distances, heights, durations, commanded speeds.
    if name == "distance":
        return st.floats(0, 1e5)
    if name in ("height", "height-above-takeoff", "z"):
        return st.floats(-12_000, 50_000)
    if name == "duration":
        return st.integers(INT32_MIN, 7 * 24 * 3600)
    if name == "commanded-speed":
        return st.lists(st.floats(0.1, 100), max_size=3)
    return {
        ParamType.GEOPOINT: geopoints(),
        ParamType.GEOPOINTS: polygons()
        if (task, name) == ("search-area", "area")
        else st.lists(geopoints(), min_size=1, max_size=4),
        ParamType.GEOPOINTARRAYS: st.lists(polygons(), min_size=1, max_size=3),
        ParamType.FLOAT64: finite,
        ParamType.INT32: st.integers(INT32_MIN, INT32_MAX),
        ParamType.BOOL: st.booleans(),
        ParamType.STRING: st.text(max_size=8),
        ParamType.STRINGS: st.lists(st.text(max_size=8), max_size=3),
        ParamType.FLOAT64S: st.lists(finite, max_size=3),
    }[ptype]


@st.composite
def task_params(draw: st.DrawFn, spec: TaskSpec) -> dict[str, Any]:
    wanted = set(spec.required)
    for group in spec.one_of:
        wanted.add(draw(st.sampled_from(group)))
    optional = sorted(set(spec.params) - wanted)
    wanted |= set(draw(st.lists(st.sampled_from(optional), unique=True)) if optional else [])
    order = draw(st.permutations(sorted(wanted)))
    params: dict[str, Any] = {}
    for name in order:
        p = spec.params[name]
        params[name] = draw(value_for(spec.name, name, p.type, p.choices))
    return params


json_leaf = (
    st.none()
    | st.booleans()
    | st.integers()
    | st.integers(min_value=-(10**400), max_value=10**400)  # beyond a float's range too
    | st.floats(allow_nan=False)
    | finite
    | st.text(max_size=8)
)
json_values = st.recursive(
    json_leaf,
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=4)
    ),
    max_leaves=12,
)


@st.composite
def node_dict(
    draw: st.DrawFn, name: str, children: list[dict[str, Any]] | None, params: dict[str, Any]
) -> dict[str, Any]:
    common: dict[str, Any] = {}
    execunit = draw(st.sampled_from(["/dji0", "/op0", "A", "team-1", "*", "", None]))
    if execunit is not None:
        common["execunit"] = execunit
    if draw(st.booleans()):
        common["node-uuid"] = "placeholder"
    values: dict[str, Any] = {
        "name": name,
        draw(st.sampled_from(["common_params", "common-params"])): common,
    }
    if children is not None:
        values["children"] = children
    elif draw(st.booleans()):
        values["children"] = []
    if params or draw(st.booleans()):
        values["params"] = params
    if draw(st.booleans()):
        values["meta"] = draw(json_values)
    order = draw(st.permutations(list(values)))
    return {k: values[k] for k in order}


@st.composite
def leaf(draw: st.DrawFn) -> dict[str, Any]:
    spec = CATALOGUE[draw(st.sampled_from(sorted(CATALOGUE)))]
    return draw(node_dict(spec.name, None, draw(task_params(spec))))


@st.composite
def control(draw: st.DrawFn, kids: st.SearchStrategy[list[dict[str, Any]]]) -> dict[str, Any]:
    return draw(node_dict(draw(st.sampled_from(["seq", "conc"])), draw(kids), {}))


def number_uuids(data: dict[str, Any]) -> dict[str, Any]:
    """Make the placeholder node-uuids unique (in place), as a caller would."""
    stack, count = [data], 0
    while stack:
        node = stack.pop()
        for key in ("common_params", "common-params"):
            if node.get(key, {}).get("node-uuid") == "placeholder":
                node[key]["node-uuid"] = f"uuid-{count}"
                count += 1
        stack.extend(node.get("children", []))
    return data


trees = st.recursive(
    leaf(), lambda kids: control(st.lists(kids, min_size=1, max_size=4)), max_leaves=10
).map(number_uuids)


@pytest.mark.slow  # hundreds of generated trees
@SETTINGS
@given(trees)
def test_catalogue_trees_round_trip_exactly_and_validate(data: dict[str, Any]) -> None:
    text = json.dumps(data)
    tree = parse_and_validate(json.loads(text))
    assert json.dumps(to_dict(tree)) == text
    assert parse_tree(to_dict(tree)) == tree
    # Instantiation helpers keep the tree valid and keep the caller's fields.
    filled = with_uuids(
        with_defaults(tree), new_uuid=iter(f"new-{i}" for i in range(10**6)).__next__
    )
    again = parse_and_validate(to_dict(filled))
    uuids = [n.node_uuid for _, n in walk(again)]
    assert None not in uuids and len(set(uuids)) == len(uuids)
    for (_, before), (_, after) in zip(walk(tree), walk(again), strict=True):
        assert after.extra == before.extra
        assert after.common_key == before.common_key
        assert {k: v for k, v in after.params.items() if k in before.params} == before.params


@SETTINGS
@given(trees)
def test_stored_nodes_reads_the_json_as_walk_reads_the_tree(data: dict[str, Any]) -> None:
    # The service reads the trees it keeps as JSON without parsing them (`stored_nodes`): the
    # same nodes, in the same order, with the same common parameters as the parsed tree.
    tree = with_uuids(parse_and_validate(data))
    raw = [(node.get("name"), common.get("node-uuid"), node.get("params", {}))
           for node, common in stored_nodes(to_dict(tree))]
    assert raw == [(n.name, n.node_uuid, n.params) for _, n in walk(tree)]


@SETTINGS
@given(json_values)
def test_any_json_is_a_tree_or_an_input_error(data: Any) -> None:
    try:
        tree = parse_and_validate(data)
    except InputError as exc:
        assert exc.problems
        assert all(p.where for p in exc.problems)
    else:
        assert isinstance(tree, TstNode)


fuzzy_value = st.one_of(
    json_values,
    geopoints(),
    polygons(),
    st.lists(polygons(), max_size=2),
    st.integers(),
    st.floats(allow_nan=False),
)


@st.composite
def fuzzy_node(draw: st.DrawFn, kids: st.SearchStrategy[Any] | None = None) -> Any:
    """Nodes that are nearly right: mostly catalogue names and keys with any values, now and
    then odd structure (so that the parameter checks, not only the structure checks, are hit)."""
    odd = draw(st.integers(0, 9)) == 0
    names = [*sorted(CATALOGUE), "seq", "conc"]
    name = draw(json_leaf if odd else st.sampled_from(names))
    if kids is not None and not odd:
        name = draw(st.sampled_from(["seq", "conc"]))
    node: dict[str, Any] = {"name": name}
    spec = CATALOGUE.get(name) if isinstance(name, str) else None
    keys = sorted(spec.params) if spec else ["waypoint", "area", "speed"]
    node["params"] = draw(
        json_values if odd else st.dictionaries(st.sampled_from(keys), fuzzy_value, max_size=4)
    )
    common = st.fixed_dictionaries(
        {},
        optional={
            "execunit": st.sampled_from(["/a", "*", "B"]) | json_leaf,
            "node-uuid": st.text(max_size=3) | json_leaf,
        },
    )
    node[draw(st.sampled_from(["common_params", "common-params"]))] = draw(
        json_values if odd else common
    )
    if kids is not None:
        node["children"] = draw(json_values if odd else kids)
    return node


fuzzy_trees = st.recursive(
    fuzzy_node(), lambda kids: fuzzy_node(st.lists(kids, max_size=3)), max_leaves=8
)


@pytest.mark.slow  # hundreds of generated trees
@SETTINGS
@given(fuzzy_trees)
def test_nearly_right_trees_are_a_tree_or_an_input_error(data: Any) -> None:
    try:
        parse_and_validate(data)
    except InputError as exc:
        assert exc.problems
        for p in exc.problems:
            assert p.where.startswith("root"), p
    result = check_data(data)
    assert result.ok or result.problems
