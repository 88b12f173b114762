"""The service's engine link and its planning results, without a broker.

`EngineLink` is driven directly (a command out, the engine's answer in, time passing), and the
core's `on_job_done` is fed each kind of `JobResult`.
"""

from __future__ import annotations

import json
from typing import Any

import pytest

from delegation.errors import InputError
from delegation.fleet import FleetRegistry
from delegation.messages import (
    DelegationResponse,
    HeartBeat,
    MissionStatus,
    SignalTstTree,
    StartTst,
    TstResponse,
    encode,
)
from delegation.runtime.core import Effects, JobDone
from delegation.service import (
    BidsDone,
    Job,
    JobFailed,
    PlanDone,
    ServiceConfig,
    ServiceCore,
    run_job,
)
from delegation.service import jobs as jobs_module
from delegation.service.engine_link import EngineAnswer, EngineLink
from test_service_core import BASE, ENGINE, PREFIX, feed_engine, feed_unit, on, partial_tree

CONFIG = ServiceConfig(prefix=PREFIX, engine_timeout=5.0)


def live_link(now: float = 100.0) -> EngineLink:
    fleet = FleetRegistry()
    hb = HeartBeat(agent_type="ground", agent_uuid="engine", levels=["tst execution"],
                   name="op0", rate=1.0, stamp=now)
    fleet.observe(f"{ENGINE}/heartbeat", hb, now)
    return EngineLink(CONFIG, fleet)


def start(link: EngineLink, face: Any = "tst", com: str = "c-1", now: float = 100.0) -> str:
    """Send a start-tst of root-1 for the caller ``com``; returns the engine command's com-uuid."""
    out = link.send("start", (face, com), face, StartTst(receiver="op0", sender="delegator0",
                                                         tst={"name": "seq"}),
                    now, "root-1", plan={"feasible": True})
    assert out.topic == f"{ENGINE}/tst/command"
    sent = json.loads(out.payload)
    assert sent["command"] == "start-tst" and sent["receiver"] == "op0"
    return str(sent["com-uuid"])


def respond(link: EngineLink, com: str, response: str,
            fail_reason: str = "") -> EngineAnswer | None:
    resp = TstResponse(response=response, response_to=com, fail_reason=fail_reason)
    got = link.receive(f"{ENGINE}/tst/response", encode(resp))
    assert got is None or isinstance(got, EngineAnswer)
    return got


def test_a_start_answered_started() -> None:
    link = live_link()
    com = start(link)
    assert link.starting("root-1")
    got = respond(link, com, "started")
    assert got is not None and got.mission_status is MissionStatus.STARTED
    assert got.answer == TstResponse(response="started", response_to="c-1", root_uuid="root-1",
                                     com_uuid=got.answer.com_uuid)  # type: ignore[attr-defined]
    assert link.pending == {} and not link.starting("root-1")
    assert respond(link, com, "started") is None  # answered once

    delegate = start(link, face="delegation", com="d-1")
    got = respond(link, delegate, "started")
    assert got is not None and isinstance(got.answer, DelegationResponse)
    assert got.answer.response == "started" and got.answer.plan == {"feasible": True}


def test_a_mission_is_starting_until_its_last_start_request_ends() -> None:
    """`starting` is kept as a count per root (asked for every open mission per plan): a start
    sent again under its com-uuid replaces the first, an expired one stops counting."""
    link = live_link()
    com = start(link)
    assert start(link) == com and link.starting("root-1")  # the same command again
    assert respond(link, com, "started") is not None
    assert not link.starting("root-1") and link.pending == {}
    start(link, com="c-2")
    assert link.starting("root-1")
    assert link.expire(105.0) and not link.starting("root-1")


def test_a_refused_start() -> None:
    link = live_link()
    got = respond(link, start(link), "failed", fail_reason="unit /dji0 unknown")
    assert got is not None and got.mission_status is MissionStatus.FAILED
    assert got.fail_reason == "engine op0 refused the tree: unit /dji0 unknown"
    assert isinstance(got.answer, TstResponse) and got.answer.response == "failed"
    assert got.answer.fail_reason == got.fail_reason and got.answer.response_to == "c-1"


