"""A start naming a preview starts the previewed plan itself (issue 22): same tree, uuids,
assignment and times, with no second plan; a preview that no longer holds (a unit moved, lost,
the mission edited, the preview unknown) is planned again and the answer says why."""

from __future__ import annotations

import copy
import json
from typing import Any

import pytest

from delegation.errors import InputError
from delegation.service import ServiceConfig, ServiceCore
from delegation.service.previews import MAX_AGE, PER_CALLER, Preview, Previews
from delegation.tst.node import without_node_uuids
from test_service_core import (
    BASE,
    delegation,
    engine_answers,
    feed_engine,
    feed_unit,
    on,
    run_jobs,
)

TASKS = ["move-to", "move-path", "search-area"]


def _wp(lat: float, lon: float) -> dict[str, Any]:
    return {"latitude": lat, "longitude": lon, "altitude": 20.0}


def _tree() -> dict[str, Any]:
    """Six free move-tos around three units: enough for `optimal` to search within its limit."""
    spots = [(57.7611, 16.6805), (57.7620, 16.6830), (57.7590, 16.6790), (57.7632, 16.6801),
             (57.7585, 16.6842), (57.7603, 16.6860)]
    return {"name": "conc", "children": [
        {"name": "move-to", "common_params": {"execunit": "*"},
         "params": {"waypoint": _wp(lat, lon)}} for lat, lon in spots]}


def _core() -> ServiceCore:
    c = ServiceCore(ServiceConfig(prefix="t"))
    _fleet(c, 100.0)
    return c


UNITS = {"dji0": (57.7605, 16.6815), "dji1": (57.7600, 16.6800), "dji2": (57.7615, 16.6850)}


def _fleet(c: ServiceCore, now: float, north: float = 0.0, silent: str = "") -> None:
    """Every unit beats (``silent`` excepted), ``north`` degrees north of where it started."""
    for name, (lat, lon) in UNITS.items():
        if name != silent:
            feed_unit(c, name, lat + north, lon, TASKS, now)
    feed_engine(c, now)


def _preview(core: ServiceCore, com: str = "p-1", now: float = 101.0) -> dict[str, Any]:
    out = delegation(core, {"command": "delegate", "tst": _tree(), "strategy": "optimal",
                            "time-limit": 0.3, "preview": True}, now, com=com)
    [answer] = on(out, "delegation/response")
    assert answer["response"] == "ok", answer
    assert on(out, "op0/tst/command") == []  # a preview starts nothing
    return dict(answer["plan"])


def _start(core: ServiceCore, tree: dict[str, Any], preview_id: str | None, now: float,
           com: str = "s-1") -> tuple[dict[str, Any], int]:
    """A start naming ``preview_id``: (the started answer, how many plans it took)."""
    command: dict[str, Any] = {"com-uuid": com, "sender": "test", "command": "delegate",
                               "tst": tree, "start": True, "strategy": "optimal",
                               "time-limit": 0.3}
    if preview_id is not None:
        command["preview-id"] = preview_id
    first = core.on_message(f"{BASE}/delegation/command", json.dumps(command).encode(), now)
    planned = run_jobs(core, first, now)
    started = engine_answers(core, planned, "started", now + 0.1)
    [answer] = on(started, "delegation/response")
    assert answer["response"] == "started", answer
    return dict(answer["plan"]), len(first.jobs)


def _same_plan(started: dict[str, Any], preview: dict[str, Any]) -> None:
    for key in ("strategy", "makespan", "total-time", "total-distance", "assignments", "tst"):
        assert started[key] == preview[key], key


def test_a_start_naming_an_optimal_preview_starts_that_plan_unplanned() -> None:
    core = _core()
    preview = _preview(core)
    assert preview["preview-id"] == "p-1" and preview["strategy"] == "optimal"
    assert core.book.find(preview["tst"]["common_params"]["node-uuid"]) is None  # not a mission
    _fleet(core, 130.0)  # still where they were
    # the operator's tree as the page sends it: the previewed one (or without uuids)
    started, plans = _start(core, without_node_uuids(_tree()), "p-1", 130.0)
    assert plans == 0, "the previewed plan is started, not planned again"
    _same_plan(started, preview)
    assert started["from-preview"] == {"id": "p-1", "started": True}
    assert "preview-id" not in started
    mission = core.book.get(preview["tst"]["common_params"]["node-uuid"])
    assert mission.plan["assignments"] == preview["assignments"]
    # a preview starts once: naming it again plans again and says so
    _fleet(core, 131.0)
    again, plans = _start(core, _tree(), "p-1", 131.0, com="s-2")
    assert plans == 1 and again["from-preview"]["started"] is False
    assert "not known" in again["from-preview"]["reason"]


