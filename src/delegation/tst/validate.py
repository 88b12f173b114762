"""Parameter validation against the task catalogue, and filling in defaults.

Readers are lenient where real WARA-PS traffic is (a ``geopoint`` given as a one-element list, a
``speed`` given as m/s or ``[7.0]`` as in the seed's observe-position example; unknown params are
kept); everything else wrong is reported with the node and the field.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from shapely.geometry import LinearRing, Polygon

from delegation.errors import InputError, InputProblem, short_repr
from delegation.geo import GeoPoint, LocalFrame
from delegation.tst.catalogue import CATALOGUE, SPEED_CLASSES, ParamType, TaskSpec
from delegation.tst.node import (
    TstNode,
    classify_execunit,
    map_tree,
    parse_tree,
    same_nodes,
    walk,
    where,
    with_uuids,
)

INT32_MIN, INT32_MAX = -(2**31), 2**31 - 1


@dataclass(frozen=True, slots=True)
class Limits:
    """Physical ranges a task's numbers must lie in (a plan with a 1e308 m/s move-to, a 1e308 m
    altitude or target size is no plan); ``max_speed`` is configurable (``ServiceConfig``)."""

    #: The highest explicit speed (m/s) a ``move-to`` may ask for.
    max_speed: float = 100.0
    #: Altitudes and heights (m): the deepest ocean to far above any aircraft here.
    altitude: tuple[float, float] = (-12_000.0, 50_000.0)
    #: Sizes and radii (m).
    max_size: float = 100_000.0
    #: The longest duration (s) a task may be given (negative: until ``$enough``).
    max_duration: int = 7 * 24 * 3600
    #: Longest name, node-uuid, execunit and string param.
    max_string: int = 128
    max_text: int = 4096


DEFAULT_LIMITS = Limits()

#: Params measured in metres that must lie in (0, max_size]: (name, may be zero).
_SIZES: dict[str, bool] = {"target-size": False, "radius": False, "distance": True}
#: Params that are heights (m), checked against ``Limits.altitude``.
_HEIGHTS = frozenset({"height", "height-above-takeoff", "z"})
#: The narrowest mean width (m: area over half the perimeter) a search polygon may have: thinner
#: is a line (collinear points), not an area to search.
MIN_AREA_WIDTH_M = 1.0


def _is_number(v: Any) -> bool:
    """A finite JSON number that fits a float (huge integers do not)."""
    if isinstance(v, bool) or not isinstance(v, int | float):
        return False
    try:
        return math.isfinite(v)
    except OverflowError:
        return False


def geopoint_problems(
    value: Any, field: str, limits: Limits = DEFAULT_LIMITS
) -> list[tuple[str, str]]:
    """(field, message) pairs for a GeoPoint value; empty when it is valid."""
    if isinstance(value, list) and len(value) == 1:
        value = value[0]  # lenient: the seed's observe-position example wraps it in a list
    if not isinstance(value, dict):
        return [(field, f"must be a GeoPoint object, not {type(value).__name__}")]
    out: list[tuple[str, str]] = []
    for key, lo, hi in (("latitude", -90.0, 90.0), ("longitude", -180.0, 180.0)):
        v = value.get(key)
        if v is None:
            out.append((f"{field}.{key}", "missing"))
        elif not _is_number(v):
            out.append((f"{field}.{key}", f"must be a number, not {short_repr(v)}"))
        elif not lo <= v <= hi:
            out.append((f"{field}.{key}", f"{v} is outside [{lo:g}, {hi:g}]"))
    alt = value.get("altitude")
    if alt is not None and not _is_number(alt):
        out.append((f"{field}.altitude", f"must be a number, not {short_repr(alt)}"))
    elif alt is not None and not limits.altitude[0] <= alt <= limits.altitude[1]:
        lo, hi = limits.altitude
        out.append((f"{field}.altitude", f"{alt} m is outside [{lo:g}, {hi:g}]"))
    return out


def read_geopoint(value: Any) -> GeoPoint:
    """A GeoPoint from a (validated) param value, accepting the one-element-list form."""
    if isinstance(value, list) and len(value) == 1:
        value = value[0]
    return GeoPoint.model_validate(value)


def _value_problems(
    spec_type: ParamType, value: Any, field: str, limits: Limits = DEFAULT_LIMITS
) -> list[tuple[str, str]]:
    if spec_type is ParamType.GEOPOINT:
        return geopoint_problems(value, field, limits)
    if spec_type is ParamType.GEOPOINTS:
        if not isinstance(value, list):
            return [(field, f"must be a list of GeoPoints, not {type(value).__name__}")]
        return [
            p for i, v in enumerate(value) for p in geopoint_problems(v, f"{field}[{i}]", limits)
        ]
    if spec_type is ParamType.GEOPOINTARRAYS:
        if not isinstance(value, list):
            return [(field, f"must be a list of GeoPoint lists, not {type(value).__name__}")]
        return [
            p
            for i, v in enumerate(value)
            for p in _value_problems(ParamType.GEOPOINTS, v, f"{field}[{i}]", limits)
        ]
    if spec_type is ParamType.FLOAT64:
        return [] if _is_number(value) else [(field, f"must be a number, not {short_repr(value)}")]
    if spec_type is ParamType.INT32:
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        if not isinstance(value, int) or isinstance(value, bool):
            return [(field, f"must be an integer, not {short_repr(value)}")]
        if not INT32_MIN <= value <= INT32_MAX:
            return [(field, f"{short_repr(value)} is outside the int32 range")]
        return []
    if spec_type is ParamType.BOOL:
        return (
            []
            if isinstance(value, bool)
            else [(field, f"must be true or false, not {short_repr(value)}")]
        )
    if spec_type is ParamType.STRING:
        if not isinstance(value, str):
            return [(field, f"must be a string, not {short_repr(value)}")]
        if len(value) > limits.max_text:
            return [(field, f"is {len(value)} characters long; at most {limits.max_text}")]
        return []
    if spec_type is ParamType.STRINGS:
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            return [(field, "must be a list of strings")]
        if any(len(v) > limits.max_text for v in value):
            return [(field, f"holds a string longer than {limits.max_text} characters")]
        return []
    if spec_type is ParamType.FLOAT64S:
        if not isinstance(value, list) or not all(_is_number(v) for v in value):
            return [(field, "must be a list of numbers")]
        return []
    raise AssertionError(spec_type)  # pragma: no cover


def _speed_problems(value: Any, field: str, limits: Limits) -> list[tuple[str, str]]:
    if isinstance(value, list) and len(value) == 1:
        value = value[0]
    if isinstance(value, str):
        if value in SPEED_CLASSES:
            return []
        return [(field, f"{short_repr(value)} is not one of {', '.join(SPEED_CLASSES)}")]
    if _is_number(value) and 0 < value <= limits.max_speed:
        return []  # lenient: an explicit m/s, as in the seed's observe-position example
    if _is_number(value) and value > limits.max_speed:
        return [(field, f"{value:g} m/s is above the maximum of {limits.max_speed:g} m/s")]
    classes = ", ".join(SPEED_CLASSES)
    return [(field, f"must be one of {classes} (or m/s > 0), not {short_repr(value)}")]


def _polygon_problems(points: list[Any], field: str) -> list[tuple[str, str]]:
    """A search polygon must be simple and have a width worth searching, judged in metres: in
    degrees, three collinear points give an area of 1e-18 (float rounding) rather than 0, and a
    sliver of a few cm² passed an exact-zero test."""
    if len(points) < 3:
        return [(field, f"a search polygon needs at least 3 points, got {len(points)}")]
    points = [p[0] if isinstance(p, list) else p for p in points]  # the one-element-list form
    coords = [(float(p["longitude"]), float(p["latitude"])) for p in points]
    ring = LinearRing(coords)
    if not ring.is_simple:
        return [(field, "the polygon crosses itself")]
    lats, lons = [c[1] for c in coords], [c[0] for c in coords]
    frame = LocalFrame((min(lats) + max(lats)) / 2.0, (min(lons) + max(lons)) / 2.0)
    east, north = frame.to_xy(lats, lons)
    metric = Polygon(list(zip(east.tolist(), north.tolist(), strict=True)))
    width = metric.area / (metric.length / 2.0) if metric.length > 0 else 0.0
    if width < MIN_AREA_WIDTH_M:
        return [(field, f"the polygon has no area: {metric.area:.3g} m² over "
                        f"{metric.length / 2.0:.3g} m, under {MIN_AREA_WIDTH_M:g} m wide "
                        "(its points are on a line)")]
    return []


def _range_problems(name: str, value: Any, field: str, limits: Limits) -> list[tuple[str, str]]:
    """Physical ranges of the numeric params (sizes, heights, durations, commanded speeds)."""
    if name in _SIZES:
        zero_ok = _SIZES[name]
        if value < 0 or (value == 0 and not zero_ok):
            return [(field, f"must be greater than 0, not {value}")]
        if value > limits.max_size:
            return [(field, f"{value:g} m is above the maximum of {limits.max_size:g} m")]
    elif name in _HEIGHTS and not limits.altitude[0] <= value <= limits.altitude[1]:
        lo, hi = limits.altitude
        return [(field, f"{value} m is outside [{lo:g}, {hi:g}]")]
    elif name == "duration" and value > limits.max_duration:
        return [(field, f"{value} s is above the maximum of {limits.max_duration} s")]
    elif name == "commanded-speed" and any(not 0 < v <= limits.max_speed for v in value):
        return [(field, f"every speed must lie in (0, {limits.max_speed:g}] m/s")]
    return []


def param_problems(
    spec: TaskSpec, params: dict[str, Any], limits: Limits = DEFAULT_LIMITS
) -> list[tuple[str, str]]:
    """(field, message) pairs for a task node's params; unknown params are allowed and kept.

    A known param given as ``null`` is refused (leave it out for its default): ``"speed": null``
    is no speed.
    """
    out: list[tuple[str, str]] = []
    for name, value in params.items():
        if value is None and name in spec.params and name not in spec.required:
            out.append((f"params.{name}", "must not be null (leave it out for the default)"))
    for name in spec.required:
        if name not in params or params[name] is None:
            out.append((f"params.{name}", f"missing: {spec.name} cannot run without it"))
    for group in spec.one_of:
        if not any(params.get(g) is not None for g in group):
            out.append(
                (f"params.{group[0]}", f"missing: {spec.name} needs one of {', '.join(group)}")
            )
    for name, value in params.items():
        pspec = spec.params.get(name)
        if pspec is None or value is None:
            continue
        field = f"params.{name}"
        if name == "speed" and pspec.type is ParamType.STRING:
            out.extend(_speed_problems(value, field, limits))
            continue
        found = _value_problems(pspec.type, value, field, limits)
        out.extend(found)
        if found:
            continue
        ranged = _range_problems(name, value, field, limits)
        out.extend(ranged)
        if ranged:
            continue
        if spec.name == "search-area" and name == "area":
            out.extend(_polygon_problems(value, field))
        elif spec.name == "search-areas" and name == "areas":
            if not value:
                out.append((field, "needs at least one area"))
            for i, area in enumerate(value):
                out.extend(_polygon_problems(area, f"{field}[{i}]"))
    return out


def _string_problems(label: str, node: TstNode, limits: Limits) -> list[InputProblem]:
    """Names, node-uuids and execunits are identifiers: bounded, so that a 1 MB name is refused
    before it is kept anywhere."""
    out: list[InputProblem] = []
    for field, value in (
        ("name", node.name),
        (f"{node.common_key}.node-uuid", node.common_params.get("node-uuid")),
        (f"{node.common_key}.execunit", node.execunit),
    ):
        if isinstance(value, str) and len(value) > limits.max_string:
            out.append(
                InputProblem(
                    label, field, f"is {len(value)} characters long; at most {limits.max_string}"
                )
            )
    return out


def tree_problems(root: TstNode, limits: Limits = DEFAULT_LIMITS) -> list[InputProblem]:
    """Every catalogue problem in a parsed tree: unknown tasks, params, execunit types, string
    lengths and physical ranges."""
    problems: list[InputProblem] = []
    for path, node in walk(root):
        label = where(path, node)
        strings = _string_problems(label, node, limits)
        if strings:
            problems.extend(strings)
            continue
        try:
            classify_execunit(node.execunit)
        except TypeError as exc:
            problems.append(InputProblem(label, f"{node.common_key}.execunit", str(exc)))
        if node.is_control:
            continue
        spec = CATALOGUE.get(node.name)
        if spec is None:
            problems.append(
                InputProblem(label, "name", f"unknown task {node.name!r}: not in the catalogue")
            )
            continue
        problems.extend(InputProblem(
            label, f, m) for f, m in param_problems(spec, node.params, limits))
    return problems


def parse_and_validate(data: Any, limits: Limits = DEFAULT_LIMITS) -> TstNode:
    """Parse a tree and check it against the catalogue; raise ``InputError`` with every problem."""
    return validate_tree(parse_tree(data), limits).root


#: Held by every `ValidatedTree` the validator made (a tree made otherwise is refused).
_VALIDATOR = object()


@dataclass(frozen=True, slots=True)
class ValidatedTree:
    """A tree the validator checked against the catalogue and ``limits`` (`validate_tree`):
    whoever receives one (the planner) need not check it again. Made here only."""

    root: TstNode
    limits: Limits = DEFAULT_LIMITS
    made_by: object = dataclasses.field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.made_by is not _VALIDATOR:
            raise TypeError("a ValidatedTree is made by validate_tree only")

    @property
    def node_uuid(self) -> str | None:
        return self.root.node_uuid

    @property
    def name(self) -> str:
        return self.root.name

    def with_uuids(self, new_uuid: Callable[[], str] | None = None) -> ValidatedTree:
        """The same tree with a ``node-uuid`` on every node (fresh uuids keep it valid)."""
        return ValidatedTree(with_uuids(self.root, new_uuid), self.limits, _VALIDATOR)


def validate_tree(tree: Any, limits: Limits = DEFAULT_LIMITS) -> ValidatedTree:
    """A tree (a `TstNode` or its JSON) checked once; ``InputError`` with every problem."""
    root = tree if isinstance(tree, TstNode) else parse_tree(tree)
    problems = tree_problems(root, limits)
    if problems:
        raise InputError(problems)
    return ValidatedTree(root, limits, _VALIDATOR)


def with_defaults(root: TstNode) -> TstNode:
    """The same tree with catalogue defaults filled in where the caller left params out.

    The public example agent silently ignores a ``move-to`` without ``speed``, so the
    instantiated tree always carries it.
    """

    def fill(node: TstNode, children: tuple[TstNode, ...]) -> TstNode:
        if not same_nodes(children, node.children):  # (else the node itself: nothing to copy)
            node = node.with_children(children)
        spec = CATALOGUE.get(node.name)
        if spec is None or not spec.defaults:
            return node
        missing = {k: v for k, v in spec.defaults.items() if k not in node.params}
        if not missing:
            return node
        return node.with_params({**node.params, **missing})

    return map_tree(root, fill)
