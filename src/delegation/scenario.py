"""Scenario files (docs/scenarios.md): a fleet and a mission, in YAML or JSON.

Scenarios serve the benchmark, the demo, the simulator and the tests alike. A bad file is answered
with one ``InputError`` whose problems name the file and the field
(``scenarios/x.yaml: agents[1].position.latitude: missing``).

Agent fields (hyphenated like the rest of WARA-PS): ``name``, ``type`` (air | ground | surface |
subsurface), ``position``, ``tasks``, optional ``speeds`` (m/s per class; missing classes from the
type's defaults, see ``delegation.fleet``), ``battery`` (0..1), ``endurance`` (s at full battery),
``home``, ``camera-fov`` (degrees), ``sweep-altitude`` (m), ``rate`` (Hz, for simulated units).

``tsplib_scenario`` (``berlin52_scenario``) turns a TSPLIB instance into a delegation scenario
for the planning benchmark (see /work/shared/benchmarks/README.md).
"""

from __future__ import annotations

import json
import logging
import re
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from delegation.errors import InputError, InputProblem
from delegation.fleet import DEFAULT_CAMERA_FOV_DEG, SPEED_KEYS, UnitState, make_unit
from delegation.geo import GeoPoint, LocalFrame
from delegation.messages.base import hyphenate
from delegation.messages.errors import loc_text
from delegation.safe_yaml import load_yaml
from delegation.topics import AGENT_TYPES
from delegation.tst import CATALOGUE, TstNode, parse_and_validate

log = logging.getLogger(__name__)

__all__ = [
    "AgentSpec",
    "Scenario",
    "berlin52_scenario",
    "load_scenario",
    "read_tsplib",
    "scenario_from_dict",
    "tsplib_scenario",
]


class AgentSpec(BaseModel):
    """One unit of a scenario's fleet."""

    model_config = ConfigDict(
        alias_generator=hyphenate, populate_by_name=True, extra="forbid", frozen=True
    )

    name: str = Field(min_length=1)
    type: str
    position: GeoPoint
    tasks: list[str]
    speeds: dict[str, float] | None = None
    battery: float | None = Field(default=None, ge=0.0, le=1.0)
    endurance: float | None = Field(default=None, gt=0.0, allow_inf_nan=False)
    home: GeoPoint | None = None
    camera_fov: float | None = Field(default=None, gt=0.0, lt=180.0)
    sweep_altitude: float | None = Field(default=None, gt=0.0, allow_inf_nan=False)
    rate: float | None = Field(default=None, gt=0.0, allow_inf_nan=False)

    @field_validator("name")
    @classmethod
    def _name(cls, value: str) -> str:
        name = value.strip().strip("/")
        if not re.fullmatch(r"[A-Za-z0-9_.-]+", name):
            raise ValueError(f"{value!r} is not a unit name (letters, digits, _ . - only)")
        return name

    @field_validator("type")
    @classmethod
    def _type(cls, value: str) -> str:
        if value not in AGENT_TYPES:
            raise ValueError(f"{value!r} is not one of {', '.join(AGENT_TYPES)}")
        return value

    @field_validator("tasks")
    @classmethod
    def _tasks(cls, value: list[str]) -> list[str]:
        unknown = [t for t in value if t not in CATALOGUE]
        if unknown:
            raise ValueError(
                f"unknown task(s) {', '.join(map(repr, unknown))}: not in the catalogue"
            )
        return value

    @field_validator("speeds")
    @classmethod
    def _speeds(cls, value: dict[str, float] | None) -> dict[str, float] | None:
        if value is None:
            return None
        for key, v in value.items():
            if key not in SPEED_KEYS:
                raise ValueError(f"{key!r} is not one of {', '.join(SPEED_KEYS)}")
            if not v > 0.0 or v != v or v == float("inf"):
                raise ValueError(f"{key}: must be a positive number of m/s, not {v}")
        return value

    def unit(self) -> UnitState:
        """The planner's view of this unit (alive, idle, at its position)."""
        return make_unit(
            self.name,
            self.type,
            self.position,
            self.tasks,
            self.speeds,
            battery=self.battery,
            endurance=self.endurance,
            home=self.home,
            camera_fov_deg=DEFAULT_CAMERA_FOV_DEG if self.camera_fov is None else self.camera_fov,
            sweep_altitude=self.sweep_altitude,
        )

    def profile(self) -> dict[str, Any]:
        """What a fleet profile holds for this unit (see ``delegation.fleet``)."""
        return self.model_dump(
            by_alias=True,
            exclude_none=True,
            include={"speeds", "battery", "endurance", "home", "camera_fov", "sweep_altitude"},
        )


