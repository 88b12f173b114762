"""Trust (issue 11, docs/security.md), message by message against the service core: strict input,
owners and operators, per-client answers, bound identities of units and the engine."""

from __future__ import annotations

import json
import logging
from typing import Any

import pytest

from delegation.allocation.planner import plan_mission
from delegation.allocation.plausibility import plausibility_notes
from delegation.fleet import FleetRegistry, make_unit
from delegation.geo import GeoPoint
from delegation.messages import HeartBeat, TstFeedback, TstResponse, decode, encode
from delegation.service import Effects, ServiceConfig, ServiceCore
from delegation.tst.node import parse_tree
from test_service_core import (
    BASE,
    ENGINE,
    PREFIX,
    _wp,
    engine_answers,
    feed_engine,
    feed_unit,
    on,
    partial_tree,
    run_jobs,
    start_tst,
)

CMD = f"{BASE}/delegation/command"
RESP = f"{BASE}/delegation/response"


def make_core(**config: Any) -> ServiceCore:
    c = ServiceCore(ServiceConfig(prefix=PREFIX, **config))
    feed_unit(c, "dji0", 57.7605, 16.6815, ["move-to", "move-path", "search-area"], 100.0)
    feed_unit(c, "dji1", 57.7600, 16.6800, ["move-to"], 100.0)
    feed_engine(c, 100.0)
    return c


@pytest.fixture
def core() -> ServiceCore:
    return make_core(operators=frozenset({"ops"}))


def send(
    core: ServiceCore, command: dict[str, Any] | bytes, now: float = 101.0, topic: str = CMD
) -> Effects:
    payload = command if isinstance(command, bytes) else json.dumps(command).encode()
    return run_jobs(core, core.on_message(topic, payload, now), now)


def answers(effects: Effects, topic: str = RESP) -> list[dict[str, Any]]:
    return [json.loads(o.payload) for o in effects.publish if o.topic == topic]


def move_to(lat: float, lon: float, **params: Any) -> dict[str, Any]:
    return {"name": "move-to", "params": {"waypoint": _wp(lat, lon), **params}}


# ---------------------------------------------------------------- strict input


@pytest.mark.parametrize(
    ("extra", "tree", "field"),
    [
        ({"start": "yes"}, move_to(57.761, 16.68), "start"),
        ({"start": 1}, move_to(57.761, 16.68), "start"),
        ({"time-limit": "2"}, move_to(57.761, 16.68), "time-limit"),
        ({}, move_to(57.761, 16.68, speed=1e308), "params.speed"),
        ({}, move_to(57.761, 16.68, speed=None), "params.speed"),
        (
            {},
            {"name": "move-to", "params": {"waypoint": {**_wp(57.7, 16.6), "altitude": 1e308}}},
            "params.waypoint.altitude",
        ),
        (
            {},
            {
                "name": "search-area",
                "params": {
                    "target-size": 1e308,
                    "area": [_wp(57.76, 16.68), _wp(57.77, 16.68), _wp(57.77, 16.69)],
                },
            },
            "params.target-size",
        ),
        (
            {},
            {
                "name": "search-area",
                "params": {"area": [_wp(57.76, 16.68), _wp(57.77, 16.68), _wp(57.78, 16.68)]},
            },
            "params.area",
        ),
        ({}, {"name": "x" * 129}, "name"),
    ],
)
def test_wrong_values_are_refused_naming_the_field(
    core: ServiceCore, extra: dict[str, Any], tree: dict[str, Any], field: str
) -> None:
    effects = send(core, {"command": "delegate", "com-uuid": "c1", "tst": tree, **extra})
    assert not effects.jobs
    (answer,) = answers(effects)
    assert answer["response"] == "failed" and answer["response-to"] == "c1"
    assert f"{field}:" in answer["fail-reason"], answer["fail-reason"]


def test_valid_input_keeps_its_answer(core: ServiceCore) -> None:
    effects = send(
        core,
        {
            "command": "delegate",
            "com-uuid": "c1",
            "start": False,
            "tst": move_to(57.761, 16.68, speed=7.5),
            "time-limit": 1,
        },
    )
    (answer,) = answers(effects)
    assert answer["response"] == "ok" and answer["plan"]["feasible"] is True


