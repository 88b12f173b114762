"""WARA-PS topics on ROS 2 (pure: no rclpy, no threads):
``{prefix}/unit/{type}/{role}/{name}/{rest}`` <-> ``/{name}/{prefix}/{rest}``.

SMARC's ROS 2 robots publish the seed's JSON on ``/<robot>/waraps/<suffix>``; a ROS topic has no
agent type or role. The cores keep speaking MQTT topics and filters; this module translates:

* a topic we publish loses its type and role (`ros_topic`); what we publish also tells the
  `UnitNames` registry a unit's name, type and role;
* a filter a core subscribes becomes a `RosFilter`: a ROS topic when its name and rest are
  concrete (``{p}/unit/+/+/engine/tst/response`` is ``/engine/waraps/tst/response``), else a
  pattern matched against the topics that ROS discovery finds;
* a message that arrives gets back the MQTT topic the core expects: the filter itself when it
  was concrete, else the unit's type from its heartbeat (`UnitNames`), role ``default_role``.

ROS names allow only letters, digits and ``_`` and no level may start with a digit, so every
other character becomes ``_`` (``drone-1`` is ``/drone_1/...``) and a leading digit gets a ``_``;
the real name comes back from the unit's heartbeat (its ``name`` field) or what we published.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from delegation.topics import parse_unit_topic

__all__ = ["RosFilter", "UnitNames", "ros_token", "ros_topic"]

_NOT_ROS = re.compile(r"[^A-Za-z0-9_]")

#: Role given to units whose topics we did not publish ourselves (ROS topics carry none).
DEFAULT_ROLE = "real"
#: Type given to a unit before its heartbeat was heard (ROS topics carry none).
UNKNOWN_TYPE = "unknown"


def ros_token(level: str) -> str:
    """One MQTT topic level as a ROS name token."""
    token = _NOT_ROS.sub("_", level) or "_"
    return f"_{token}" if token[0].isdigit() else token


def _tokens(levels: list[str]) -> list[str]:
    return [ros_token(level) for level in levels]


def ros_topic(topic: str) -> str:
    """Where an MQTT topic is published on ROS 2: ``/{name}/{prefix}/{rest}`` for a unit topic,
    else its levels as tokens (``delegation-probe/x`` is ``/delegation_probe/x``)."""
    parsed = parse_unit_topic(topic)
    if parsed is None:
        return "/" + "/".join(_tokens(topic.split("/")))
    levels = [parsed.name, *parsed.prefix.split("/"), *parsed.rest.split("/")]
    return "/" + "/".join(_tokens(levels))


@dataclass(slots=True)
class _Known:
    name: str
    agent_type: str
    role: str
    own: bool


@dataclass(slots=True)
class UnitNames:
    """What is known of the units behind ROS name tokens: their real name, type and role."""

    default_role: str = DEFAULT_ROLE
    _known: dict[str, _Known] = field(default_factory=dict)

    def published(self, topic: str) -> bool:
        """We publish ``topic``: its unit's name, type and role are known for sure. True when
        that changed what is known."""
        parsed = parse_unit_topic(topic)
        if parsed is None:
            return False
        return self._set(ros_token(parsed.name),
                         _Known(parsed.name, parsed.agent_type, parsed.role, True))

    def _set(self, token: str, known: _Known) -> bool:
        if self._known.get(token) == known:
            return False
        self._known[token] = known
        return True

    def heard(self, token: str, heartbeat: object) -> bool:
        """A heartbeat arrived under ``token``: learn its name and agent type (not for units we
        publish ourselves, whose topics are authoritative). True when that changed anything."""
        if not isinstance(heartbeat, dict):
            return False
        known = self._known.get(token)
        if known is not None and known.own:
            return False
        name, agent_type = heartbeat.get("name"), heartbeat.get("agent-type")
        if not isinstance(name, str) or ros_token(name.strip("/")) != token:
            name = known.name if known is not None else token
        if not isinstance(agent_type, str) or not agent_type or "/" in agent_type \
                or "+" in agent_type or "#" in agent_type:
            agent_type = known.agent_type if known is not None else UNKNOWN_TYPE
        return self._set(token, _Known(name.strip("/"), agent_type, self.default_role, False))

    def name(self, token: str) -> str:
        known = self._known.get(token)
        return known.name if known is not None else token

    def agent_type(self, token: str) -> str | None:
        known = self._known.get(token)
        return known.agent_type if known is not None else None

    def role(self, token: str) -> str:
        known = self._known.get(token)
        return known.role if known is not None else self.default_role


@dataclass(frozen=True, slots=True)
class RosFilter:
    """An MQTT filter as seen on ROS 2.

    For a unit filter, ``prefix``/``agent_type``/``role``/``name`` are its levels (``+`` where a
    wildcard) and ``rest`` the levels after the name; for any other filter ``prefix`` is None and
    ``rest`` is all its levels."""

    mqtt: str
    prefix: str | None
    agent_type: str
    role: str
    name: str
    rest: tuple[str, ...]

    @classmethod
    def of(cls, mqtt: str) -> RosFilter:
        levels = mqtt.split("/")
        for i in range(len(levels) - 5, -1, -1):
            if levels[i + 1] == "unit" and not {"+", "#"} & set(levels[: i + 1]):
                t, r, n = levels[i + 2], levels[i + 3], levels[i + 4]
                if "#" not in (t, r, n):
                    return cls(mqtt, "/".join(levels[: i + 1]), t, r, n, tuple(levels[i + 5 :]))
        return cls(mqtt, None, "", "", "", tuple(levels))

    @property
    def _pattern(self) -> list[str]:
        """The ROS levels, ``+``/``#`` kept as wildcards."""
        keep = ("+", "#")
        rest = [r if r in keep else ros_token(r) for r in self.rest]
        if self.prefix is None:
            return rest
        name = self.name if self.name == "+" else ros_token(self.name)
        return [name, *_tokens(self.prefix.split("/")), *rest]

    @property
    def concrete(self) -> str | None:
        """The one ROS topic this filter means, or None when it needs discovery."""
        pattern = self._pattern
        if "+" in pattern or "#" in pattern:
            return None
        return "/" + "/".join(pattern)

    def for_unit(self, token: str) -> str | None:
        """The ROS topic of unit ``token`` this filter means (a name wildcard, a concrete rest),
        so that it is subscribed as soon as the unit is seen, before it publishes there."""
        if self.prefix is None or self.name != "+" or {"+", "#"} & set(self.rest):
            return None
        return "/" + "/".join([token, *self._pattern[1:]])

    def unit_token(self, ros: str) -> str | None:
        """The name token of a ROS topic under this filter's prefix (``/x/waraps/...`` -> ``x``),
        whatever the rest: a unit to subscribe `for_unit`."""
        if self.prefix is None:
            return None
        levels = ros.strip("/").split("/")
        prefix = _tokens(self.prefix.split("/"))
        if len(levels) > len(prefix) + 1 and levels[1 : len(prefix) + 1] == prefix:
            return levels[0]
        return None

    def mqtt_topic(self, ros: str, names: UnitNames) -> str | None:
        """The MQTT topic a message on ROS topic ``ros`` has for this filter; None when the
        filter does not match it."""
        levels = ros.strip("/").split("/")
        if not _match(self._pattern, levels):
            return None
        if self.concrete is not None and self.prefix is None:
            return self.mqtt
        if self.prefix is None:
            return "/".join(levels)
        token = levels[0]
        known_type = names.agent_type(token)
        if self.agent_type != "+" and known_type not in (None, self.agent_type):
            return None  # a unit of another type
        agent_type = self.agent_type if self.agent_type != "+" else (known_type or UNKNOWN_TYPE)
        role = self.role if self.role != "+" else names.role(token)
        name = self.name if self.name != "+" else names.name(token)
        tail = levels[1 + len(self.prefix.split("/")) :]
        rest: list[str] = []
        for i, level in enumerate(self.rest):
            if level == "#":
                rest += tail[i:]
                break
            rest.append(tail[i] if level == "+" else level)
        return "/".join([self.prefix, "unit", agent_type, role, name, *rest])


def _match(pattern: list[str], levels: list[str]) -> bool:
    for i, p in enumerate(pattern):
        if p == "#":
            return True
        if i >= len(levels) or (p != "+" and p != levels[i]):
            return False
    return len(levels) == len(pattern)