def test_an_engine_timeout_is_answered_failed_once() -> None:
    link = live_link()
    com = start(link)
    assert link.expire(104.9) == []
    expired = link.expire(105.0)
    assert len(expired) == 1 and expired[0].mission_status is MissionStatus.FAILED
    assert isinstance(expired[0].answer, TstResponse)
    assert expired[0].answer.fail_reason == "engine op0 did not answer within 5 s"
    assert link.expire(200.0) == []
    assert respond(link, com, "started") is None  # too late: already answered


def test_signals_and_cancels_pass_the_engine_answer_on() -> None:
    link = live_link()
    abort = SignalTstTree(node_uuid="root-1", signal="$abort", sender="delegator0")
    out = link.send("cancel", ("delegation", "x-1"), "delegation", abort, 100.0, "root-1")
    got = respond(link, json.loads(out.payload)["com-uuid"], "ok")
    assert got is not None and got.mission_status is None
    assert got.answer == DelegationResponse(response="ok", response_to="x-1",
                                            com_uuid=got.answer.com_uuid)  # type: ignore[attr-defined]
    out = link.send("signal", ("tst", "s-1"), "tst", abort, 100.0, "root-1")
    got = respond(link, json.loads(out.payload)["com-uuid"], "failed", "no such tree")
    assert got is not None and isinstance(got.answer, TstResponse)
    assert got.answer.fail_reason == "engine op0: no such tree"
    # A timed-out signal does not touch the mission.
    link.send("signal", ("tst", "s-2"), "tst", abort, 100.0, "root-1")
    (late,) = link.expire(106.0)
    assert late.mission_status is None and late.answer.response == "failed"  # type: ignore[attr-defined]


def test_nothing_is_sent_without_a_live_engine() -> None:
    link = EngineLink(CONFIG, FleetRegistry())
    assert link.problem(100.0) is not None and "'op0'" in (link.problem(100.0) or "")
    with pytest.raises(InputError, match="no TST engine 'op0'"):
        start(link)
    assert link.pending == {}
    # Unreadable engine messages and answers to someone else are ignored.
    live = live_link()
    assert live.receive(f"{ENGINE}/tst/response", b"{nope") is None
    assert respond(live, "someone-else", "ok") is None


def test_core_answers_an_engine_timeout_once_and_resends_it() -> None:
    core = ServiceCore(CONFIG)
    feed_unit(core, "dji0", 57.7605, 16.6815, ["move-to"], 100.0)
    feed_engine(core, 100.0)
    payload = json.dumps({"com-uuid": "c-9", "command": "start-tst", "sender": "t",
                          "tst": partial_tree()}).encode()
    first = core.on_message(f"{BASE}/tst/command", payload, 100.0)
    (job,) = first.jobs
    core.on_job_done(JobDone(job, run_job(job)), 100.1)
    expired = core.on_tick(105.2)
    (answer,) = on(expired, f"{BASE}/tst/response")
    assert answer["response"] == "failed" and "did not answer" in answer["fail-reason"]
    assert [f["status"] for f in on(expired, "delegation/feedback")] == ["failed"]
    assert core.on_tick(110.0).publish == []
    again = core.on_message(f"{BASE}/tst/command", payload, 111.0)
    assert again.publish == [o for o in expired.publish if o.topic == f"{BASE}/tst/response"]


# --------------------------------------------------------------------------- on_job_done


@pytest.fixture
def core() -> ServiceCore:
    c = ServiceCore(ServiceConfig(prefix=PREFIX))
    feed_unit(c, "dji0", 57.7605, 16.6815, ["move-to", "move-path", "search-area"], 100.0)
    feed_unit(c, "dji1", 57.7600, 16.6800, ["move-to"], 100.0)
    feed_engine(c, 100.0)
    return c


def job_for(core: ServiceCore, command: dict[str, Any], com: str = "d-1") -> Job:
    payload = json.dumps({"com-uuid": com, "sender": "t", **command}).encode()
    effects = core.on_message(f"{BASE}/delegation/command", payload, 101.0)
    assert effects.publish == []
    (job,) = effects.jobs
    assert isinstance(job, Job)
    return job