def test_nan_is_refused_naming_the_field(core: ServiceCore) -> None:
    payload = (
        b'{"command": "delegate", "com-uuid": "c-nan", "tst": {"name": "move-to", '
        b'"params": {"speed": NaN, "waypoint": {"latitude": 57.7, "longitude": 16.6}}}}'
    )
    (answer,) = answers(send(core, payload))
    assert answer["response-to"] == "c-nan"
    assert "tst.params.speed: invalid JSON: NaN" in answer["fail-reason"]


def test_empty_and_overlong_com_uuids_are_answered_and_not_kept(
    core: ServiceCore, caplog: pytest.LogCaptureFixture
) -> None:
    before = len(core.commands)
    with caplog.at_level(logging.INFO):
        (empty,) = answers(send(core, {"command": "ping", "com-uuid": ""}))
        (long,) = answers(send(core, {"command": "ping", "com-uuid": "u" * 200_000}))
        (huge,) = answers(send(core, {"command": "ping", "com-uuid": "u" * 1_000_000}))
    assert empty["response-to"] == "" and "com-uuid: must not be empty" in empty["fail-reason"]
    assert (
        long["response-to"] == ""
        and "com-uuid: Value error, is 200000 characters" in (long["fail-reason"])
    )
    assert huge["response-to"] == "" and "bytes is more than" in huge["fail-reason"]
    assert len(core.commands) == before
    assert not any(r.exc_info for r in caplog.records)  # no traceback


def test_oversized_and_unreadable_commands_are_answered_by_their_com_uuid(
    core: ServiceCore,
) -> None:
    big = b'{"com-uuid": "c-big", "command": "ping", "pad": "' + b"x" * 300_000 + b'"}'
    (answer,) = answers(send(core, big))
    assert answer["response-to"] == "c-big" and "300" in answer["fail-reason"]
    assert "more than the 262144 allowed" in answer["fail-reason"]
    (utf8,) = answers(send(core, b'{"com-uuid": "c-utf8", "command": "ping", "x": "\xff"}'))
    assert utf8["response-to"] == "c-utf8" and "not UTF-8" in utf8["fail-reason"]
    (cut,) = answers(send(core, b'{"com-uuid": "c-cut", "command": "pi'))
    assert cut["response-to"] == "c-cut" and "invalid JSON" in cut["fail-reason"]


def test_reused_com_uuid_with_another_command_is_refused(core: ServiceCore) -> None:
    (pong,) = answers(send(core, {"command": "ping", "com-uuid": "c1", "sender": "a"}))
    assert pong["response"] == "pong"
    # The same command again (keys reordered): the stored answer.
    again = answers(send(core, b'{"sender": "a", "com-uuid": "c1", "command": "ping"}'))
    assert again == [pong]
    (other,) = answers(send(core, {"command": "list-agents", "com-uuid": "c1", "sender": "a"}))
    assert other["response"] == "failed" and other["response-to"] == "c1"
    assert "com-uuid: 'c1' reused for a different command" in other["fail-reason"]
    assert answers(send(core, {"command": "ping", "com-uuid": "c1", "sender": "a"})) == [pong]


# ---------------------------------------------------------------- owners and operators


def _alice_mission(core: ServiceCore) -> str:
    effects = send(
        core, {"command": "delegate", "com-uuid": "a1", "sender": "alice", "tst": partial_tree()}
    )
    (answer,) = answers(effects)
    assert answer["response"] == "ok"
    return str(answer["plan"]["tst"]["common_params"]["node-uuid"])


def test_only_the_owner_and_operators_may_touch_a_mission(core: ServiceCore) -> None:
    root = _alice_mission(core)
    for i, command in enumerate(("query-mission", "cancel-mission")):
        (refused,) = answers(
            send(
                core,
                {"command": command, "com-uuid": f"m{i}", "sender": "mallory", "root-uuid": root},
            )
        )
        assert refused["response"] == "failed"
        assert f"mission {root} belongs to 'alice'; 'mallory' is neither" in refused["fail-reason"]
    (anon,) = answers(send(core, {"command": "query-mission", "com-uuid": "m3", "root-uuid": root}))
    assert "an anonymous caller" in anon["fail-reason"]
    (listed,) = answers(
        send(core, {"command": "list-missions", "com-uuid": "m4", "sender": "mallory"})
    )
    assert listed["missions"] == []
    (own,) = answers(
        send(
            core,
            {"command": "query-mission", "com-uuid": "a2", "sender": "alice", "root-uuid": root},
        )
    )
    assert own["response"] == "ok" and own["mission"]["owner"] == "alice"
    (ops,) = answers(send(core, {"command": "list-missions", "com-uuid": "o1", "sender": "ops"}))
    assert [m["root-uuid"] for m in ops["missions"]] == [root]
    (cancel,) = answers(
        send(
            core,
            {"command": "cancel-mission", "com-uuid": "o2", "sender": "ops", "root-uuid": root},
        )
    )
    assert cancel["response"] == "ok"


