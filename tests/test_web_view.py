"""The operator page's live state (web/view.py), plan geometry and mission input: pure, fast."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from delegation.errors import InputError
from delegation.tst import without_node_uuids
from delegation.web.auth import bearer, read_users, user_of
from delegation.web.geometry import plan_geometry, task_shapes
from delegation.web.mission_input import mission_tree, with_node_uuids
from delegation.web.server import is_loopback, parse_http
from delegation.web.view import TRACK_MAX, LiveView, node_uuid_of

BASE = "waraps/unit/air/simulation/dji0"


def hb(uuid: str = "a1", rate: float = 1.0) -> dict[str, Any]:
    return {"agent-type": "air", "agent-uuid": uuid, "levels": ["sensor", "direct execution"],
            "name": "dji0", "rate": rate, "type": "HeartBeat"}


def pos(lat: float, lon: float = 16.68) -> dict[str, Any]:
    return {"latitude": lat, "longitude": lon, "altitude": 40.0, "type": "GeoPoint"}


def live_unit(view: LiveView, now: float = 100.0, base: str = BASE) -> None:
    view.heartbeat(base, "dji0", "air", hb(), now)
    view.position(base, "dji0", "air", pos(57.76), now)


def test_a_unit_appears_with_its_sensors_and_is_lost_after_the_services_timeout() -> None:
    view = LiveView()
    live_unit(view)
    view.sensor(BASE, "dji0", "air", "heading", {"value": 90.0}, 100.0)
    view.sensor(BASE, "dji0", "air", "speed", 3.0, 100.0)
    view.sensor(BASE, "dji0", "air", "battery_state", {"percentage": 0.5, "charging": False},
                100.0)
    view.execution_info(BASE, "dji0", "air", {
        "tasks-available": [{"name": "move-to", "signals": []}, "land"],
        "tasks-executing": [{"task-name": "move-to", "task-uuid": "t1"}]}, 100.0)
    (unit,) = view.state(100.0)["units"]
    assert unit["name"] == "dji0" and unit["type"] == "air" and unit["base"] == BASE
    assert (unit["latitude"], unit["heading"], unit["speed"], unit["battery"]) == (
        57.76, 90.0, 3.0, 0.5)
    assert unit["status"] == "alive"
    assert unit["tasks-available"] == ["land", "move-to"]
    assert unit["executing"] == [{"name": "move-to", "uuid": "t1"}]
    assert unit["track"] == [[57.76, 16.68]]
    # 1 Hz heartbeat: lost after 3 periods, at least 5 s (FleetRegistry.timeout)
    assert view.tick(104.9) == 0
    assert view.tick(105.0) == 1
    assert view.state(105.0)["units"][0]["status"] == "lost"
    kinds = [e["kind"] for e in view.state(105.0)["events"]]
    assert kinds == ["unit-new", "unit-lost"]
    view.heartbeat(BASE, "dji0", "air", hb(), 106.0)
    assert view.state(106.0)["units"][0]["status"] == "alive"
    assert view.state(106.0)["events"][-1]["kind"] == "unit-back"


def test_engines_and_units_without_a_position_are_not_shown() -> None:
    view = LiveView()
    engine = {"agent-type": "ground", "agent-uuid": "e", "levels": ["tst execution"],
              "name": "op0", "rate": 1.0}
    view.heartbeat("waraps/unit/ground/simulation/op0", "op0", "ground", engine, 1.0)
    view.heartbeat(BASE, "dji0", "air", hb(), 1.0)
    assert view.state(1.0)["units"] == []


def test_a_name_is_bound_to_its_first_base_topic() -> None:
    view = LiveView()
    live_unit(view)
    other = "waraps/unit/air/real/dji0"
    view.heartbeat(other, "dji0", "air", hb("evil"), 101.0)
    view.position(other, "dji0", "air", pos(10.0), 101.0)
    (unit,) = view.state(101.0)["units"]
    assert unit["base"] == BASE and unit["latitude"] == 57.76


def test_the_track_is_thinned_and_bounded() -> None:
    view = LiveView()
    view.heartbeat(BASE, "dji0", "air", hb(), 0.0)
    for k in range(1000):
        view.position(BASE, "dji0", "air", pos(57.0 + k * 1e-4), float(k))  # ~11 m apart
    view.position(BASE, "dji0", "air", pos(57.0 + 999 * 1e-4 + 1e-6), 1000.0)  # 0.1 m: dropped
    track = view.state(1000.0)["units"][0]["track"]
    assert len(track) <= TRACK_MAX
    assert track[0] == [57.0, 16.68]
    assert track[-1][0] == pytest.approx(57.0 + 999 * 1e-4)
    lats = [p[0] for p in track]
    assert lats == sorted(lats)


def test_units_since_returns_only_changed_units_without_tracks() -> None:
    view = LiveView()
    live_unit(view)
    view.heartbeat("waraps/unit/air/simulation/dji1", "dji1", "air", hb("b"), 100.0)
    view.position("waraps/unit/air/simulation/dji1", "dji1", "air", pos(57.7), 100.0)
    seq = view.seq
    assert view.units_since(seq) == []
    view.position(BASE, "dji0", "air", pos(57.761), 101.0)
    (changed,) = view.units_since(seq)
    assert changed["name"] == "dji0" and changed["point"] == [57.761, 16.68]
    assert "track" not in changed


def plan_json(root: str = "r1") -> dict[str, Any]:
    tree = {"name": "seq", "common_params": {"node-uuid": root, "execunit": "/op0"},
            "children": [
                {"name": "move-to", "common_params": {"node-uuid": "t1", "execunit": "/dji0"},
                 "params": {"waypoint": pos(57.77), "speed": "standard"}},
                {"name": "search-area", "common_params": {"node-uuid": "t2",
                                                          "execunit": "/dji0"},
                 "params": {"area": [pos(57.78, 16.6), pos(57.78, 16.7), pos(57.79, 16.7)]}},
                {"name": "look-at-position", "common_params": {"node-uuid": "t3",
                                                               "execunit": "/dji0"},
                 "params": {"geopoint": pos(57.0)}},
            ]}
    return {"strategy": "auction", "objective": "makespan", "makespan": 120.0,
            "assignments": [
                {"node-uuid": "t1", "name": "move-to", "execunit": "/dji0", "start": 0.0,
                 "end": 50.0},
                {"node-uuid": "t2", "name": "search-area", "execunit": "/dji0", "start": 50.0,
                 "end": 120.0},
                {"node-uuid": "t3", "name": "look-at-position", "execunit": "/dji0",
                 "start": 120.0, "end": 120.0},
            ], "unassigned": [], "tst": tree}


def test_a_mission_follows_feedback_forward_only_with_elapsed_frozen_at_the_end() -> None:
    view = LiveView(scale=2.0)
    live_unit(view)
    plan = plan_json()
    view.mission_planned("r1", plan, plan["tst"], "alice", 100.0)
    (m,) = view.state(100.0)["missions"]
    assert (m["id"], m["owner"], m["strategy"], m["objective"]) == ("r1", "alice", "auction",
                                                                    "makespan")
    assert m["status"] == "planned" and m["units"] == ["dji0"] and m["elapsed"] is None
    assert m["fallback"] is None
    view.mission_feedback({"root-uuid": "r1", "status": "started"}, 101.0)
    view.mission_feedback({"root-uuid": "r1", "status": "running"}, 102.0)
    view.mission_feedback({"root-uuid": "r1", "status": "started"}, 103.0)  # late: ignored
    view.node_feedback({"node-uuid": "t1", "status": "running"}, 102.0)
    view.node_feedback({"node-uuid": "t1", "status": "succeeded"}, 110.0)
    view.mission_feedback({"root-uuid": "r1", "status": "succeeded"}, 121.0)
    view.mission_feedback({"root-uuid": "r1", "status": "failed"}, 122.0)  # ended: ignored
    (m,) = view.state(200.0)["missions"]
    assert m["status"] == "succeeded"
    assert m["elapsed"] == pytest.approx(40.0)  # 20 wall s at a speed-up of 2
    kinds = [e["kind"] for e in view.state(200.0)["events"] if e["mission"] == "r1"]
    assert kinds == ["started", "running", "succeeded"]
    tree = view.node_tree("r1")
    assert tree is not None
    t1 = tree["children"][0]
    assert (t1["uuid"], t1["execunit"], t1["status"]) == ("t1", "dji0", "succeeded")
    assert (t1["plan-start"], t1["plan-end"]) == (0.0, 50.0)
    assert (t1["actual-start"], t1["actual-end"]) == (pytest.approx(2.0), pytest.approx(18.0))
    assert tree["children"][1]["status"] is None


def test_feedback_before_the_tree_is_applied_when_the_mission_is_known() -> None:
    view = LiveView()
    view.mission_feedback({"root-uuid": "r1", "status": "planned"}, 1.0)
    assert view.drain_fetch() == ["r1"]
    view.node_feedback({"node-uuid": "t1", "status": "running"}, 2.0)
    answer = {"root-uuid": "r1", "name": "seq", "owner": "bob", "status": "running",
              "started": 1.5, "ended": None, "nodes": [], **{k: v for k, v in plan_json().items()
                                                             if k != "objective"},
              "received": plan_json()["tst"]}
    view.mission_answer(answer, 3.0)
    tree = view.node_tree("r1")
    assert tree is not None and tree["children"][0]["status"] == "running"
    assert tree["children"][0]["actual-start"] == pytest.approx(0.5)
    assert view.state(3.0)["missions"][0]["owner"] == "bob"


def test_re_delegated_nodes_report_on_the_operators_node() -> None:
    view = LiveView()
    plan = plan_json()
    view.mission_planned("r1", plan, plan["tst"], "", 1.0)
    view.mission_feedback({"root-uuid": "r1", "status": "re-delegated", "fail-reason": "lost",
                           "tasks": [{"node-uuid": "t1b", "replaces": "t1", "name": "move-to",
                                      "unit": "/dji1"}]}, 2.0)
    view.node_feedback({"node-uuid": "t1b", "status": "running"}, 3.0)
    tree = view.node_tree("r1")
    assert tree is not None and tree["children"][0]["status"] == "running"
    assert tree["children"][0]["execunit"] == "dji1"
    assert view.state(3.0)["events"][-1]["kind"] == "re-delegated"
    assert view.state(3.0)["missions"][0]["units"] == ["dji0", "dji1"]


def test_a_task_that_ended_runs_again_after_a_re_delegation_and_its_new_end_shows() -> None:
    """The operator's uuids are kept through a re-delegation (docs/protocol.md §4): a task that
    failed (or was aborted) before it may run again and succeed; an end after it stays."""
    view = LiveView()
    plan = plan_json()
    view.mission_planned("r1", plan, plan["tst"], "", 1.0)

    def status() -> str:
        tree = view.node_tree("r1")
        assert tree is not None
        return str(tree["children"][0]["status"])

    view.node_feedback({"node-uuid": "t1", "status": "running"}, 2.0)
    view.node_feedback({"node-uuid": "t1", "status": "failed"}, 3.0)
    view.node_feedback({"node-uuid": "t1", "status": "running"}, 3.5)
    assert status() == "failed"  # no re-delegation: an end is kept
    view.mission_feedback({"root-uuid": "r1", "status": "re-delegated", "fail-reason": "lost",
                           "tasks": [{"node-uuid": "t1", "replaces": "t1", "name": "move-to",
                                      "unit": "/dji1"}]}, 4.0)
    view.node_feedback({"node-uuid": "t1", "status": "running"}, 5.0)
    assert status() == "running"
    view.node_feedback({"node-uuid": "t1", "status": "succeeded"}, 6.0)
    view.node_feedback({"node-uuid": "t1", "status": "running"}, 7.0)
    assert status() == "succeeded"  # ended after the re-delegation: kept


def test_hidden_missions_never_show() -> None:
    view = LiveView()
    view.hide("dry")
    view.mission_feedback({"root-uuid": "dry", "status": "planned"}, 1.0)
    assert view.state(1.0)["missions"] == [] and view.drain_fetch() == []


def test_stream_items_since_and_falling_behind() -> None:
    view = LiveView()
    view.mission_feedback({"root-uuid": "r1", "status": "planned"}, 1.0)
    seq = view.seq
    live_unit(view, 1.5)  # unit changes take seqs too, without stream items
    view.mission_feedback({"root-uuid": "r1", "status": "started"}, 2.0)
    items = view.items_since(seq)
    assert items is not None
    assert [(k, d.get("kind") or d.get("status")) for _, k, d in items] == [
        ("log", "unit-new"), ("mission", "started"), ("log", "started")]
    for k in range(5000):
        view.mission_feedback({"root-uuid": f"m{k}", "status": "planned"}, 3.0)
    assert view.items_since(seq) is None


def test_plan_geometry_routes_vehicle_tasks_from_the_start_position() -> None:
    routes, tasks = plan_geometry(plan_json(), {"dji0": [57.76, 16.68]})
    assert routes == {"dji0": [[57.76, 16.68], [57.77, 16.68], [57.78, 16.6], [57.78, 16.7],
                               [57.79, 16.7]]}
    assert [(t["uuid"], t["kind"], t["unit"]) for t in tasks] == [
        ("t1", "point", "dji0"), ("t2", "area", "dji0"), ("t3", "point", "dji0")]


def test_task_shapes() -> None:
    assert task_shapes("move-path", {"waypoints": [pos(1.0), pos(2.0)]})[0] == (
        "path", [[1.0, 16.68], [2.0, 16.68]])
    (kind, circle), = task_shapes("search-around-position", {"geopoint": pos(57.0),
                                                            "radius": 100.0})
    assert kind == "area" and len(circle) == 24
    assert max(p[0] for p in circle) - 57.0 == pytest.approx(100.0 / 111_320.0)
    assert len(task_shapes("search-areas", {"areas": [[pos(1.0)], [pos(2.0)]]})) == 2
    assert task_shapes("look-at-bearing", {"bearing": 10.0}) == []


TREE_YAML = """
name: move-to
params:
  waypoint: {latitude: 57.76, longitude: 16.68, altitude: 40}