def answer_of(effects: Effects) -> dict[str, Any]:
    (answer,) = on(effects, f"{BASE}/delegation/response")
    return answer


def test_plan_done_records_the_mission_and_answers_the_plan(core: ServiceCore) -> None:
    job = job_for(core, {"command": "delegate", "tst": partial_tree()})
    result = run_job(job)
    assert isinstance(result, PlanDone) and result.plan.feasible
    effects = core.on_job_done(JobDone(job, result, 0.25), 101.5)
    assert [f["status"] for f in on(effects, "delegation/feedback")] == ["planned"]
    answer = answer_of(effects)
    # the plan of docs/plan.md §1, and its notes (here: the units are planned with default speeds)
    assert answer["response"] == "ok"
    assert answer["plan"] == {**result.plan.to_json(), "notes": result.plan.notes}
    assert any("defaults" in note for note in answer["plan"]["notes"])
    mission = core.book.get("root-1")
    assert mission.status is MissionStatus.PLANNED and mission.created == 101.5
    assert not core.timings  # only a tree sent to the engine is timed


def test_plan_done_with_start_is_timed(core: ServiceCore) -> None:
    job = job_for(core, {"command": "delegate", "tst": partial_tree(), "start": True})
    effects = core.on_job_done(JobDone(job, run_job(job), 0.25), 101.5)
    assert on(effects, "op0/tst/command") and on(effects, "delegation/response") == []
    (timing,) = core.timings
    assert (timing.root_uuid, timing.received, timing.sent, timing.planning) == (
        "root-1", 101.0, 101.5, 0.25)


def test_an_infeasible_plan_done_fails_with_the_plan(core: ServiceCore) -> None:
    tree = partial_tree()
    tree["children"].append({"name": "look-at-bearing", "common_params": {"node-uuid": "lab"},
                             "params": {"bearing": 90.0}})
    job = job_for(core, {"command": "delegate", "tst": tree})
    result = run_job(job)
    assert isinstance(result, PlanDone) and not result.plan.feasible
    answer = answer_of(core.on_job_done(JobDone(job, result), 101.5))
    assert answer["response"] == "failed" and answer["plan"]["feasible"] is False
    assert "lab" in answer["fail-reason"] and "root-1" not in core.book


def test_bids_done_answers_the_bids(core: ServiceCore) -> None:
    job = job_for(core, {"command": "get-bids", "tst": partial_tree()})
    bids = [{"node-uuid": "n1", "name": "move-to", "unit": "/dji0", "reason": "test"}]
    answer = answer_of(core.on_job_done(JobDone(job, BidsDone(bids)), 101.5))
    assert answer["response"] == "ok" and answer["bids"] == bids
    assert isinstance(run_job(job), BidsDone)


def test_job_failed_answers_its_reason(core: ServiceCore) -> None:
    job = job_for(core, {"command": "delegate", "tst": partial_tree()})
    answer = answer_of(core.on_job_done(JobDone(job, JobFailed("no can do")), 101.5))
    assert (answer["response"], answer["fail-reason"], answer["response-to"]) == (
        "failed", "no can do", "d-1")
    assert len(core.book) == 0


def test_a_job_that_raised_is_answered_failed(core: ServiceCore) -> None:
    """A planner that raised (the unit's worker hands the exception back) is an internal error."""
    job = job_for(core, {"command": "delegate", "tst": partial_tree()})
    answer = answer_of(core.on_job_done(JobDone(job, RuntimeError("kaboom")), 101.5))
    assert answer["response"] == "failed"
    assert "internal error: RuntimeError: kaboom" in answer["fail-reason"]


def test_run_job_turns_a_planner_bug_into_job_failed(core: ServiceCore,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    def broken(*_args: Any, **_kwargs: Any) -> Any:
        raise ZeroDivisionError("oops")

    monkeypatch.setattr(jobs_module, "plan_mission", broken)
    result = run_job(job_for(core, {"command": "delegate", "tst": partial_tree()}))
    assert isinstance(result, JobFailed)
    assert "internal error: ZeroDivisionError: oops" in result.reason