def test_signals_to_someone_elses_tree_are_refused(core: ServiceCore) -> None:
    started = engine_answers(
        core,
        run_jobs(
            core, core.on_message(f"{BASE}/tst/command", start_tst(partial_tree()), 101.0), 101.0
        ),
        "started",
        101.1,
    )
    assert started.publish
    for cmd in (
        {"command": "signal-tst-tree", "node-uuid": "root-1", "signal": "$abort"},
        {"command": "signal-unit", "unit": "/dji0", "signal": "$abort"},
    ):
        effects = core.on_message(
            f"{BASE}/tst/command",
            json.dumps({"com-uuid": f"x-{cmd['command']}", "sender": "mallory", **cmd}).encode(),
            102.0,
        )
        assert on(effects, "op0/tst/command") == []
        (answer,) = on(effects, f"{BASE}/tst/response")
        assert answer["response"] == "failed" and "belongs to 'test'" in answer["fail-reason"]


def test_answers_go_to_the_callers_response_topic(core: ServiceCore) -> None:
    mine = f"{RESP}/alice"
    effects = send(core, {"command": "ping", "com-uuid": "p1", "response-topic": mine})
    assert [o.topic for o in effects.publish] == [mine]
    bad = send(core, {"command": "ping", "com-uuid": "p2", "response-topic": "elsewhere/x"})
    (answer,) = answers(bad)
    assert answer["response"] == "failed" and "response-topic: must be" in answer["fail-reason"]
    # A per-client command topic: the client level names the caller (the broker's ACL
    # guarantees it), whatever "sender" says; the answer goes to that client's response topic.
    effects = send(
        core,
        {"command": "delegate", "com-uuid": "p3", "sender": "mallory", "tst": partial_tree()},
        topic=f"{CMD}/alice",
    )
    (answer,) = answers(effects, mine)
    assert answer["response"] == "ok" and answers(effects) == []
    (query,) = answers(
        send(core, {"command": "list-missions", "com-uuid": "p4"}, topic=f"{CMD}/alice"), mine
    )
    assert [m["owner"] for m in query["missions"]] == ["alice"]
    wrong = send(
        core,
        {"command": "ping", "com-uuid": "p5", "response-topic": f"{RESP}/bob"},
        topic=f"{CMD}/alice",
    )
    assert "'alice' may only be answered on" in answers(wrong, mine)[0]["fail-reason"]


# ---------------------------------------------------------------- bound identities


def test_a_unit_name_from_another_topic_is_ignored(caplog: pytest.LogCaptureFixture) -> None:
    fleet = FleetRegistry()
    real, fake = "w/unit/air/simulation/u0", "w/unit/air/real/u0"
    hb = HeartBeat(
        agent_type="air",
        agent_uuid="a",
        levels=["direct execution"],
        name="u0",
        rate=1.0,
        stamp=0.0,
    )
    pos = decode(f"{real}/sensor/position", b'{"latitude": 57.7, "longitude": 16.6}')
    fleet.observe(f"{real}/heartbeat", hb, 1.0)
    fleet.observe(f"{real}/sensor/position", pos, 1.0)
    with caplog.at_level(logging.WARNING):
        for t in (2.0, 2.1):
            fleet.observe(f"{fake}/heartbeat", hb.model_copy(update={"agent_uuid": "b"}), t)
            fleet.observe(
                f"{fake}/sensor/position",
                decode(f"{fake}/sensor/position", b'{"latitude": 1.0, "longitude": 1.0}'),
                t,
            )
    assert fleet.base_topic("u0") == real
    assert fleet.snapshot(2.2)[0].position.latitude == 57.7
    assert [r.message for r in caplog.records].count(
        f"fleet: ignoring {fake}: u0 is bound to {real}"
    ) == 1
    # A new agent-uuid on the same topic is a reboot, as before.
    fleet.observe(f"{real}/heartbeat", hb.model_copy(update={"agent_uuid": "c"}), 3.0)
    assert fleet.agents(3.0)[0]["reboots"] == 1


