"""The fleet: the planner's view of a unit (``UnitState``) and the live registry that builds it.

The registry is pure: it is fed decoded messages together with ``now`` and never reads the clock,
so liveness, reboots and busy/idle are tested with explicit times.

Default speeds (m/s) per agent type, used when neither the scenario nor a fleet profile gives a
unit's speeds:

==========  =====  ========  =====  ==========================================================
type        slow   standard  fast   why
==========  =====  ========  =====  ==========================================================
air         1.5    3.0       6.0    the public WARA-PS example agent (type ``air``), our
                                    reference peer, flies exactly these
surface     1.0    2.5       5.0    small survey boats / USVs at harbour speeds
ground      0.5    1.0       2.0    wheeled field robots (walking pace at ``standard``)
subsurface  0.5    1.0       1.5    small AUVs
==========  =====  ========  =====  ==========================================================

Default sweep altitude (m above ground, or sensor height for surface/ground units) used for the
coverage footprint (see ``delegation.costs.sweep_width``): air 40, surface 10, ground 3,
subsurface 5. The default camera field of view is 60 degrees.

An unknown agent type gets the ``air`` values (the reference peer's).

Liveness: a unit is alive while its last heartbeat is younger than ``periods`` heartbeat periods
(``1/rate``), and never less than ``min_timeout`` seconds. A heartbeat with a new ``agent-uuid``
means the unit rebooted: everything it reported executing is forgotten.

Fleet profiles (``FleetRegistry(profiles=...)``) give what heartbeats do not carry: a dict keyed
by unit name or agent type (a name entry wins), each value with any of ``speeds``, ``home``,
``endurance``, ``battery``, ``camera-fov``, ``sweep-altitude`` (scenario spelling, see
``delegation.scenario``).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from delegation.geo import GeoPoint

log = logging.getLogger(__name__)

#: The agent types of seed section 5.1.
AGENT_TYPES: tuple[str, ...] = ("air", "ground", "surface", "subsurface")

#: The speed classes every ``UnitState.speeds`` holds.
SPEED_KEYS: tuple[str, str, str] = ("slow", "standard", "fast")

#: m/s per speed class and agent type (table in the module docstring).
DEFAULT_SPEEDS: dict[str, dict[str, float]] = {
    "air": {"slow": 1.5, "standard": 3.0, "fast": 6.0},
    "surface": {"slow": 1.0, "standard": 2.5, "fast": 5.0},
    "ground": {"slow": 0.5, "standard": 1.0, "fast": 2.0},
    "subsurface": {"slow": 0.5, "standard": 1.0, "fast": 1.5},
}

#: Metres above ground (sensor height) for the coverage footprint, per agent type.
DEFAULT_SWEEP_ALTITUDE: dict[str, float] = {
    "air": 40.0,
    "surface": 10.0,
    "ground": 3.0,
    "subsurface": 5.0,
}

DEFAULT_CAMERA_FOV_DEG = 60.0


def default_speeds(agent_type: str) -> dict[str, float]:
    """A fresh copy of the default speeds for ``agent_type`` (``air`` for unknown types)."""
    return dict(DEFAULT_SPEEDS.get(agent_type, DEFAULT_SPEEDS["air"]))


def complete_speeds(agent_type: str, given: Mapping[str, float] | None) -> dict[str, float]:
    """All three speed classes: the given ones, the rest from the type's defaults.

    When ``standard`` is given the missing classes keep the defaults' ratios to it (a unit twice as
    fast as the default at ``standard`` is also twice as fast at ``fast``).
    """
    base = default_speeds(agent_type)
    if not given:
        return base
    scale = 1.0
    if "standard" in given:
        scale = float(given["standard"]) / base["standard"]
    return {k: float(given[k]) if k in given else base[k] * scale for k in SPEED_KEYS}


@dataclass(frozen=True, slots=True)
class UnitState:
    """The planner's view of one unit: where it is, what it can do, how fast, how long."""

    name: str
    agent_type: str
    position: GeoPoint
    speeds: dict[str, float]
    tasks: frozenset[str]
    alive: bool = True
    busy: bool = False
    battery: float | None = None
    endurance: float | None = None
    home: GeoPoint | None = None
    camera_fov_deg: float = DEFAULT_CAMERA_FOV_DEG
    sweep_altitude: float | None = None
    base_topic: str | None = None

    @property
    def remaining_endurance(self) -> float | None:
        """Seconds of operation left (``battery * endurance``), or None when unknown.

        A known endurance with an unknown battery counts as a full battery.
        """
        if self.endurance is None:
            return None
        return (1.0 if self.battery is None else self.battery) * self.endurance

    @property
    def execunit(self) -> str:
        """The unit as a TST ``execunit`` (``/dji0``)."""
        return f"/{self.name}"

    @property
    def effective_sweep_altitude(self) -> float:
        """The sweep altitude, or the default for the agent type."""
        if self.sweep_altitude is not None:
            return self.sweep_altitude
        return DEFAULT_SWEEP_ALTITUDE.get(self.agent_type, DEFAULT_SWEEP_ALTITUDE["air"])


def make_unit(
    name: str,
    agent_type: str,
    position: GeoPoint,
    tasks: frozenset[str] | set[str] | list[str] | tuple[str, ...],
    speeds: Mapping[str, float] | None = None,
    **kw: Any,
) -> UnitState:
    """A ``UnitState`` with speeds completed from the type defaults (handy for tests and tools)."""
    return UnitState(
        name=name.strip("/"),
        agent_type=agent_type,
        position=position,
        speeds=complete_speeds(agent_type, speeds),
        tasks=frozenset(tasks),
        **kw,
    )
