"""The validated-tree type (`delegation.tst.validate.ValidatedTree`): made by the validator only,
and planned without being checked again."""

from __future__ import annotations

import pytest

from delegation.allocation import planner
from delegation.errors import InputError
from delegation.fleet import make_unit
from delegation.geo import GeoPoint
from delegation.tst.node import parse_tree
from delegation.tst.validate import Limits, ValidatedTree, validate_tree

TREE = {"name": "move-to", "params": {"waypoint": {"latitude": 57.76, "longitude": 16.68,
                                                   "altitude": 20.0}, "speed": 30.0}}


def test_only_the_validator_makes_one_and_it_names_every_problem() -> None:
    with pytest.raises(TypeError):
        ValidatedTree(parse_tree(TREE))
    checked = validate_tree(TREE)
    assert checked.name == "move-to" and checked.node_uuid is None
    assert checked.with_uuids(lambda: "u-1").node_uuid == "u-1"
    with pytest.raises(InputError, match="speed"):
        validate_tree(TREE, Limits(max_speed=10.0))


def test_plan_mission_checks_a_raw_tree_but_not_a_validated_one(
    monkeypatch: pytest.MonkeyPatch
) -> None:
    units = [make_unit("u0", "air", GeoPoint(latitude=57.76, longitude=16.681), ["move-to"])]
    checked = validate_tree(TREE)
    calls: list[object] = []
    real = planner.validate_tree
    monkeypatch.setattr(planner, "validate_tree",
                        lambda tree, limits: calls.append(tree) or real(tree, limits))
    assert planner.plan_mission(checked, units).feasible and calls == []
    assert planner.plan_mission(parse_tree(TREE), units).feasible and len(calls) == 1
    with pytest.raises(InputError):
        planner.plan_mission(parse_tree(TREE), units, limits=Limits(max_speed=10.0))
