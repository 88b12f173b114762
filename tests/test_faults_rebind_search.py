"""A unit lost mid-sweep of a shared search, with real processes (issue 22 item 3, issue 21 item 4;
docs/protocol.md §11 and §12.6): one ``search-area`` shared among three simulated units; u1 is
killed -9 halfway through its part. What its reported positions swept is subtracted and only the
remainder is planned again among u0 and u2, run in the place of u1's part within the running tree
(``rebind-tst-nodes`` ``subtrees``). u0's and u2's own parts are never signalled nor started again
(counted on the wire), the mission succeeds, and what was flown covers the area: u1's reported
track (w/2 either side) and every part that finished.

Same set-up as `test_faults` (private mosquitto, one ``delegation sim`` process per unit, the
reference engine and the service in this process, the service quick to judge a unit lost)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from shapely.geometry import Polygon

from conftest import Collector
from delegation.costs import sweep_width
from delegation.engine import TstEngine
from delegation.fleet import make_unit
from delegation.geo import GeoPoint, LocalFrame
from delegation.runtime.broker import PrivateMosquitto
from delegation.sim.flown import footprint
from test_faults import (
    Processes,
    final_status,
    mosquitto,
    prefix,
    procs,
    pytestmark,
    ready,
    start_service,
)

__all__ = ["mosquitto", "prefix", "procs", "pytestmark"]

#: Three drones south of a 360 m x 330 m area (0.12 km2): a part each of about 0.04 km2.
HOMES = {"u0": (57.7590, 16.6800), "u1": (57.7590, 16.6830), "u2": (57.7590, 16.6860)}
SW, DLAT, DLON = (57.7600, 16.6800), 0.0030, 0.0060
TASKS = ["move-to", "search-area", "search-areas"]
SPEEDS = {"slow": 2.0, "standard": 4.0, "fast": 8.0}
#: Twice `test_faults.SPEEDUP`, with twice its heartbeat rate: the units report a position every
#: 40 m of their sweeps as there (the track's coverage is judged from these), in half the time.
SPEEDUP, RATE = 40.0, 4.0


def search_sim(procs: Processes, name: str) -> None:
    lat, lon = HOMES[name]
    agent = {"name": name, "type": "air", "rate": RATE,
             "position": {"latitude": lat, "longitude": lon, "altitude": 20.0},
             "speeds": SPEEDS, "tasks": TASKS}
    path = Path(procs.workdir) / f"{name}.json"
    path.write_text(json.dumps({"name": name, "description": "a searcher", "agents": [agent],
                                "mission": {"name": "move-to", "common_params": {},
                                            "params": {"waypoint": agent["position"]}}}))
    procs._run(name, "sim", str(path), "--speedup", str(SPEEDUP))


def area() -> list[dict[str, float]]:
    lat, lon = SW
    return [{"latitude": a, "longitude": b, "altitude": 20.0}
            for a, b in ((lat, lon), (lat + DLAT, lon), (lat + DLAT, lon + DLON),
                         (lat, lon + DLON))]


def polygon(ring: list[dict[str, float]], frame: LocalFrame) -> Polygon:
    return Polygon([frame.point_xy(GeoPoint.model_validate(p)) for p in ring])


def rings(task: dict[str, Any]) -> list[list[dict[str, float]]]:
    p = task["params"]
    return [p["area"]] if "area" in p else list(p["areas"])


def starts_on(col: Collector, unit: str) -> list[dict[str, Any]]:
    return [d for d in col.json_on(f"+/unit/+/+/{unit}/exec/command")
            if d.get("command") == "start-task"]


def test_a_unit_lost_mid_sweep_has_only_its_unswept_remainder_shared_and_the_others_fly_on(
        mosquitto: PrivateMosquitto, procs: Processes, prefix: str) -> None:
    settings = mosquitto.settings()
    for name in HOMES:
        search_sim(procs, name)
    with TstEngine(settings, prefix=prefix), start_service(settings, prefix) as service:
        ready(service, list(HOMES))
        col = Collector(settings, [f"{prefix}/unit/+/+/+/exec/#",
                                   f"{prefix}/unit/+/+/u1/sensor/position",
                                   f"{prefix}/unit/+/+/delegator0/delegation/#"]).start()
        try:
            com = "search-" + prefix
            tree = {"name": "search-area", "common_params": {"execunit": "*"},
                    "params": {"area": area(), "speed": "standard"}}
            col.publish(f"{service.config.base_topic}/delegation/command",
                        {"com-uuid": com, "command": "delegate", "tst": tree, "start": True,
                         "strategy": "auction"})
            answer = col.wait_json("+/unit/+/+/+/delegation/response",
                                   lambda d: d.get("response-to") == com, timeout=30.0)
            assert answer["response"] == "started", answer
            root = answer["plan"]["tst"]["common_params"]["node-uuid"]
            parts = {c["common_params"]["execunit"]: c for c in answer["plan"]["tst"]["children"]}
            assert set(parts) == {"/u0", "/u1", "/u2"}, "the search was not shared among three"
            u1_part = parts["/u1"]["common_params"]["node-uuid"]
            # u1 halfway through its sweep: half its part's positions reported inside it.
            frame = LocalFrame(*SW)
            mine = shapely.union_all([polygon(r, frame) for r in rings(parts["/u1"])])

            def inside() -> int:
                return sum(mine.buffer(5.0).contains(shapely.Point(frame.point_xy(
                    GeoPoint.model_validate(d)))) for d in col.json_on(
                        "+/unit/+/+/u1/sensor/position"))

            col.wait_for(lambda _m: inside() >= 12, 60.0, "u1 sweeping its part")
            procs.kill("u1")
            moved = col.wait_json("+/unit/+/+/+/delegation/feedback",
                                  lambda d: d.get("status") == "re-delegated", timeout=30.0)
            assert "/u1 lost" in moved["fail-reason"], moved
            assert {t["replaces"] for t in moved["tasks"]} == {u1_part}, moved
            assert all(0.05 < t["swept"] < 0.95 for t in moved["tasks"]), moved
            assert {t["unit"] for t in moved["tasks"]} <= {"/u0", "/u2"}, moved
            end = final_status(col, root, timeout=180.0)
            assert end["status"] == "succeeded", end
            finished = {d["task-uuid"] for d in col.json_on("+/unit/+/+/+/exec/feedback")
                        if d.get("status") == "finished"}
            # u0 and u2: their own part started once (re-sends carry its com-uuid), never
            # signalled; then the remainder's pieces they were given.
            for unit in ("u0", "u2"):
                sent = col.json_on(f"+/unit/+/+/{unit}/exec/command")
                assert not [d for d in sent if d.get("command") == "signal-task"], unit
                own = {d["com-uuid"] for d in starts_on(col, unit)
                       if d["task"]["params"].get("area") == parts[f"/{unit}"]["params"].get(
                           "area")}
                assert len(own) == 1, (unit, own)
            # What was flown covers the area: u1's track and every part that finished.
            unit = make_unit("u1", "air", GeoPoint(latitude=HOMES["u1"][0],
                                                   longitude=HOMES["u1"][1], altitude=20.0),
                             TASKS, SPEEDS)
            width = sweep_width(unit, 2.0)
            track = [frame.point_xy(GeoPoint.model_validate(d))
                     for d in col.json_on("+/unit/+/+/u1/sensor/position")]
            flown = [footprint(np.array(track), width)]  # the camera's (square) footprint
            for u in ("u0", "u2"):
                flown += [polygon(r, frame) for d in starts_on(col, u)
                          if d["task-uuid"] in finished for r in rings(d["task"])]
            whole = polygon(area(), frame)
            covered = shapely.union_all(flown).intersection(whole)
            assert covered.area >= 0.995 * whole.area, covered.area / whole.area
        finally:
            col.stop()
