"""Planning jobs alone (`delegation.service.planning`): the tree validated once into a job, a
plan answered or recorded, a clash planned again around the busy unit."""

from __future__ import annotations

import json

import pytest

from delegation.errors import InputError
from delegation.messages import MissionStatus
from delegation.runtime.core import Effects, JobDone
from delegation.service import ServiceConfig, ServiceCore, run_job
from delegation.service.jobs import JobFailed, PlanDone
from delegation.service.planning import MAX_REPLANS
from delegation.tst.validate import ValidatedTree
from test_service_core import feed_engine, feed_unit, on, partial_tree

KEY = ("delegation", "c-1")


def _core(**config: object) -> ServiceCore:
    c = ServiceCore(ServiceConfig(prefix="t", **config))  # type: ignore[arg-type]
    feed_unit(c, "dji0", 57.7605, 16.6815, ["move-to"], 100.0)
    feed_unit(c, "dji1", 57.7600, 16.6800, ["move-to"], 100.0)
    feed_engine(c, 100.0)
    c.desk.arrive("delegation", b'{"command": "ping", "com-uuid": "c-1"}', 100.5)
    return c


def _job(core: ServiceCore, start: bool = False) -> Effects:
    return core.planning.job("delegation", KEY, partial_tree(), 101.0,
                             core.planning.options(None, None, None), start=start,
                             source="delegate")


def test_a_job_carries_the_validated_tree_units_and_when_the_command_came() -> None:
    core = _core()
    [job] = _job(core).jobs
    assert isinstance(job.tree, ValidatedTree) and job.tree.node_uuid == "root-1"
    assert {u.name for u in job.units} == {"dji0", "dji1"} and job.received == 100.5
    assert job.id == 1 and core.planning.next_id() == 2


def test_bad_input_is_refused_before_any_job() -> None:
    core = _core()
    with pytest.raises(InputError, match="strategy"):
        core.planning.options("fastest", None, None)
    tree = partial_tree()
    tree["children"][0]["params"] = {}
    with pytest.raises(InputError, match="waypoint"):
        core.planning.job("delegation", KEY, tree, 101.0, core.planning.options(None, None, None),
                          start=False, source="delegate")


def test_a_plan_without_start_is_recorded_and_answered_ok() -> None:
    core = _core()
    [job] = _job(core).jobs
    result = run_job(job)
    assert isinstance(result, PlanDone)
    out = core.planning.planned(job, result.plan, 101.1, 0.01)
    [answer] = on(out, "delegation/response")
    assert answer["response"] == "ok" and answer["plan"]["tst"]["common_params"]["node-uuid"]
    assert core.book.get("root-1").status is MissionStatus.PLANNED
    assert core.book.get("root-1").command == KEY


def test_a_start_plan_using_a_unit_busy_meanwhile_is_planned_again() -> None:
    core = _core(commitments="exclude")
    [job] = _job(core, start=True).jobs
    result = run_job(job)
    assert isinstance(result, PlanDone)
    used = {a.execunit.strip("/") for a in result.plan.assignments}
    core.view.committed = lambda but="": dict.fromkeys(used, "other")  # type: ignore[method-assign]
    for attempt in range(MAX_REPLANS):
        again = core.planning.planned(job, result.plan, 101.1, 0.01)
        assert [j.id for j in again.jobs] == [2 + attempt] and again.publish == []
    sent = core.planning.planned(job, result.plan, 101.2, 0.01)  # the budget is spent: sent
    assert on(sent, "op0/tst/command") and core.timings[-1].received == 100.5


def _control_only(width: int, kind: str = "seq") -> dict[str, object]:
    return {"name": "seq", "common_params": {"node-uuid": "root-1"},
            "children": [{"name": kind, "children": []} for _ in range(width)]}


