"""A search shared among units, end to end on a real broker (DESIGN 3.11).

The service plans a free ``search-area`` beside another task for three simulated drones; the
reference engine runs the tree with one part per drone; the operator hears the search's own
node succeed (its status follows its parts), never the parts.
"""

from __future__ import annotations

import uuid
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from delegation.fleet import UnitState, make_unit
from delegation.runtime.settings import BrokerSettings
from delegation.tst.node import parse_tree, walk
from test_e2e_service import FRAME, Runtime, move_to, pt, start_runtime

pytestmark = [pytest.mark.mqtt, pytest.mark.slow]

TASKS = ["move-to", "move-path", "search-area", "search-areas"]


def drones() -> list[UnitState]:
    speeds = {"slow": 4.0, "standard": 8.0, "fast": 14.0}
    return [make_unit(f"dji{i}", "air", FRAME.geopoint(-200.0 + 200.0 * i, -300.0, 30), TASKS,
                      speeds=speeds) for i in range(3)]


@pytest.fixture
def team(mqtt_settings: BrokerSettings, prefix: str,
         collector: Callable[..., Any]) -> Iterator[Runtime]:
    yield from start_runtime(mqtt_settings, prefix, drones(), collector, speedup=100.0)


def test_a_shared_search_is_flown_by_its_units_and_the_operator_sees_its_node(
        team: Runtime, collector: Callable[..., Any]) -> None:
    engine = collector(f"{team.engine_base}/tst/feedback")  # the sent tree's nodes
    root, search = str(uuid.uuid4()), str(uuid.uuid4())
    area = [pt(-300, 0), pt(300, 0), pt(300, 250), pt(50, 250), pt(50, 120), pt(-300, 120)]
    tree = {"name": "conc", "common_params": {"node-uuid": root}, "children": [
        {"name": "search-area", "common_params": {"execunit": "*", "node-uuid": search},
         "params": {"area": area, "target-size": 2.0}},
        move_to(-150, -400),
    ]}
    answer = team.send({"command": "delegate", "tst": tree, "start": True}, api="delegation")
    assert answer["response"] == "started", answer
    plan = answer["plan"]
    (shared,) = plan["shared-searches"]
    assert shared["node-uuid"] == search and len(shared["parts"]) >= 2
    parts = {p["node-uuid"]: p["execunit"] for p in shared["parts"]}
    sent = parse_tree(team.engine_trees()[0]["tst"])
    flown = {n.node_uuid: n.execunit for _, n in walk(sent) if n.name.startswith("search")}
    assert flown == parts  # one part per unit, on its unit

    team.node_status(search, "succeeded", timeout=60)
    team.node_status(root, "succeeded", timeout=30)
    relayed = {d.get("node-uuid") for d in team.watch.json_on(f"{team.base}/tst/feedback")}
    assert search in relayed and not relayed & set(parts)  # the parts are not shown
    # Every drone flew its own part to the end.
    for part in parts:
        done = (part, "succeeded")
        engine.wait_json(f"{team.engine_base}/tst/feedback",
                         lambda d, x=done: (d.get("node-uuid"), d.get("status")) == x,
                         timeout=5, what=f"succeeded for part {part}")