class Scenario(BaseModel):
    """A fleet and a mission (the TST as a C2 tool would send it, kept raw)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = Field(min_length=1)
    description: str = ""  # optional: a scenario needs a fleet and a mission, not prose
    agents: list[AgentSpec]
    mission: dict[str, Any]
    #: Where the scenario came from (a file path or ``<dict>``), for messages.
    source: str = Field(default="<dict>", exclude=True)

    def tree(self) -> TstNode:
        """The mission, parsed and validated against the task catalogue."""
        try:
            return parse_and_validate(self.mission)
        except InputError as exc:
            raise _in_mission(exc, self.source) from None

    def units(self) -> list[UnitState]:
        """The fleet as the planner sees it."""
        return [a.unit() for a in self.agents]

    def agent(self, name: str) -> AgentSpec | None:
        """The agent called ``name`` (with or without ``/``)."""
        key = name.strip("/")
        return next((a for a in self.agents if a.name == key), None)

    def profiles(self) -> dict[str, dict[str, Any]]:
        """Fleet profiles by unit name, for a ``FleetRegistry`` that runs this scenario live."""
        return {a.name: a.profile() for a in self.agents}

    def to_dict(self) -> dict[str, Any]:
        """The scenario as file data (hyphenated keys, no empty optionals)."""
        return {
            "name": self.name,
            "description": self.description,
            "agents": [
                a.model_dump(by_alias=True, exclude_none=True, mode="json") for a in self.agents
            ],
            "mission": self.mission,
        }


def _in_mission(exc: InputError, source: str) -> InputError:
    return InputError(
        [InputProblem(f"{source}: mission {p.where}", p.field, p.message) for p in exc.problems]
    )


def scenario_from_dict(data: Any, source: str = "<dict>") -> Scenario:
    """Build and check a scenario: its fields, unique agent names, and the mission tree."""
    if not isinstance(data, dict):
        raise InputError(
            InputProblem(
                source, "", "a scenario must be a mapping (name, description, agents, mission)")
        )
    try:
        scenario = Scenario.model_validate({**data, "source": source})
    except ValidationError as exc:
        problems = []
        for err in exc.errors():
            msg = err["msg"]
            if err["type"] == "missing":
                msg = "missing"
            elif err["type"] == "extra_forbidden":
                msg = "unknown field"
            msg = msg.removeprefix("Value error, ")
            problems.append(InputProblem(source, loc_text(err["loc"]) or "(top level)", msg))
        raise InputError(problems) from None
    seen: set[str] = set()
    for i, agent in enumerate(scenario.agents):
        if agent.name in seen:
            raise InputError(
                InputProblem(source, f"agents[{i}].name", f"duplicate agent name {agent.name!r}")
            )
        seen.add(agent.name)
    scenario.tree()  # raises InputError naming file, node and field
    return scenario


def read_text(path: str | Path) -> str:
    """A UTF-8 text file, or an ``InputError`` naming the file (unreadable, not UTF-8)."""
    source = str(path)
    try:
        return Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise InputError(InputProblem(source, "", f"cannot read: {exc.strerror or exc}")) from None
    except UnicodeDecodeError as exc:
        raise InputError(
            InputProblem(source, "", f"not UTF-8 text: {exc.reason} at byte {exc.start}")
        ) from None


def read_document(path: str | Path) -> Any:
    """Decoded JSON (``.json``) or YAML (any other suffix), with errors that name file and line."""
    p = Path(path)
    source = str(path)
    text = read_text(p)
    try:
        return json.loads(text) if p.suffix.lower() == ".json" else load_yaml(text)
    except RecursionError:
        raise InputError(InputProblem(source, "", "nested too deeply")) from None
    except json.JSONDecodeError as exc:
        raise InputError(
            InputProblem(
                source, "", f"not valid JSON (line {exc.lineno}, column {exc.colno}): {exc.msg}"
            )
        ) from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise InputError(InputProblem(source, "", f"not valid YAML{where}: {problem}")) from None


def load_scenario(path: str | Path) -> Scenario:
    """Load a scenario file (``.yaml``/``.yml`` or ``.json``; other suffixes are tried as YAML)."""
    return scenario_from_dict(read_document(path), str(path))


# --------------------------------------------------------------------------- TSPLIB


#: TSPLIB edge weight types whose nodes are plane coordinates (distances here are real-valued
#: Euclidean, not the format's rounded ones).
PLANAR_EDGE_WEIGHTS: tuple[str, ...] = ("EUC_2D", "CEIL_2D", "ATT")


def read_tsplib(path: str | Path) -> list[tuple[float, float]]:
    """The node coordinates of a TSPLIB file with planar coordinates (``EUC_2D``, ``CEIL_2D``,
    ``ATT``), in file order; ``InputError`` naming the file and the field for anything else."""
    source = str(path)
    lines = read_text(path).splitlines()
    header: dict[str, str] = {}
    for line in lines:
        key, sep, value = line.partition(":")
        if sep and key.strip().isupper():
            header.setdefault(key.strip(), value.strip())
    kind = header.get("EDGE_WEIGHT_TYPE")
    if kind is not None and kind not in PLANAR_EDGE_WEIGHTS:
        raise InputError(InputProblem(source, "EDGE_WEIGHT_TYPE", f"{kind} is not supported; "
                                 f"expected one of {', '.join(PLANAR_EDGE_WEIGHTS)}"))
    coords: list[tuple[float, float]] = []
    in_section = False
    for number, line in enumerate(lines, start=1):
        text = line.strip()
        if text.startswith("NODE_COORD_SECTION"):
            in_section = True
            continue
        if not in_section or not text:
            continue
        if text == "EOF" or not text[0].isdigit():
            break
        parts = text.split()
        if len(parts) < 3:
            raise InputError(InputProblem(source, f"line {number}", "expected 'id x y'"))
        try:
            coords.append((float(parts[1]), float(parts[2])))
        except ValueError:
            raise InputError(InputProblem(
                source, f"line {number}", f"not numbers: {text!r}")) from None
    if not coords:
        raise InputError(InputProblem(source, "NODE_COORD_SECTION", "no coordinates found "
                                 "(not a TSPLIB file with node coordinates?)"))
    dimension = header.get("DIMENSION")
    if dimension is not None and dimension.isdigit() and int(dimension) != len(coords):
        raise InputError(InputProblem(source, "DIMENSION", f"says {dimension} nodes, the file has "
                                 f"{len(coords)}"))
    if len(coords) < 2:
        raise InputError(InputProblem(source, "NODE_COORD_SECTION", "needs a depot and a city"))
    return coords


def tsplib_scenario(
    path_to_tsp: str | Path,
    units: int,
    speed: float = 1.0,
    site: tuple[float, float] = (57.76, 16.68),
) -> Scenario:
    """A TSPLIB instance as an mTSP delegation scenario (benchmarks/README.md).

    Points are east/north metres (1 unit = 1 m) around ``site``, the bounding box centred on it;
    node 1 is the depot, where every unit starts and has its ``home``; every other node is a
    ``move-to`` (``node-uuid`` ``<name>-<id>``) under one ``conc``. All units are identical
    ``air`` units with ``speed`` m/s in every speed class, so time x speed = distance.
    """
    if units < 1:
        raise InputError(InputProblem("tsplib", "units", f"must be at least 1, not {units}"))
    if not speed > 0.0:
        raise InputError(InputProblem("tsplib", "speed", f"must be positive, not {speed}"))
    coords = read_tsplib(path_to_tsp)
    name = Path(path_to_tsp).stem
    xs = [c[0] for c in coords]
    ys = [c[1] for c in coords]
    cx, cy = (min(xs) + max(xs)) / 2.0, (min(ys) + max(ys)) / 2.0
    frame = LocalFrame(site[0], site[1])
    points = [frame.geopoint(x - cx, y - cy) for x, y in coords]
    depot = points[0]

    agents = [
        {
            "name": f"u{k}",
            "type": "air",
            "position": depot.to_wire(),
            "home": depot.to_wire(),
            "speeds": {"slow": speed, "standard": speed, "fast": speed},
            "tasks": ["move-to"],
        }
        for k in range(units)
    ]
    children = [
        {
            "name": "move-to",
            "common_params": {"execunit": "*", "node-uuid": f"{name}-{i + 1}"},
            "params": {"speed": "standard", "waypoint": p.to_wire()},
        }
        for i, p in enumerate(points)
        if i > 0
    ]
    mission = {
        "name": "conc",
        "common_params": {"node-uuid": f"{name}-root"},
        "children": children,
    }
    return scenario_from_dict(
        {
            "name": f"{name}-{units}u",
            "description": (
                f"TSPLIB {name} as an mTSP: {units} identical unit(s) at {speed:g} m/s start and "
                f"end at node 1; the other {len(children)} nodes are move-tos under one conc."
            ),
            "agents": agents,
            "mission": mission,
        },
        source=str(path_to_tsp),
    )


#: The name the planning benchmark has used (any TSPLIB file works).
berlin52_scenario = tsplib_scenario
