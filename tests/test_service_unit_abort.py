"""The service's side of issue 20 items 4 and 5 (docs/protocol.md §11, §12.3), table-driven at the
core: what one task's end means for the mission. A task aborted by its own unit unasked is
re-delegated like a failure (the engine says so in the fail-reason); one aborted because someone
asked (the operator's ``$abort``, the engine stopping a failed branch) or skipped by ``$enough``
(``revoked``) is not, and does not end the mission by itself; ``signal-tst-node`` reaches the
engine as ``signal-tst-node``. The engine's side: which fail-reason an aborted task gets."""

from __future__ import annotations

import pytest

from delegation.messages import UNIT_ABORTED
from delegation.messages import NodeStatus as S
from delegation.service import ServiceConfig, ServiceCore
from test_engine_core import ctl, task
from test_engine_signals import Fleet
from test_service_core import PREFIX, on
from test_service_redelegation import _task, _tree, feedback, fleet, started_mission, statuses
from test_service_tst_face_repair import signal

#: (name, the task n1's status and fail-reason, re-delegated?, the mission's status after)
ENDS = [
    ("failed on its unit", "failed", "/u1 reported failed", True, "running"),
    ("aborted by its unit unasked", "aborted", f"/u1 {UNIT_ABORTED}", True, "running"),
    ("aborted as asked ($abort)", "aborted", "/u1 reported aborted", False, "running"),
    ("skipped by $enough", "revoked", "not started: $enough", False, "running"),
    ("succeeded", "succeeded", "", False, "running"),
]


@pytest.mark.parametrize(("status", "reason", "moved", "after"), [e[1:] for e in ENDS],
                         ids=[e[0] for e in ENDS])
def test_what_a_tasks_end_means_for_the_mission(status, reason, moved, after) -> None:
    core = ServiceCore(ServiceConfig(prefix=PREFIX))
    fleet(core, 100.0)
    started_mission(core, _tree("conc", "root-1", _task("n0", "/u0"), _task("n1", "/u1")))
    feedback(core, "root-1", "running", 101.2, root=True)
    feedback(core, "n0", "running", 101.5)
    feedback(core, "n1", "running", 101.5)
    out = feedback(core, "n1", status, 102.0, reason=reason)
    assert (len(out.jobs) == 1) is moved
    mission = core.book.get("root-1")
    assert mission.redelegating is moved and mission.status.value == after
    if moved:  # planned as for a failure (test_service_redelegation), the unit left out
        replan = core.repair.replans["root-1"]
        assert f"{status} on /u1" in replan.why and not replan.rebind
        assert "u1" not in {u.name for u in out.jobs[0].units}


def test_the_engines_verdict_ends_the_mission_when_nothing_is_re_delegated() -> None:
    core = ServiceCore(ServiceConfig(prefix=PREFIX))
    fleet(core, 100.0)
    started_mission(core, _tree("conc", "root-1", _task("n0", "/u0"), _task("n1", "/u1")))
    feedback(core, "n1", "aborted", 102.0, reason="/u1 reported aborted")  # the operator's
    feedback(core, "n0", "succeeded", 103.0)
    # conc: the other branch ran to its end, then the engine ends the root aborted (§12.3).
    assert statuses(feedback(core, "root-1", "aborted", 103.0, root=True)) == ["aborted"]


def test_signal_tst_node_is_forwarded_as_signal_tst_node() -> None:
    core = ServiceCore(ServiceConfig(prefix=PREFIX))
    fleet(core, 100.0)
    started_mission(core, _tree("conc", "root-1", _task("n0", "/u0"), _task("n1", "/u1")))
    for command in ("signal-tst-node", "signal-tst-tree"):
        [sent] = on(signal(core, command, "root-1", "$abort", 102.0, com=command),
                    "op0/tst/command")
        assert (sent["command"], sent["node-uuid"]) == (command, "root-1")


#: (name, the engine sent $abort first?, the fail-reason's end)
ABORTS = [("unasked", False, UNIT_ABORTED), ("asked", True, "reported aborted")]


@pytest.mark.parametrize(("asked", "ends"), [a[1:] for a in ABORTS], ids=[a[0] for a in ABORTS])
def test_the_engine_says_whether_a_unit_aborted_a_task_unasked(asked, ends) -> None:
    fleet_ = Fleet.of(ctl("conc", "R", task("a", "/dji0"), task("b", "/dji1")),
                      answer_signals=False)
    if asked:
        fleet_.step("node", "a", "$abort")
    fleet_.step("aborted", "a")
    assert fleet_.last("a") is S.ABORTED and fleet_.reasons["a"].endswith(ends)
    assert fleet_.last("b") is S.RUNNING  # one node's abort does not abort the tree
