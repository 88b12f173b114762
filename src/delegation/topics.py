"""The WARA-PS topic scheme and MQTT topic matching: pure, no broker, no paho.

Seed section 3.1: ``{prefix}/unit/{agent-type}/{role}/{name}/{rest}``. A unit's base topic is
learned from where its heartbeat arrives (topic minus ``/heartbeat``), so a peer needs only a
unit's name. Every module that reads or builds topics uses these helpers; the fleet registry, the
cores and the MQTT runtime alike.
"""

from __future__ import annotations

from dataclasses import dataclass

#: Default first topic level (seed section 3.1: the context, e.g. ``waraps``).
DEFAULT_PREFIX = "waraps"
#: Roles the seed names for the fourth topic level.
ROLES: tuple[str, ...] = ("simulation", "real", "playback")
#: Agent types the seed allows.
AGENT_TYPES: tuple[str, ...] = ("air", "ground", "surface", "subsurface")

#: Commands, responses and feedback are QoS 1; periodic heartbeats and sensors QoS 0.
QOS_COMMAND = 1
QOS_PERIODIC = 0
#: The largest command or status payload read (bytes), and the largest request body the page
#: reads: a larger one is refused unread.
MAX_PAYLOAD = 256 * 1024


def _check_levels(value: str, what: str) -> None:
    if not value:
        raise ValueError(f"{what} must not be empty")
    if "\x00" in value:
        raise ValueError(f"{what} must not contain NUL")
    if len(value.encode("utf-8")) > 65535:
        raise ValueError(f"{what} is longer than 65535 bytes")


@dataclass(frozen=True, slots=True)
class Topic:
    """A concrete topic name (no wildcards), as messages are published to."""

    value: str

    def __post_init__(self) -> None:
        _check_levels(self.value, "a topic")
        if "+" in self.value or "#" in self.value:
            raise ValueError(f"a topic cannot contain wildcards: {self.value!r}")

    @property
    def levels(self) -> list[str]:
        return self.value.split("/")

    def matches(self, wildcard: Wildcard | str) -> bool:
        """True when this topic is matched by ``wildcard``."""
        wc = wildcard if isinstance(wildcard, Wildcard) else Wildcard(wildcard)
        return wc.matches(self)

    def __str__(self) -> str:
        return self.value


@dataclass(frozen=True, slots=True)
class Wildcard:
    """A subscription filter with MQTT's ``+`` (one level) and ``#`` (the rest) wildcards."""

    value: str

    def __post_init__(self) -> None:
        _check_levels(self.value, "a topic filter")
        levels = self.value.split("/")
        for i, level in enumerate(levels):
            if "#" in level and (level != "#" or i != len(levels) - 1):
                raise ValueError(f"'#' must be a whole last level: {self.value!r}")
            if "+" in level and level != "+":
                raise ValueError(f"'+' must be a whole level: {self.value!r}")

    def matches(self, topic: Topic | str) -> bool:
        """MQTT matching: ``a/#`` matches ``a``; wildcards never match a leading ``$``."""
        name = topic.value if isinstance(topic, Topic) else topic
        t_levels = name.split("/")
        f_levels = self.value.split("/")
        if name.startswith("$") and f_levels[0] in ("+", "#"):
            return False
        for i, f in enumerate(f_levels):
            if f == "#":
                return True
            if i >= len(t_levels):
                return False
            if f != "+" and f != t_levels[i]:
                return False
        return len(t_levels) == len(f_levels)

    def __str__(self) -> str:
        return self.value


def topic_matches(pattern: str, topic: str) -> bool:
    """Shorthand for ``Wildcard(pattern).matches(topic)``."""
    return Wildcard(pattern).matches(topic)


@dataclass(frozen=True, slots=True)
class UnitTopic:
    """A topic split by the WARA-PS scheme ``{prefix}/unit/{agent-type}/{role}/{name}/{rest}``."""

    prefix: str
    agent_type: str
    role: str
    name: str
    rest: str

    @property
    def base(self) -> str:
        """The unit's base topic (everything before ``rest``)."""
        return unit_base_topic(self.name, self.agent_type, self.role, self.prefix)


def unit_base_topic(
    name: str, agent_type: str, role: str = "simulation", prefix: str = DEFAULT_PREFIX
) -> str:
    """``{prefix}/unit/{agent-type}/{role}/{name}``; names are given without a leading ``/``."""
    parts = {"name": name.strip("/"), "agent type": agent_type, "role": role, "prefix": prefix}
    for what, value in parts.items():
        if not value or "/" in value or "+" in value or "#" in value:
            raise ValueError(f"invalid {what} for a topic: {value!r}")
    return f"{prefix}/unit/{agent_type}/{role}/{parts['name']}"


def parse_unit_topic(topic: str) -> UnitTopic | None:
    """Split a unit topic; None when it does not follow the scheme.

    The prefix may itself have several levels; the ``unit`` level is found from the end so that
    ``a/b/unit/air/simulation/dji0/heartbeat`` works.
    """
    levels = topic.split("/")
    for i in range(len(levels) - 5, -1, -1):
        if levels[i + 1] == "unit" and i >= 0:
            prefix = "/".join(levels[: i + 1])
            agent_type, role, name = levels[i + 2], levels[i + 3], levels[i + 4]
            rest = "/".join(levels[i + 5 :])
            if prefix and agent_type and role and name and rest:
                return UnitTopic(prefix, agent_type, role, name, rest)
    return None


def base_from_heartbeat(topic: str) -> str | None:
    """A unit's base topic from where its heartbeat arrived (topic minus ``/heartbeat``)."""
    suffix = "/heartbeat"
    if topic.endswith(suffix) and len(topic) > len(suffix):
        return topic[: -len(suffix)]
    return None


def unit_filter(prefix: str = DEFAULT_PREFIX, rest: str = "#") -> str:
    """A filter over every unit's ``rest`` under ``prefix`` (``heartbeat``, ``exec/response``)."""
    return f"{prefix}/unit/+/+/+/{rest}"


#: Info topics directly under a unit's base topic (``delegation.messages.INFO``'s keys).
INFO_LEVELS: frozenset[str] = frozenset(
    {"heartbeat", "sensor_info", "direct_execution_info", "tst_execution_info", "delegation_info"}
)


def split_unit_topic(topic: str) -> tuple[str, str] | None:
    """(base topic, rest) for a topic under a unit, e.g. ``(waraps/unit/air/simulation/dji0,
    sensor/position)``; None for topics the fleet registry does not read.

    Unlike `parse_unit_topic` it does not need the ``unit`` level: any base works.
    """
    levels = topic.strip("/").split("/")
    if len(levels) >= 2 and levels[-1] in INFO_LEVELS:
        return "/".join(levels[:-1]), levels[-1]
    if len(levels) >= 3 and levels[-2] in ("sensor", "exec", "tst", "delegation"):
        return "/".join(levels[:-2]), "/".join(levels[-2:])
    return None


def type_from_base(base: str) -> str | None:
    """The agent type in ``{prefix}/unit/{type}/{role}/{name}``, if the topic follows the scheme."""
    levels = base.split("/")
    if len(levels) >= 4 and levels[-4] == "unit" and levels[-3] in AGENT_TYPES:
        return levels[-3]
    return None
