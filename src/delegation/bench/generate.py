"""Random scenarios for benchmarking: reproducible from a seed, in the scenario file format.

A generated scenario is a plain dict in the docs/scenarios.md layout (``name``, ``description``,
``agents``, ``mission``), so it is saved as YAML that ``load_scenario`` reads back, and read by
``scenario_from_dict`` without a file. Everything random comes from one ``numpy`` generator seeded
with ``seed``: the same arguments always give the same dict, so results can be reproduced and
sizes explored.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from delegation.errors import InputError, InputProblem
from delegation.geo import LocalFrame


@dataclass(frozen=True, slots=True)
class Site:
    """A named WARA-PS test site: where generated fleets and missions are placed."""

    name: str
    latitude: float
    longitude: float
    description: str


#: The WARA-PS sites scenarios can be generated at.
SITES: dict[str, Site] = {
    s.name: s
    for s in (
        Site("granso", 57.76, 16.68, "Gränsö, the WARA-PS maritime test site"),
        Site("motala", 58.54, 15.04, "Motala, lake Vättern"),
        Site("linkoping", 58.41, 15.62, "Linköping"),
    )
}

#: Task types the generator places; all are vehicle tasks with a location.
TASK_TYPES: tuple[str, ...] = (
    "move-to",
    "move-path",
    "search-area",
    "search-around-position",
    "observe-position",
)

#: Mission shapes: one ``conc`` over all tasks, one ``seq``, or a ``conc`` of short ``seq``s.
STRUCTURES: tuple[str, ...] = ("mixed", "conc", "seq")

#: What each agent type offers (air units offer every generated task, so none is orphaned).
_TYPE_TASKS: dict[str, tuple[str, ...]] = {
    "air": (*TASK_TYPES, "look-at-position"),
    "surface": (
        "move-to",
        "move-path",
        "search-area",
        "search-around-position",
        "observe-position",
    ),
    "ground": ("move-to", "move-path", "observe-position"),
}

#: Base speeds (m/s) per agent type; each generated unit varies them by up to +-20 %.
_TYPE_SPEEDS: dict[str, tuple[float, float, float]] = {
    "air": (4.0, 8.0, 14.0),
    "surface": (1.5, 3.0, 6.0),
    "ground": (1.0, 2.0, 4.0),
}

_TYPE_ALTITUDE: dict[str, float] = {"air": 40.0, "surface": 0.0, "ground": 0.0}
_TYPE_PREFIX: dict[str, str] = {"air": "dji", "surface": "boat", "ground": "ugv"}

#: Scenario families: ``mixed`` (random tasks, the default) and ``team-search`` (one free search
#: over a concave area 0.2-4 km2 with a heterogeneous fleet of 3-6 units, every third an endurance
#: case: ``delegation.bench.team_search``; units, tasks, site, mix, structure and radius do not
#: apply to it).
FAMILIES: tuple[str, ...] = ("mixed", "team-search")

#: Default share of each agent type in a fleet.
DEFAULT_TYPE_MIX: dict[str, float] = {"air": 0.6, "surface": 0.2, "ground": 0.2}


@dataclass(frozen=True)
class GeneratorOptions:
    """Everything that shapes a generated scenario (with the seed, it fixes the result)."""

    units: int = 5
    tasks: int = 10
    site: str = "granso"
    seed: int = 0
    #: Relative weight of each task type; missing types are not generated.
    mix: Mapping[str, float] = field(default_factory=lambda: dict.fromkeys(TASK_TYPES, 1.0))
    #: Relative share of each agent type (unit 0 is always ``air``).
    type_mix: Mapping[str, float] = field(default_factory=lambda: dict(DEFAULT_TYPE_MIX))
    structure: str = "mixed"
    #: Radius (m) around the site within which units and tasks are placed.
    radius: float = 2000.0
    #: Give every unit a ``home`` (its start position): routes become closed tours.
    homes: bool = False
    #: Which scenarios: one of ``FAMILIES``.
    family: str = "mixed"


def parse_mix(text: str, known: Sequence[str] = TASK_TYPES) -> dict[str, float]:
    """Read ``"move-to=2,search-area=1"`` (or ``"move-to,search-area"``) into weights."""
    weights: dict[str, float] = {}
    problems: list[InputProblem] = []
    for part in (p.strip() for p in text.split(",")):
        if not part:
            continue
        name, _, value = part.partition("=")
        name = name.strip()
        if name not in known:
            problems.append(InputProblem("mix", name, f"unknown; choose from {', '.join(known)}"))
            continue
        try:
            weight = float(value) if value else 1.0
        except ValueError:
            problems.append(InputProblem("mix", name, f"weight {value!r} is not a number"))
            continue
        if not math.isfinite(weight) or weight < 0:
            problems.append(InputProblem("mix", name, f"weight {value!r} must be >= 0"))
            continue
        weights[name] = weight
    if not problems and sum(weights.values()) <= 0:
        problems.append(InputProblem(
            "mix", "", "needs at least one task type with a positive weight"))
    if problems:
        raise InputError(problems)
    return weights


def _check(options: GeneratorOptions) -> None:
    problems: list[InputProblem] = []
    if options.units < 1:
        problems.append(InputProblem(
            "generator", "units", f"must be at least 1, not {options.units}"))
    if options.tasks < 1:
        problems.append(InputProblem(
            "generator", "tasks", f"must be at least 1, not {options.tasks}"))
    if options.site not in SITES:
        problems.append(
            InputProblem(
                "generator",
                "site",
                f"unknown site {options.site!r}; choose from {', '.join(SITES)}",
            )
        )
    if options.structure not in STRUCTURES:
        problems.append(
            InputProblem(
                "generator",
                "structure",
                f"{options.structure!r} is not one of {', '.join(STRUCTURES)}",
            )
        )
    bad_types = [t for t in options.mix if t not in TASK_TYPES]
    if bad_types or sum(w for w in options.mix.values() if w > 0) <= 0:
        problems.append(
            InputProblem(
                "generator", "mix", f"needs positive weights for some of {', '.join(TASK_TYPES)}"
            )
        )
    bad_agents = [t for t in options.type_mix if t not in _TYPE_TASKS]
    if bad_agents or sum(w for w in options.type_mix.values() if w > 0) <= 0:
        problems.append(
            InputProblem(
                "generator",
                "type_mix",
                f"needs positive weights for some of {', '.join(_TYPE_TASKS)}",
            )
        )
    if options.family not in FAMILIES:
        problems.append(InputProblem(
            "generator", "family", f"{options.family!r} is not one of {', '.join(FAMILIES)}"))
    if not options.radius > 0:
        problems.append(InputProblem("generator", "radius", f"must be > 0, not {options.radius}"))
    if problems:
        raise InputError(problems)


def scenario_name(options: GeneratorOptions) -> str:
    """A name that says how the scenario was made."""
    return f"gen-{options.site}-u{options.units}-t{options.tasks}-s{options.seed}"


def generate_scenario(options: GeneratorOptions | None = None, **overrides: Any) -> dict[str, Any]:
    """A random scenario dict (docs/scenarios.md layout); the same options always give the same
    dict."""
    if options is None:
        options = GeneratorOptions(**overrides)
    elif overrides:
        options = GeneratorOptions(**{**options.__dict__, **overrides})
    _check(options)
    if options.family == "team-search":
        from delegation.bench.team_search import team_scenario

        return team_scenario(options.seed)
    site = SITES[options.site]
    rng = np.random.default_rng(options.seed)
    frame = LocalFrame(site.latitude, site.longitude)
    agents = _agents(options, rng, frame)
    leaves = [_task(kind, options, rng, frame) for kind in _task_kinds(options, rng)]
    mission = _mission(leaves, options.structure, rng)
    return {
        "name": scenario_name(options),
        "description": (
            f"Generated (seed {options.seed}): {options.units} units and {options.tasks} tasks "
            f"({options.structure}) within {options.radius:g} m of {site.description}."
        ),
        "agents": agents,
        "mission": mission,
    }


def generate_many(base: GeneratorOptions, count: int) -> list[dict[str, Any]]:
    """``count`` scenarios with seeds ``base.seed``, ``base.seed + 1``, ..."""
    return [generate_scenario(replace(base, seed=base.seed + i)) for i in range(count)]


def save_scenarios(scenarios: Sequence[Mapping[str, Any]], directory: str | Path) -> list[Path]:
    """Write each scenario as ``<name>.yaml`` in ``directory`` (created); returns the paths."""
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    paths: list[Path] = []
    for scenario in scenarios:
        path = out / f"{scenario['name']}.yaml"
        text = yaml.dump(
            _flowed(dict(scenario)),
            Dumper=_ScenarioDumper,
            sort_keys=False,
            allow_unicode=True,
            width=100,
        )
        path.write_text(text, encoding="utf-8")
        paths.append(path)
    return paths


class _Flow(dict[str, Any]):
    """A mapping written on one line (GeoPoints, speeds), as in the hand-written scenarios."""


class _FlowList(list[Any]):
    """A list of names written on one line (tasks-available)."""


class _ScenarioDumper(yaml.SafeDumper):
    pass


_ScenarioDumper.add_representer(
    _Flow, lambda d, v: d.represent_mapping("tag:yaml.org,2002:map", v, flow_style=True)
)
_ScenarioDumper.add_representer(
    _FlowList, lambda d, v: d.represent_sequence("tag:yaml.org,2002:seq", v, flow_style=True)
)


def _flowed(value: Any) -> Any:
    """The same data with GeoPoints, speeds and name lists marked for one-line output."""
    if isinstance(value, dict):
        inner = {k: _flowed(v) for k, v in value.items()}
        if "latitude" in value or set(value) <= {"slow", "standard", "fast", "execunit"}:
            return _Flow(inner)
        return inner
    if isinstance(value, list):
        items = [_flowed(v) for v in value]
        return _FlowList(items) if all(isinstance(v, str) for v in value) else items
    return value


# --------------------------------------------------------------------------- pieces


def _point(frame: LocalFrame, east: float, north: float, altitude: float) -> dict[str, float]:
    lat, lon = frame.to_geo(east, north)
    return {
        "latitude": round(float(lat), 7),
        "longitude": round(float(lon), 7),
        "altitude": altitude,
    }


def _in_disc(rng: np.random.Generator, radius: float) -> tuple[float, float]:
    r = radius * math.sqrt(float(rng.random()))
    a = 2.0 * math.pi * float(rng.random())
    return r * math.cos(a), r * math.sin(a)


def _weighted(rng: np.random.Generator, weights: Mapping[str, float], n: int) -> list[str]:
    names = [k for k, w in weights.items() if w > 0]
    p = np.array([weights[k] for k in names], dtype=float)
    idx = rng.choice(len(names), size=n, p=p / p.sum())
    return [names[int(i)] for i in idx]


def _agents(
    options: GeneratorOptions, rng: np.random.Generator, frame: LocalFrame
) -> list[dict[str, Any]]:
    types = ["air", *_weighted(rng, options.type_mix, options.units - 1)]
    counters: dict[str, int] = {}
    agents: list[dict[str, Any]] = []
    for agent_type in types:
        index = counters.get(agent_type, 0)
        counters[agent_type] = index + 1
        east, north = _in_disc(rng, options.radius * 0.5)
        factor = float(rng.uniform(0.8, 1.2))
        slow, standard, fast = (round(v * factor, 2) for v in _TYPE_SPEEDS[agent_type])
        position = _point(frame, east, north, _TYPE_ALTITUDE[agent_type])
        agent: dict[str, Any] = {
            "name": f"{_TYPE_PREFIX[agent_type]}{index}",
            "type": agent_type,
            "position": position,
            "speeds": {"slow": slow, "standard": standard, "fast": fast},
            "tasks": list(_TYPE_TASKS[agent_type]),
        }
        if options.homes:
            agent["home"] = {**position, "altitude": 0.0}
        agents.append(agent)
    return agents


def _task_kinds(options: GeneratorOptions, rng: np.random.Generator) -> list[str]:
    return _weighted(rng, options.mix, options.tasks)


def _task(
    kind: str, options: GeneratorOptions, rng: np.random.Generator, frame: LocalFrame
) -> dict[str, Any]:
    east, north = _in_disc(rng, options.radius)
    speed = str(rng.choice(["slow", "standard", "standard", "fast"]))
    params: dict[str, Any]
    if kind == "move-to":
        params = {"speed": speed, "waypoint": _point(frame, east, north, 30.0)}
    elif kind == "move-path":
        count = int(rng.integers(2, 6))
        points = []
        for _ in range(count):
            points.append(_point(frame, east, north, 30.0))
            east += float(rng.uniform(-300.0, 300.0))
            north += float(rng.uniform(-300.0, 300.0))
        params = {"speed": speed, "waypoints": points}
    elif kind == "search-area":
        # A convex polygon: 4-6 corners on an ellipse, angles sorted so it never crosses itself.
        corners = int(rng.integers(4, 7))
        a, b = float(rng.uniform(60.0, 200.0)), float(rng.uniform(40.0, 150.0))
        turn = float(rng.uniform(0.0, math.pi))
        angles = np.sort(rng.uniform(0.0, 2.0 * math.pi, size=corners))
        area = []
        for ang in angles:
            x, y = a * math.cos(ang), b * math.sin(ang)
            xr = x * math.cos(turn) - y * math.sin(turn)
            yr = x * math.sin(turn) + y * math.cos(turn)
            area.append(_point(frame, east + xr, north + yr, 0.0))
        params = {"speed": speed, "area": area, "target-size": float(rng.choice([1.0, 2.0, 5.0]))}
    elif kind == "search-around-position":
        params = {
            "speed": speed,
            "geopoint": _point(frame, east, north, 0.0),
            "radius": round(float(rng.uniform(20.0, 80.0)), 1),
            "target-size": float(rng.choice([1.0, 2.0, 5.0])),
        }
    elif kind == "observe-position":
        params = {
            "speed": speed,
            "geopoint": _point(frame, east, north, 0.0),
            "duration": int(rng.integers(30, 181)),
        }
    else:  # pragma: no cover - TASK_TYPES is closed
        raise AssertionError(kind)
    return {"name": kind, "common_params": {"execunit": "*"}, "params": params}


def _mission(
    leaves: list[dict[str, Any]], structure: str, rng: np.random.Generator
) -> dict[str, Any]:
    if structure in ("conc", "seq") or len(leaves) == 1:
        name = "seq" if structure == "seq" else "conc"
        return {"name": name, "common_params": {"execunit": "*"}, "children": leaves}
    # mixed: a conc of single tasks and short seqs, some seqs holding a small conc.
    children: list[dict[str, Any]] = []
    i = 0
    while i < len(leaves):
        roll = float(rng.random())
        if roll < 0.5:
            children.append(leaves[i])
            i += 1
            continue
        size = int(rng.integers(2, 5))
        group = leaves[i : i + size]
        i += len(group)
        if len(group) == 1:
            children.append(group[0])
            continue
        if roll > 0.85 and len(group) >= 3:
            inner = {"name": "conc", "common_params": {"execunit": "*"}, "children": group[1:]}
            group = [group[0], inner]
        children.append({"name": "seq", "common_params": {"execunit": "*"}, "children": group})
    return {"name": "conc", "common_params": {"execunit": "*"}, "children": children}