@pytest.mark.parametrize("change, reason", [
    ("moved", "m since the preview"),  # a unit it uses moved: its times no longer hold
    ("edited", "the mission is not the one previewed"),
    ("unknown", "not known"),
    ("expired", "not known"),
    ("lost", "no longer available"),
])
def test_a_preview_that_no_longer_holds_is_planned_again_and_the_answer_says_why(
        change: str, reason: str) -> None:
    core = _core()
    preview = _preview(core)
    used = sorted({a["execunit"].strip("/") for a in preview["assignments"]})
    tree, name, now = _tree(), "p-1", 110.0
    if change == "moved":  # every unit 50 m north
        _fleet(core, now, north=0.00045)
    elif change == "edited":
        tree["children"][0]["params"]["waypoint"]["latitude"] += 0.001
        _fleet(core, now)
    elif change == "unknown":
        name = "p-nope"
        _fleet(core, now)
    elif change == "expired":
        now = 101.0 + MAX_AGE + 1.0
        _fleet(core, now)
    elif change == "lost":  # the others beat on; the first one used is silent
        now = 140.0
        _fleet(core, now, silent=used[0])
        core.on_tick(now)  # the service judges it lost
    started, plans = _start(core, tree, name, now)
    assert plans == 1, "planned again"
    said = started["from-preview"]
    assert said["id"] == name and said["started"] is False and reason in said["reason"], said
    assert any(f"preview {name} not started, planned again" in n for n in started["notes"])
    if change == "lost":
        assert used[0] not in {a["execunit"].strip("/") for a in started["assignments"]}


def test_preview_id_only_with_a_start() -> None:
    core = _core()
    _preview(core)
    out = delegation(core, {"command": "delegate", "tst": _tree(), "preview-id": "p-1"},
                     com="x-1")
    [answer] = on(out, "delegation/response")
    assert answer["response"] == "failed" and "preview-id" in answer["fail-reason"]


def test_another_callers_preview_is_not_theirs_to_start() -> None:
    core = _core()
    _preview(core)  # sent by "test"
    _fleet(core, 110.0)
    command = {"com-uuid": "s-9", "sender": "mallory", "command": "delegate", "tst": _tree(),
               "start": True, "preview-id": "p-1"}
    first = core.on_message(f"{BASE}/delegation/command", json.dumps(command).encode(), 110.0)
    assert len(first.jobs) == 1 and any("not known" in n for n in first.jobs[0].notes)


def test_previews_are_bounded_per_caller_in_all_and_in_age() -> None:
    core = _core()
    [job] = core.planning.job(  # a job to keep
        "delegation", ("delegation", "c-0"), _tree(), 101.0,
        core.planning.options(None, None, None), start=False, source="preview").jobs
    shelf = Previews(per_caller=3, total=4, max_age=10.0)

    def kept(caller: str, i: int, at: float = 0.0) -> Preview:
        return Preview(f"id-{i}", caller, job, None, {}, at, {})  # type: ignore[arg-type]

    for i in range(5):
        shelf.keep(kept("a", i))
    assert len(shelf) == 3 and shelf.take("a", "id-1", 0.0)[0] is None
    assert shelf.take("a", "id-4", 0.0)[0] is not None
    for i in range(5):
        shelf.keep(kept("b", i))
    assert len(shelf) == 4 and shelf.take("a", "id-2", 0.0)[0] is None  # the oldest went first
    assert shelf.take("a", "id-3", 0.0)[0] is not None
    shelf.keep(kept("c", 0, at=100.0))
    assert shelf.take("c", "id-0", 111.0)[0] is None  # too old
    assert PER_CALLER >= 3  # the page previews three strategies at a time


def test_a_bad_preview_id_is_refused() -> None:
    core = _core()
    out = delegation(core, {"command": "delegate", "tst": _tree(), "start": True,
                            "preview-id": "x" * 129}, com="x-2")
    [answer] = on(out, "delegation/response")
    assert answer["response"] == "failed" and "preview-id" in answer["fail-reason"]
    with pytest.raises(InputError):
        core.planning.job("delegation", ("delegation", "x-3"), copy.deepcopy(_tree()), 101.0,
                          core.planning.options(None, None, None), start=False,
                          source="delegate", preview_id="p-1")