def test_the_engine_is_bound_and_feedback_only_counts_from_it(core: ServiceCore) -> None:
    fake = f"{PREFIX}/unit/air/real/op0"
    forged_hb = HeartBeat(
        agent_type="air",
        agent_uuid="evil",
        levels=["tst execution"],
        name="op0",
        rate=20.0,
        stamp=101.0,
    )
    core.on_message(f"{fake}/heartbeat", encode(forged_hb), 100.5)
    planned = run_jobs(
        core, core.on_message(f"{BASE}/tst/command", start_tst(partial_tree()), 101.0), 101.0
    )
    (sent,) = [o for o in planned.publish if o.topic.endswith("op0/tst/command")]
    assert sent.topic == f"{ENGINE}/tst/command"
    com = json.loads(sent.payload)["com-uuid"]
    forged = TstResponse(response="started", response_to=com, root_uuid="root-1")
    assert core.on_message(f"{fake}/tst/response", encode(forged), 101.1).publish == []
    started = engine_answers(core, planned, "started", 101.2)
    assert on(started, "tst/response")[0]["response"] == "started"
    done = TstFeedback(node_uuid="root-1", status="succeeded", root_flag=True)
    assert core.on_message(f"{fake}/tst/feedback", encode(done), 101.3).publish == []
    assert core.book.get("root-1").status.value == "started"
    real = core.on_message(f"{ENGINE}/tst/feedback", encode(done), 101.4)
    assert on(real, "delegation/feedback")[0]["status"] == "succeeded"


# ---------------------------------------------------------------- plausibility


def test_swapped_coordinates_are_noted_in_the_plan(
    core: ServiceCore, caplog: pytest.LogCaptureFixture
) -> None:
    with caplog.at_level(logging.WARNING):
        effects = send(
            core, {"command": "delegate", "com-uuid": "far", "tst": move_to(16.6815, 57.7605)}
        )
    (answer,) = answers(effects)
    assert answer["response"] == "ok"  # planned as asked, but flagged in the service log
    assert any("latitude and longitude look swapped" in r.message for r in caplog.records)
    units = core.units(101.0)
    plan = plan_mission(parse_tree(move_to(16.6815, 57.7605)), units, strategy="nearest")
    assert any(n.endswith("latitude and longitude look swapped") for n in plan.notes)


def test_plausibility_notes_name_the_node_and_the_nearest_unit() -> None:
    units = [make_unit("dji0", "air", GeoPoint(latitude=57.76, longitude=16.68), ["move-to"])]
    near = parse_tree(move_to(57.77, 16.69))
    swapped = parse_tree(move_to(16.68, 57.76))
    far = parse_tree(move_to(-33.9, 151.2))
    assert plausibility_notes(near, units) == []
    (note,) = plausibility_notes(swapped, units)
    assert note.startswith("root (move-to): params.waypoint is ") and "(dji0)" in note
    assert note.endswith("latitude and longitude look swapped")
    (note,) = plausibility_notes(far, units)
    assert "swapped" not in note and "km from the nearest unit" in note


def test_serve_takes_operators_max_speed_and_a_password_file(tmp_path: Any) -> None:
    from delegation.cli import build_parser
    from delegation.cli.connect import broker_settings

    secret = tmp_path / "pw"
    secret.write_text("hunter2\n")
    args = build_parser().parse_args(
        [
            "serve",
            "--broker",
            "127.0.0.1",
            "--operator",
            "ops",
            "--operator",
            "lead",
            "--max-speed",
            "30",
            "--username",
            "delegator0",
            "--password-file",
            str(secret),
        ]
    )
    assert args.operator == ["ops", "lead"] and args.max_speed == 30.0
    settings = broker_settings(args)
    assert settings is not None and settings.password == "hunter2"
    assert ServiceConfig(max_speed=args.max_speed).limits.max_speed == 30.0
