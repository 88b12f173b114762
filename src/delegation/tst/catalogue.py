"""The task catalogue: every task of seed section 9, plus ``go-home`` and ``look-at-angle``.

``go-home`` is offered by the public WARA-PS example agent; ``look-at-angle`` appears in the seed's
own start-tst examples (11.1.1). Each task lists its parameters with the seed's types, its tags
(``vehicle`` tasks move the platform, so a unit runs one at a time; ``payload`` tasks use a sensor),
which parameters it cannot run without, and the defaults the service fills in.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any


class ParamType(StrEnum):
    """Parameter types as the seed names them."""

    GEOPOINT = "geopoint"
    GEOPOINTS = "geopoints"
    GEOPOINTARRAYS = "geopointarrays"
    FLOAT64 = "float64"
    INT32 = "int32"
    BOOL = "bool"
    STRING = "string"
    STRINGS = "strings"
    FLOAT64S = "float64s"


class SpeedClass(StrEnum):
    """Qualitative speed levels; their m/s are per unit (fleet profile or scenario)."""

    SLOW = "slow"
    STANDARD = "standard"
    FAST = "fast"


SPEED_CLASSES: tuple[str, ...] = tuple(s.value for s in SpeedClass)


@dataclass(frozen=True, slots=True)
class ParamSpec:
    """One task parameter."""

    name: str
    type: ParamType
    description: str = ""
    default: Any = None
    choices: tuple[str, ...] | None = None


@dataclass(frozen=True, slots=True)
class TaskSpec:
    """One task type: parameters, tags, which parameters it cannot run without."""

    name: str
    description: str
    tags: frozenset[str]
    params: dict[str, ParamSpec]
    required: tuple[str, ...] = ()
    #: Alternatives: at least one of each group must be given (e.g. geopoint or named-position).
    one_of: tuple[tuple[str, ...], ...] = ()
    defaults: dict[str, Any] = field(default_factory=dict)

    @property
    def is_vehicle(self) -> bool:
        """Vehicle tasks move the platform: a unit runs one at a time."""
        return "vehicle" in self.tags


def _p(name: str, type_: ParamType, description: str = "", **kw: Any) -> ParamSpec:
    return ParamSpec(name, type_, description, **kw)


def _speed() -> ParamSpec:
    return _p(
        "speed",
        ParamType.STRING,
        "Qualitative speed level: slow, standard or fast (platform-dependent m/s)",
        default="standard",
        choices=SPEED_CLASSES,
    )


def _task(
    name: str,
    description: str,
    tags: tuple[str, ...],
    params: list[ParamSpec],
    required: tuple[str, ...] = (),
    one_of: tuple[tuple[str, ...], ...] = (),
) -> TaskSpec:
    specs = {p.name: p for p in params}
    defaults = {p.name: p.default for p in params if p.default is not None}
    return TaskSpec(name, description, frozenset(tags), specs, required, one_of, defaults)


_TARGET_SIZE_DEFAULT = 2.0


def _search_params(area_type: bool = True) -> list[ParamSpec]:
    """What every search task takes after its area: speed, what it looks for and how big."""
    kind = [_p("area-type", ParamType.STRING)] if area_type else []
    return [
        _speed(),
        _p("target-type", ParamType.STRING),
        *kind,
        _p("target-size", ParamType.FLOAT64, "metres", default=_TARGET_SIZE_DEFAULT),
    ]

CATALOGUE: dict[str, TaskSpec] = {
    t.name: t
    for t in [
        _task(
            "image-object-detection",
            "Run detection on an image stream; result published as a sensor. $enough stops it.",
            (),
            [
                _p("image-input-url", ParamType.STRING),
                _p("image-input-ros-topic", ParamType.STRING),
                _p("score", ParamType.FLOAT64),
                _p("annotation", ParamType.STRING),
                _p("detections-sensor-topic", ParamType.STRING),
                _p("object-types", ParamType.STRINGS),
                _p("wanted-detection-rate", ParamType.INT32),
                _p("salient-points-topic", ParamType.STRING),
                _p("salient-score", ParamType.FLOAT64),
            ],
        ),
        _task(
            "look-at-bearing",
            "Point the camera along a bearing until $enough.",
            ("payload",),
            [
                _p("bearing", ParamType.FLOAT64, "degrees, clockwise"),
                _p("use-absolute-bearing", ParamType.BOOL),
                _p("tilt", ParamType.FLOAT64, "degrees, positive up"),
                _p("tilt-body-relative", ParamType.BOOL),
            ],
        ),
        _task(
            "look-at-angle",
            "Point the camera at pan/tilt angles (used by the seed's start-tst example 11.1.1).",
            ("payload",),
            [
                _p("pan", ParamType.FLOAT64),
                _p("pan-body-relative", ParamType.BOOL),
                _p("tilt", ParamType.FLOAT64),
                _p("tilt-body-relative", ParamType.BOOL),
            ],
        ),
        _task(
            "look-at-position",
            "Observe a position by moving only the camera, until $enough.",
            (),
            [
                _p("geopoint", ParamType.GEOPOINT, "The position to observe"),
                _p("named-position", ParamType.STRING, "Named position, or /unit"),
            ],
            one_of=(("geopoint", "named-position"),),
        ),
        _task(
            "look-at-positions",
            "Observe the nearest of several positions by moving only the camera, until $enough.",
            (),
            [
                _p("geopoints", ParamType.GEOPOINTS, "The positions to observe"),
                _p("named-positions", ParamType.STRINGS),
            ],
            one_of=(("geopoints", "named-positions"),),
        ),
        _task(
            "move-path",
            "Move along a path.",
            ("vehicle",),
            [_p("waypoints", ParamType.GEOPOINTS, "The positions to move to"), _speed()],
            required=("waypoints",),
        ),
        _task(
            "move-to",
            "Move to a position.",
            ("vehicle",),
            [_p("waypoint", ParamType.GEOPOINT, "The position to move to"), _speed()],
            required=("waypoint",),
        ),
        _task(
            "observe-position",
            "Observe a position (circling or hovering) for a duration or until $enough.",
            (),
            [
                _p("geopoint", ParamType.GEOPOINT, "The position to observe"),
                _speed(),
                _p("distance", ParamType.FLOAT64, "Circling radius / observation distance"),
                _p("height", ParamType.FLOAT64, "Hover height above the position"),
                _p("duration", ParamType.INT32, "Seconds; negative: until $enough"),
            ],
            required=("geopoint",),
        ),
        _task(
            "search-area",
            "Search a polygon (closed from last to first point).",
            ("vehicle",),
            [
                _p("area", ParamType.GEOPOINTS, "The area to search"),
                *_search_params(),
            ],
            required=("area",),
        ),
        _task(
            "search-areas",
            "Search several polygons.",
            ("vehicle",),
            [
                _p("areas", ParamType.GEOPOINTARRAYS, "The areas to search"),
                *_search_params(),
            ],
            required=("areas",),
        ),
        _task(
            "search-around-position",
            "Search a circle around a position.",
            ("vehicle",),
            [
                _p("geopoint", ParamType.GEOPOINT, "The centre of the search"),
                _p("radius", ParamType.FLOAT64, "metres", default=50.0),
                *_search_params(area_type=False),
            ],
            required=("geopoint",),
        ),
        _task(
            "land",
            "Land at p, or at the current position.",
            ("vehicle",),
            [
                _p("p", ParamType.GEOPOINT, "Landing position"),
                _p("land-at-current-position-flag", ParamType.BOOL),
                _p("z", ParamType.FLOAT64, "Offset from the default landing altitude", default=0.0),
                _p("heading", ParamType.FLOAT64),
            ],
        ),
        _task(
            "navigate",
            "Navigate through waypoints, optionally looping or holding.",
            (),
            [
                _p("waypoints", ParamType.GEOPOINTS),
                _p("commanded-speed", ParamType.FLOAT64S),
                _p("speed", ParamType.STRINGS),
                _p("continue-flag", ParamType.BOOL),
                _p("loop-flag", ParamType.BOOL),
                _p("hold-flag", ParamType.BOOL),
                _p("straight-line-flag", ParamType.BOOL),
            ],
            required=("waypoints",),
        ),
        _task(
            "take-off",
            "Make sure the platform is airborne.",
            ("vehicle",),
            [
                _p("height-above-takeoff", ParamType.FLOAT64),
                _p("path", ParamType.GEOPOINTS),
            ],
        ),
        _task(
            "go-home",
            "Return to the unit's home position (offered by the public example agent).",
            ("vehicle",),
            [_speed()],
        ),
    ]
}


def task_spec(name: str) -> TaskSpec | None:
    """The catalogue entry for ``name``, or None."""
    return CATALOGUE.get(name)


#: Tasks the seed does not tag ``vehicle`` but that still move the platform.
_MOVING_UNTAGGED = frozenset({"observe-position", "navigate"})


def is_vehicle_task(name: str) -> bool:
    """True when the task occupies the platform, so its unit runs it alone.

    That is every ``vehicle``-tagged task, plus ``observe-position`` and ``navigate`` (they move
    the platform although the seed does not tag them); unknown names count as vehicle tasks.
    """
    spec = CATALOGUE.get(name)
    return True if spec is None else (spec.is_vehicle or name in _MOVING_UNTAGGED)
