"""The pure halves of the ROS 2 transport: topic translation (`delegation.ros_topics`) and what
real ROS 2 publishers put in a String (`delegation.messages.ros_text`). No rclpy needed."""

from __future__ import annotations

import json

import pytest

from delegation.errors import MessageError
from delegation.messages import decode
from delegation.messages.ros_text import json_text
from delegation.ros_topics import RosFilter, UnitNames, ros_token, ros_topic
from delegation.topics import MAX_PAYLOAD, topic_matches

# --------------------------------------------------------------------------- topics


def test_unit_topics_lose_type_and_role_and_keep_the_smarc_layout() -> None:
    assert ros_topic("waraps/unit/air/real/sam0/heartbeat") == "/sam0/waraps/heartbeat"
    assert ros_topic("waraps/unit/ground/simulation/dji-1/exec/command") == \
        "/dji_1/waraps/exec/command"
    assert ros_topic("a/b/unit/air/real/x/sensor/position") == "/x/a/b/sensor/position"
    assert ros_topic("delegation-probe/eng-1") == "/delegation_probe/eng_1"


def test_tokens_are_valid_ros_names() -> None:
    assert ros_token("drone-1") == "drone_1"
    assert ros_token("0x") == "_0x"
    assert ros_token("a.b c") == "a_b_c"
    assert ros_token("") == "_"


def test_a_concrete_name_and_rest_is_one_ros_topic_whatever_the_type() -> None:
    flt = RosFilter.of("waraps/unit/+/+/engine/tst/response")
    assert flt.concrete == "/engine/waraps/tst/response"
    names = UnitNames()
    names.heard("engine", {"name": "engine", "agent-type": "ground"})
    assert flt.mqtt_topic("/engine/waraps/tst/response", names) == \
        "waraps/unit/ground/real/engine/tst/response"


def test_a_concrete_filter_comes_back_exactly() -> None:
    mqtt = "waraps/unit/air/simulation/sim-1/exec/command"
    flt = RosFilter.of(mqtt)
    assert flt.concrete == "/sim_1/waraps/exec/command"
    assert flt.mqtt_topic("/sim_1/waraps/exec/command", UnitNames()) == mqtt


def test_name_wildcards_take_the_real_name_and_type_from_the_heartbeat() -> None:
    flt = RosFilter.of("waraps/unit/+/+/+/heartbeat")
    assert flt.concrete is None
    names = UnitNames()
    assert flt.mqtt_topic("/drone_1/waraps/heartbeat", names) == \
        "waraps/unit/unknown/real/drone_1/heartbeat"
    names.heard("drone_1", {"name": "drone-1", "agent-type": "air"})
    topic = flt.mqtt_topic("/drone_1/waraps/heartbeat", names)
    assert topic == "waraps/unit/air/real/drone-1/heartbeat"
    assert topic is not None and topic_matches(flt.mqtt, topic)
    assert flt.mqtt_topic("/drone_1/other/heartbeat", names) is None
    assert flt.mqtt_topic("/drone_1/waraps/sensor_info", names) is None


def test_a_heartbeat_never_renames_a_unit_to_another_token() -> None:
    names = UnitNames()
    names.heard("x", {"name": "someone-else", "agent-type": "air/evil"})
    assert names.name("x") == "x" and names.agent_type("x") == "unknown"


def test_what_we_publish_is_authoritative() -> None:
    names = UnitNames()
    names.published("waraps/unit/air/simulation/sim-1/heartbeat")
    names.heard("sim_1", {"name": "sim_1", "agent-type": "ground"})
    flt = RosFilter.of("waraps/unit/+/+/+/exec/response")
    assert flt.mqtt_topic("/sim_1/waraps/exec/response", names) == \
        "waraps/unit/air/simulation/sim-1/exec/response"


def test_a_filter_of_another_type_does_not_take_a_known_unit() -> None:
    names = UnitNames()
    names.heard("usv0", {"name": "usv0", "agent-type": "surface"})
    assert RosFilter.of("waraps/unit/air/+/+/heartbeat").mqtt_topic(
        "/usv0/waraps/heartbeat", names) is None


def test_multi_level_wildcards_and_per_client_levels() -> None:
    names = UnitNames()
    sensors = RosFilter.of("waraps/unit/+/+/+/sensor/#")
    assert sensors.mqtt_topic("/a/waraps/sensor/position", names) == \
        "waraps/unit/unknown/real/a/sensor/position"
    per_client = RosFilter.of("waraps/unit/ground/simulation/svc/tst/command/+")
    assert per_client.concrete is None
    assert per_client.mqtt_topic("/svc/waraps/tst/command/client_ab", names) == \
        "waraps/unit/ground/simulation/svc/tst/command/client_ab"
    answers = RosFilter.of("waraps/unit/+/+/svc/+/response")
    assert answers.mqtt_topic("/svc/waraps/tst/response", names) == \
        "waraps/unit/unknown/real/svc/tst/response"