@pytest.mark.parametrize(("tree", "nodes"), [
    ({"name": "seq", "common_params": {"node-uuid": "root-1"}, "children": []}, 1),
    (_control_only(1, "conc"), 2),
    (_control_only(1000), 1001),  # a seq of ~1,000 control children: no RecursionError either
])
def test_a_tree_of_control_nodes_only_is_answered_clearly(tree: dict[str, object],
                                                          nodes: int) -> None:
    """Issue 20 item 7: was "planner: internal error: ValueError: zero-size array to reduction
    operation minimum"; now the command fails naming what is wrong."""
    core = _core()
    [job] = core.planning.job("delegation", KEY, tree, 101.0,
                              core.planning.options(None, None, None), start=True,
                              source="delegate").jobs
    result = run_job(job)
    assert isinstance(result, JobFailed)
    assert result.reason == (f"root: children: the tree has no task node ({nodes} control "
                             "nodes only): there is nothing to plan")


def _one_move(root: str, lat: float) -> dict[str, object]:
    return {"name": "conc", "common_params": {"node-uuid": root},
            "children": [{"name": "move-to", "common_params": {"execunit": "*"},
                          "params": {"waypoint": {"latitude": lat, "longitude": 16.6815,
                                                  "altitude": 20.0}}}]}


@pytest.mark.parametrize("commitments", ["exclude", "wait"])
def test_a_burst_of_start_plans_is_planned_one_at_a_time_with_the_units_then(
        commitments: str) -> None:
    """Start plans that arrive together are handed to the planner one after another, each with
    the units as they are when the one before it is done: none is planned twice around a unit
    the one before it took (issue 19: a burst's plans were made up to four times)."""
    core = _core(commitments=commitments)
    topic = core.topics.delegation_command
    first = Effects()
    for i in range(3):
        body = {"com-uuid": f"b-{i}", "command": "delegate", "start": True,
                "tst": _one_move(f"root-b{i}", 57.7610 + 0.001 * i)}
        first.extend(core.on_message(topic, json.dumps(body).encode(), 102.0))
    assert [j.id for j in first.jobs] == [1] and core.planner_jobs == 3
    jobs, sent, now = list(first.jobs), 0, 102.1
    while jobs:
        job = jobs.pop(0)
        out = core.on_job_done(JobDone(job, run_job(job)), now)
        sent += len(on(out, "op0/tst/command"))
        jobs.extend(out.jobs)
        if out.jobs:  # the next one knows the unit the one just started holds
            [nxt] = out.jobs
            busy = set(core.view.committed())
            assert busy and nxt.id == job.id + 1
            if commitments == "exclude":
                assert busy.isdisjoint(u.name for u in nxt.units)
            else:
                assert all(u.available_at > 0 for u in nxt.units if u.name in busy)
        now += 0.1
    assert sent == (2 if commitments == "exclude" else 3) and core.planner_jobs == 0
    assert core.planning.next_id() == 4  # three plans in all: none made again


def test_a_start_plan_waiting_for_the_one_being_made_reads_the_fleet_when_handed_out() -> None:
    """A start plan that arrives while another is being made waits for it (`holds_units`): it
    reads the fleet only when handed out (issue 19: a burst read it twice per plan, once for
    nothing), and then carries the units, their speed sources and the input warnings."""
    core = _core()
    topic = core.topics.delegation_command
    first = Effects()
    for i, lat in enumerate((57.7610, 16.6815)):  # the second: latitude and longitude swapped
        body = {"com-uuid": f"d-{i}", "command": "delegate", "start": True,
                "tst": _one_move(f"root-d{i}", lat)}
        first.extend(core.on_message(topic, json.dumps(body).encode(), 102.0))
    [running] = first.jobs
    assert not running.deferred and {u.name for u in running.units} == {"dji0", "dji1"}
    [waiting] = core._start_queue
    assert waiting.deferred and waiting.units == () and waiting.warnings == ()
    out = core.on_job_done(JobDone(running, run_job(running)), 102.1)
    [nxt] = out.jobs
    assert nxt.id == waiting.id and not nxt.deferred
    assert {u.name for u in nxt.units} == {"dji0", "dji1"} and set(nxt.speed_sources) == \
        {"dji0", "dji1"}
    assert any("from the nearest unit" in w for w in nxt.warnings)
    result = run_job(nxt)
    assert isinstance(result, PlanDone) and any("from the nearest unit" in n
                                                for n in result.plan.notes)