"""


def test_mission_input_reads_yaml_json_scenarios_and_commands() -> None:
    tree = mission_tree(TREE_YAML)
    assert tree["name"] == "move-to"
    assert mission_tree({"command": "start-tst", "tst": tree})["name"] == "move-to"
    assert mission_tree({"agents": [], "mission": tree})["name"] == "move-to"
    with pytest.raises(InputError, match=r"params\.waypoint"):
        mission_tree('{"name": "move-to", "params": {}}')
    with pytest.raises(InputError, match="no TST found"):
        mission_tree({"x": 1})
    with pytest.raises(InputError, match="neither JSON nor YAML"):
        mission_tree("{a: [")
    full = with_node_uuids(tree)
    assert node_uuid_of(full)
    assert node_uuid_of(without_node_uuids(full)) is None


def test_users_file_tokens_and_bearer_headers(tmp_path: Path) -> None:
    users = tmp_path / "users"
    users.write_text("# token name\nalice-token-1 alice  # the lead\n\nbob-token-22 bob\n")
    table = read_users(users)
    assert table == {"alice-token-1": "alice", "bob-token-22": "bob"}
    assert user_of(table, "bob-token-22") == "bob"
    assert user_of(table, "bob-token-2") is None and user_of(table, None) is None
    assert bearer("Bearer abc") == "abc" and bearer("bearer  abc ") == "abc"
    assert bearer("Basic abc") is None and bearer(None) is None and bearer("Bearer ") is None
    for text, says in (("short alice\n", "8 characters"), ("alice-token-1\n", "TOKEN NAME"),
                       ("alice-token-1 a\nalice-token-1 b\n", "twice"), ("# none\n", "no users")):
        users.write_text(text)
        with pytest.raises(InputError, match=says):
            read_users(users)


def test_http_addresses() -> None:
    assert parse_http("127.0.0.1:8765") == ("127.0.0.1", 8765)
    assert parse_http("8765") == ("127.0.0.1", 8765)
    assert parse_http("[::1]:0") == ("::1", 0)
    assert parse_http("0.0.0.0:80") == ("0.0.0.0", 80)
    for bad in ("localhost", ":80", "host:99999", "[::1]", "host:x"):
        with pytest.raises(ValueError):
            parse_http(bad)
    assert is_loopback("127.0.0.2") and is_loopback("::1") and is_loopback("localhost")
    assert not is_loopback("0.0.0.0") and not is_loopback("example.org")


def test_a_plan_that_kept_another_strategys_says_so() -> None:
    """`optimal` that kept the auction's plan is shown as such (`optimal (= auction)` on the
    page), from the plan and from a query-mission answer alike."""
    view = LiveView()
    live_unit(view)
    plan = {**plan_json(), "strategy": "optimal", "fallback": "auction"}
    view.mission_planned("r1", plan, plan["tst"], "alice", 100.0)
    (m,) = view.state(100.0)["missions"]
    assert (m["strategy"], m["fallback"]) == ("optimal", "auction")
    other = LiveView()
    other.mission_answer({"root-uuid": "r2", "status": "running", "strategy": "optimal",
                          "fallback": "auction", "tst": plan["tst"]}, 100.0)
    (m,) = other.state(100.0)["missions"]
    assert (m["strategy"], m["fallback"]) == ("optimal", "auction")


@pytest.mark.parametrize(("method", "host", "origin", "loopback_only", "refused"), [
    ("GET", "127.0.0.1:8765", None, True, False),
    ("GET", "localhost:8765", None, True, False),
    ("GET", "[::1]:8765", None, True, False),
    ("GET", "evil.example:8765", None, True, True),          # DNS rebinding
    ("GET", "evil.example:8765", None, False, False),        # a public page (tokens) is named so
    ("POST", "127.0.0.1:8765", None, True, False),           # curl, scripts: no Origin
    ("POST", "127.0.0.1:8765", "http://127.0.0.1:8765", True, False),
    ("POST", "127.0.0.1:8765", "http://evil.example", True, True),
    ("POST", "127.0.0.1:8765", "null", True, True),
    ("POST", "ops.example:443", "https://ops.example:443", False, False),
    ("POST", "ops.example:443", "https://evil.example", False, True),
    ("GET", "127.0.0.1:8765", "http://evil.example", True, False),  # reads: the Host rule
])
def test_cross_site_refusal(method: str, host: str, origin: str | None, loopback_only: bool,
                            refused: bool) -> None:
    from delegation.web.auth import cross_site_refusal

    assert (cross_site_refusal(method, host, origin, loopback_only) is not None) == refused


def _shared_plan() -> tuple[dict[str, Any], dict[str, Any]]:
    """(plan JSON, the operator's tree) of a real plan sharing one search among units (the
    team-search tests' concave comb, four drones and a boat, two move-tos beside it)."""
    from delegation.allocation import plan_mission
    from delegation.tst.node import to_dict
    from test_team_search import _conc_tree, fleet

    plan = plan_mission(_conc_tree(), fleet(), strategy="auction")
    assert plan.shared and plan.source is not None
    return plan.to_json(), to_dict(plan.source)


def _flat(node: dict[str, Any]) -> list[dict[str, Any]]:
    return [node, *(n for c in node["children"] for n in _flat(c))]


def test_a_shared_search_is_one_tree_node_carrying_its_parts_per_unit() -> None:
    """Issue 21: the operator's tree keeps their one search node; its parts (never tree nodes)
    hang off it with their unit and planned times, the node spans them, and the map draws each
    part as an area of its unit naming the search."""
    plan, tree = _shared_plan()
    (search,) = plan["shared-searches"]
    view = LiveView()
    root = str(node_uuid_of(plan["tst"]))
    view.mission_planned(root, plan, tree, "alice", 1.0)
    shown = view.node_tree(root)
    assert shown is not None
    nodes = {n["uuid"]: n for n in _flat(shown)}
    part_ids = [p["node-uuid"] for p in search["parts"]]
    assert not set(part_ids) & set(nodes), "parts are not tree nodes"
    node = nodes[search["node-uuid"]]
    assigned = {a["node-uuid"]: a for a in plan["assignments"]}
    parts = node["parts"]
    assert [p["uuid"] for p in parts] == part_ids and len({p["unit"] for p in parts}) >= 2
    for i, p in enumerate(parts):
        a = assigned[p["uuid"]]
        assert p["unit"] == a["execunit"].strip("/") and p["part"] == f"{i + 1}/{len(parts)}"
        assert (p["plan-start"], p["plan-end"]) == (a["start"], a["end"])
        assert p["area"] > 0 and p["status"] is None
    assert node["plan-start"] == min(p["plan-start"] for p in parts)
    assert node["plan-end"] == max(p["plan-end"] for p in parts) == search["end"]
    others = [n for n in nodes.values() if n["name"] == "move-to"]
    assert others and all("parts" not in n and n["plan-end"] for n in others)

    _, tasks = plan_geometry(plan, {})
    drawn = {t["uuid"]: t for t in tasks if t.get("part-of") == search["node-uuid"]}
    assert set(drawn) == set(part_ids)
    for p in parts:
        t = drawn[p["uuid"]]
        assert t["kind"] == "area" and t["unit"] == p["unit"] and t["part"] == p["part"]
    assert all("part-of" not in t for t in tasks if t["name"] == "move-to")


def test_a_parts_status_and_times_come_from_its_engines_feedback() -> None:
    """The service relays no feedback for parts (DESIGN 3.4): the page takes the feedback of the
    engine that runs the mission (the plan's root execunit) for the parts, and nobody else's."""
    plan, tree = _shared_plan()
    plan["tst"]["common_params"]["execunit"] = "/op0"
    (search,) = plan["shared-searches"]
    first = search["parts"][0]["node-uuid"]
    view = LiveView()
    root = str(node_uuid_of(plan["tst"]))
    view.mission_planned(root, plan, tree, "alice", 1.0)
    assert view.drain_engines() == ["op0"] and view.drain_engines() == []
    view.node_feedback({"node-uuid": root, "status": "running"}, 10.0)  # the mission starts

    def part() -> dict[str, Any]:
        shown = view.node_tree(root)
        assert shown is not None
        (node,) = [n for n in _flat(shown) if n["uuid"] == search["node-uuid"]]
        return dict(node["parts"][0])

    view.engine_feedback("op1", {"node-uuid": first, "status": "running"}, 11.0)  # not its engine
    assert part()["status"] is None
    seq = view.seq
    view.engine_feedback("op0", {"node-uuid": first, "status": "running"}, 12.0)
    assert (part()["status"], part()["actual-start"], part()["actual-end"]) == (
        "running", pytest.approx(2.0), None)
    assert any(kind == "node" and d["uuid"] == first
               for _, kind, d in view.items_since(seq) or [])
    view.engine_feedback("op0", {"node-uuid": first, "status": "succeeded"}, 50.0)
    assert (part()["status"], part()["actual-end"]) == ("succeeded", pytest.approx(40.0))
    # the engine's feedback on anything else (the instantiated tree's own nodes) is not taken
    view.engine_feedback("op0", {"node-uuid": root, "status": "failed"}, 51.0)
    shown = view.node_tree(root)
    assert shown is not None and shown["status"] == "running"


def _reshare(plan: dict[str, Any], part: str, units: tuple[str, str]) -> tuple[
        dict[str, Any], list[dict[str, Any]]]:
    """(the tree the engine runs once the part ``part`` of ``plan``'s shared search was re-shared
    between ``units``, the ``re-delegated`` feedback's rows): the part cut in two halves, each a
    search of one unit, in a ``conc`` under the part's uuid (docs/protocol.md §12.6
    ``subtrees``, as ``service.repair`` builds it)."""
    import numpy as np

    from delegation.allocation.share_plan import searched_over
    from delegation.allocation.sharing import cut, pieces_xy, region_of
    from delegation.costs import search_polygons_xy
    from delegation.geo import LocalFrame
    from delegation.tst import TstNode, map_tree
    from delegation.tst.node import parse_tree, to_dict, walk

    sent = parse_tree(plan["tst"])
    node = next(n for _, n in walk(sent) if n.node_uuid == part)
    frame = LocalFrame(57.76, 16.68)
    halves = cut(region_of(search_polygons_xy(node, frame)), np.array([1.0, 0.0]), 0.5)
    pieces = []
    for i, (half, unit) in enumerate(zip(halves, units, strict=True)):
        name, params = searched_over(node, pieces_xy(half), frame)
        pieces.append(TstNode(name=name, params=params, common_params={
            "execunit": f"/{unit}", "node-uuid": f"{part}-piece{i}"}))
    conc = TstNode(name="conc", children=tuple(pieces), common_params={"node-uuid": part})

    def swap(n: TstNode, children: tuple[TstNode, ...]) -> TstNode:
        if n.is_control:
            from dataclasses import replace
            return replace(n, children=children)
        return conc if n.node_uuid == part else n

    rows = [{"node-uuid": p.node_uuid, "replaces": part, "name": p.name, "unit": p.execunit,
             "path": f"root/children[{i}]", "swept": 0.4} for i, p in enumerate(pieces)]
    return to_dict(map_tree(sent, swap)), rows


def test_a_lost_units_part_re_shared_shows_as_its_pieces_on_the_timeline_and_map() -> None:
    """Issue 21: once a lost unit's part is re-shared (its remainder runs as pieces in its place,
    rebind ``subtrees``), the page shows the parts as they are: the pieces on their units, with
    their engine's feedback, drawn on the map; not the lost unit's part."""
    plan, tree = _shared_plan()
    plan["tst"]["common_params"]["execunit"] = "/op0"
    (search,) = plan["shared-searches"]
    lost = search["parts"][0]
    live = sorted({p["execunit"].strip("/") for p in search["parts"][1:]})[:2]
    view = LiveView()
    root = str(node_uuid_of(plan["tst"]))
    view.mission_planned(root, plan, tree, "alice", 1.0)
    view.node_feedback({"node-uuid": root, "status": "running"}, 10.0)
    current, rows = _reshare(plan, lost["node-uuid"], (live[0], live[1]))
    view.mission_feedback({"root-uuid": root, "status": "re-delegated", "tasks": rows,
                           "fail-reason": f"{lost['execunit']} lost (no heartbeat)"}, 20.0)
    # A piece's feedback before the page has the tree that runs now is kept for it.
    view.engine_feedback("op0", {"node-uuid": rows[0]["node-uuid"], "status": "running"}, 21.0)
    view.mission_answer({"root-uuid": root, "status": "running", "received": tree,
                         "current-tst": current, "nodes": []}, 22.0)

    shown = view.node_tree(root)
    assert shown is not None
    (node,) = [n for n in _flat(shown) if n["uuid"] == search["node-uuid"]]
    parts = {p["uuid"]: p for p in node["parts"]}
    pieces = [r["node-uuid"] for r in rows]
    assert lost["node-uuid"] not in parts
    assert set(parts) == {p["node-uuid"] for p in search["parts"][1:]} | set(pieces)
    for row in rows:
        piece = parts[row["node-uuid"]]
        assert piece["unit"] == row["unit"].strip("/") and piece["plan-start"] is None
    assert parts[pieces[0]]["status"] == "running"
    assert parts[pieces[0]]["actual-start"] == pytest.approx(11.0)
    assert sorted(p["part"] for p in node["parts"]) == sorted(
        f"{i + 1}/{len(parts)}" for i in range(len(parts)))
    # The other parts keep their plan, and the search its planned interval.
    assert all(p["plan-end"] is not None for u, p in parts.items() if u not in pieces)
    assert (node["plan-start"], node["plan-end"]) == (
        min(p["start"] for p in search["parts"]), search["end"])
    view.engine_feedback("op0", {"node-uuid": pieces[1], "status": "succeeded"}, 30.0)
    shown = view.node_tree(root)
    assert shown is not None
    (node,) = [n for n in _flat(shown) if n["uuid"] == search["node-uuid"]]
    assert {p["uuid"]: p["status"] for p in node["parts"]}[pieces[1]] == "succeeded"

    record = view.mission_record(root)
    assert record is not None
    _, tasks = plan_geometry(record.shown_plan or {}, {})
    drawn = {t["uuid"]: t for t in tasks if t.get("part-of") == search["node-uuid"]}
    assert lost["node-uuid"] not in drawn and set(pieces) <= set(drawn)
    for row in rows:
        assert drawn[row["node-uuid"]]["unit"] == row["unit"].strip("/")
        assert drawn[row["node-uuid"]]["kind"] == "area"
