"""Repair alone (`delegation.service.repair`): a lost unit's tasks re-planned as a job, its plan
started in place of the old tree, failures ending the mission; a lost engine failing its
missions waiting for it, then failed."""

from __future__ import annotations

from delegation.fleet import FleetEvent, FleetEventKind
from delegation.messages import MissionStatus, TstFeedback, encode
from delegation.runtime.core import JobDone
from delegation.service import ServiceConfig, ServiceCore, run_job
from delegation.service.jobs import JobFailed
from delegation.service.repair import INTERNAL
from test_service_core import (
    BASE,
    ENGINE,
    engine_answers,
    feed_engine,
    feed_unit,
    on,
    run_jobs,
    start_tst,
)


def _started(repair: str = "rebind") -> ServiceCore:
    core = ServiceCore(ServiceConfig(prefix="t", repair=repair))
    for i, name in enumerate(("u0", "u1")):
        feed_unit(core, name, 57.760 + i * 0.001, 16.680, ["move-to"], 100.0)
    feed_engine(core, 100.0)
    task = {"name": "move-to", "common_params": {"node-uuid": "a", "execunit": "/u0"},
            "params": {"waypoint": {"latitude": 57.7611, "longitude": 16.6805,
                                    "altitude": 20.0}}}
    tree = {"name": "seq", "common_params": {"node-uuid": "r"}, "children": [task]}
    planned = run_jobs(core, core.on_message(f"{BASE}/tst/command", start_tst(tree), 101.0),
                       101.0)
    engine_answers(core, planned, "started", 101.0)
    core.on_message(f"{ENGINE}/tst/feedback", encode(TstFeedback(node_uuid="a", status="running")),
                    101.5)
    return core


def test_a_lost_unit_is_replanned_as_a_job_and_started_in_place() -> None:
    core = _started("restart")
    out = core.repair.unit_lost(FleetEvent(FleetEventKind.LOST, "u0", 102.0), 102.0)
    [job] = out.jobs
    assert job.redelegate == "r" and job.key[0] == INTERNAL and "u0" not in {
        u.name for u in job.units}
    assert core.book.get("r").redelegating and "r" in core.repair.replans
    done = core.repair.redelegated(job, run_job(job), 102.5)
    assert [o["command"] for o in on(done, "op0/tst/command")] == ["signal-tst-tree",
                                                                   "start-tst"]
    [moved] = on(done, "delegation/feedback")
    assert moved["status"] == "re-delegated" and moved["tasks"][0]["unit"] == "/u1"
    assert not core.book.get("r").redelegating and core.repair.replans == {}


def test_a_replan_that_fails_ends_the_mission_naming_why() -> None:
    core = _started()
    [job] = core.repair.unit_lost(FleetEvent(FleetEventKind.LOST, "u0", 102.0), 102.0).jobs
    out = core.on_job_done(JobDone(job, JobFailed("planner: no")), 102.5)
    [failed] = on(out, "delegation/feedback")
    assert failed["status"] == "failed" and "/u0 lost (no heartbeat); planner: no" in \
        failed["fail-reason"]


def test_a_restarted_engine_leaves_its_missions_running_and_to_be_caught_up_with() -> None:
    core = _started()
    out = core.repair.engine_gone(FleetEvent(FleetEventKind.REBOOTED, "op0", 103.0), 103.0)
    assert on(out, "delegation/feedback") == []
    assert core.catch_up.due == {"r"}
    assert core.book.get("r").status is MissionStatus.STARTED
