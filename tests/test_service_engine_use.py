"""The engine's feedback and answers applied, alone (`delegation.service.engine_use`): feedback
from where the tree went only, cancels waiting for the engine, signals authorised."""

from __future__ import annotations

import pytest

from delegation.errors import InputError
from delegation.messages import CancelMission, SignalTstNode, TstFeedback, TstResponse, encode
from delegation.service import ServiceConfig, ServiceCore
from test_service_core import (
    BASE,
    ENGINE,
    engine_answers,
    feed_engine,
    feed_unit,
    on,
    partial_tree,
    run_jobs,
    start_tst,
)


@pytest.fixture
def core() -> ServiceCore:
    c = ServiceCore(ServiceConfig(prefix="t", cancel_timeout=5.0))
    feed_unit(c, "dji0", 57.7605, 16.6815, ["move-to"], 100.0)
    feed_unit(c, "dji1", 57.7600, 16.6800, ["move-to"], 100.0)
    feed_engine(c, 100.0)
    planned = run_jobs(c, c.on_message(f"{BASE}/tst/command", start_tst(partial_tree()), 101.0),
                       101.0)
    engine_answers(c, planned, "started", 101.0)
    return c


def test_feedback_moves_the_mission_and_is_relayed_from_the_engine_it_went_to_only(
    core: ServiceCore
) -> None:
    fb = encode(TstFeedback(node_uuid="n1", status="running"))
    impostor = core.engine_use.receive("t/unit/ground/simulation/elsewhere/op0/tst/feedback", fb,
                                       102.0)
    assert impostor.publish == [] and core.book.get("root-1").node_status == {}
    relayed = core.engine_use.receive(f"{ENGINE}/tst/feedback", fb, 102.0)
    assert [f["node-uuid"] for f in on(relayed, f"{BASE}/tst/feedback")] == ["n1"]
    assert core.book.get("root-1").node_status == {"n1": "running"}


def test_an_accepted_cancel_waits_for_the_end_or_its_deadline(core: ServiceCore) -> None:
    key = ("delegation", "x-1")
    core.desk.arrive("delegation", b'{"command": "cancel-mission", "com-uuid": "x-1", '
                                   b'"root-uuid": "root-1", "sender": "test"}', 102.0)
    sent = core.engine_use.cancel(CancelMission(root_uuid="root-1", com_uuid="x-1"), key, 102.0)
    [abort] = on(sent, "op0/tst/command")
    accepted = core.on_message(f"{ENGINE}/tst/response", encode(TstResponse(
        response="ok", response_to=abort["com-uuid"])), 102.5)
    assert on(accepted, "delegation/response") == []  # not before the engine confirms
    late = core.on_tick(107.6)
    assert on(late, "delegation/response")[0]["response"] == "pending"


def test_a_signal_to_an_unknown_node_is_refused(core: ServiceCore) -> None:
    with pytest.raises(InputError, match="not a node of any mission"):
        core.engine_use.signal(SignalTstNode(node_uuid="nope", signal="$pause"), ("tst", "s"),
                               103.0)
