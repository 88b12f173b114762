"""compute_bids: per task and unit, the estimated travel, work and distance, or the reason."""

from __future__ import annotations

import pytest

from allocation_helpers import move_to, unit
from delegation.allocation import compute_bids
from delegation.tst import parse_tree, with_uuids


def test_a_capable_unit_bids_and_an_incapable_one_says_why() -> None:
    tree = with_uuids(parse_tree({"name": "seq", "children": [move_to(300, 400)]}),
                      lambda: "task-1")
    units = [unit("mover", 0, 0, speed=5.0, tasks=("move-to",)),
             unit("looker", 0, 0, tasks=("look-at-position",))]
    mover, looker = compute_bids(tree, units)
    assert mover["node-uuid"] == looker["node-uuid"] == "task-1"
    assert mover["name"] == looker["name"] == "move-to"
    assert (mover["unit"], looker["unit"]) == ("/mover", "/looker")
    # 500 m from where the unit is, at the standard 5 m/s; a move-to does no work on arrival.
    assert mover["distance"] == pytest.approx(500.0, abs=0.5)
    assert mover["travel-time"] == pytest.approx(100.0, abs=0.1)
    assert mover["work-time"] == 0.0
    assert mover["open-ended"] is False
    assert "reason" not in mover
    assert looker == {"node-uuid": "task-1", "name": "move-to", "unit": "/looker",
                      "reason": "looker does not offer move-to"}


def test_no_tasks_or_no_units_no_bids() -> None:
    tree = parse_tree({"name": "seq", "children": [move_to(0, 0)]})
    assert compute_bids(tree, []) == []
    assert compute_bids(parse_tree({"name": "seq", "children": []}),
                        [unit("a", 0, 0)]) == []