def test_a_unit_seen_anywhere_is_subscribed_for_a_name_wildcard() -> None:
    flt = RosFilter.of("waraps/unit/+/+/+/exec/response")
    assert flt.unit_token("/sim1/waraps/heartbeat") == "sim1"
    assert flt.unit_token("/sim1/other/heartbeat") is None
    assert flt.for_unit("sim1") == "/sim1/waraps/exec/response"
    assert RosFilter.of("waraps/unit/+/+/+/sensor/#").for_unit("sim1") is None


def test_other_topics_map_level_by_level() -> None:
    flt = RosFilter.of("delegation-probe/eng-1")
    assert flt.concrete == "/delegation_probe/eng_1"
    assert flt.mqtt_topic("/delegation_probe/eng_1", UnitNames()) == "delegation-probe/eng-1"


# --------------------------------------------------------------------------- payloads

HEARTBEAT = {"agent-type": "air", "agent-uuid": "u-1", "levels": ["sensor"], "name": "sam0",
             "rate": 1.0, "stamp": 1.5, "type": "HeartBeat"}


def test_json_passes_unchanged() -> None:
    text = json.dumps(HEARTBEAT)
    assert json_text(text) == text


def test_json_wrapped_in_quotes_is_unwrapped() -> None:
    once = json.dumps(json.dumps(HEARTBEAT))
    assert json.loads(json_text(once)) == HEARTBEAT
    twice = json.dumps(once)
    assert json.loads(json_text(twice)) == HEARTBEAT


def test_python_literals_become_json() -> None:
    literal = str({**HEARTBEAT, "extra": (True, None, False)})
    assert "'" in literal and "True" in literal
    assert json.loads(json_text(literal)) == {**HEARTBEAT, "extra": [True, None, False]}
    assert json.loads(json_text(json.dumps(str(HEARTBEAT)))) == HEARTBEAT  # a quoted literal


def test_then_the_same_strict_checks_as_on_mqtt() -> None:
    decoded = decode("waraps/unit/air/real/sam0/heartbeat", json_text(str(HEARTBEAT)).encode())
    assert decoded.name == "sam0"  # type: ignore[attr-defined]
    bad = str({**HEARTBEAT, "rate": "fast"})
    with pytest.raises(MessageError):
        decode("waraps/unit/air/real/sam0/heartbeat", json_text(bad).encode())


@pytest.mark.parametrize("text", [
    "__import__('os').system('true')",  # a call: literal_eval refuses it, nothing runs
    "{1, 2}",                           # a set: no JSON
    "{1: 'a'}",                         # a non-string key
    "{'x': float('nan')}",
    "{'x': b'bytes'}",
    "{'x': 1j}",
    "not json at all",
    "\"a plain string\"",
])
def test_anything_else_reaches_the_reader_unchanged(text: str) -> None:
    assert json_text(text) == text


def test_oversized_and_deep_text_is_not_parsed() -> None:
    big = "{'a': '" + "x" * MAX_PAYLOAD + "'}"
    assert json_text(big) == big
    deep = "[" * 100_000 + "]" * 100_000
    assert json_text(deep) == deep


# --------------------------------------------------------------------------- the bridge's echoes


def test_the_bridge_drops_each_message_it_sent_once_when_it_comes_back() -> None:
    from delegation.runtime.ros_bridge import ECHO_SECONDS, _Echoes

    echoes = _Echoes()
    echoes.sent("/u/waraps/heartbeat", "{}", 0.0)
    echoes.sent("/u/waraps/heartbeat", "{}", 0.1)
    assert not echoes.is_echo("/u/waraps/heartbeat", '{"other":1}', 0.2)
    assert not echoes.is_echo("/v/waraps/heartbeat", "{}", 0.2)
    assert echoes.is_echo("/u/waraps/heartbeat", "{}", 0.2)
    assert echoes.is_echo("/u/waraps/heartbeat", "{}", 0.2)
    assert not echoes.is_echo("/u/waraps/heartbeat", "{}", 0.2)  # each once
    echoes.sent("/u/waraps/exec/command", "{}", 1.0)
    assert not echoes.is_echo("/u/waraps/exec/command", "{}", 1.0 + ECHO_SECONDS + 0.1)
    assert len(echoes) == 0  # expired: memory stays bounded
