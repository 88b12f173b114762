"""Plausibility of a mission's places: warnings for the plan's notes, never a refusal.

A tree can be valid and still wrong: latitude and longitude swapped gives a perfectly valid point
thousands of kilometres away (once a 5,492 km ``move-to``). Such a task is planned as asked, but
the plan's notes (and the service log) say so, naming the node and the nearest unit.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import Any

from delegation.fleet import UnitState
from delegation.geo import GeoPoint, great_circle_matrix_m
from delegation.tst.node import TstNode, walk, where

#: A task farther than this from every unit is called implausible.
DEFAULT_MAX_DISTANCE_M = 1_000_000.0

#: Task params that hold positions, and whether they hold one point, a list, or lists of lists.
_POINT_PARAMS: dict[str, int] = {
    "geopoint": 0, "waypoint": 0, "p": 0, "waypoints": 1, "geopoints": 1, "area": 1, "path": 1,
    "areas": 2,
}  # fmt: skip


def _points(value: Any, depth: int) -> Iterator[GeoPoint]:
    """The GeoPoints in a (validated) param value; anything unreadable is skipped."""
    if depth == 0:
        if isinstance(value, list) and len(value) == 1:
            value = value[0]
        if isinstance(value, dict):
            try:
                yield GeoPoint.model_validate(value)
            except ValueError:
                return
        return
    if isinstance(value, list):
        for item in value:
            yield from _points(item, depth - 1)


def _first_point(node: TstNode) -> tuple[str, GeoPoint] | None:
    for name, depth in _POINT_PARAMS.items():
        for point in _points(node.params.get(name), depth):
            return name, point
    return None


def plausibility_notes(
    tree: TstNode,
    units: Sequence[UnitState],
    max_distance_m: float = DEFAULT_MAX_DISTANCE_M,
) -> list[str]:
    """One note per task whose place is farther than ``max_distance_m`` from every unit (by its
    first point), saying when swapping latitude and longitude would bring it near one."""
    if not units:
        return []
    positions = [u.position for u in units]
    found = [(path, node, *first) for path, node in walk(tree)
             if not node.is_control and (first := _first_point(node)) is not None]
    if not found:
        return []
    # One distance matrix for every task's point (a call per task cost most of the check).
    distances = great_circle_matrix_m([point for *_, point in found], positions)
    notes: list[str] = []
    for (path, node, param, point), row in zip(found, distances, strict=True):
        far = float(row.min())
        if far <= max_distance_m:
            continue
        nearest = units[int(row.argmin())]
        note = (
            f"{where(path, node)}: params.{param} is {far / 1000:,.0f} km from the nearest unit "
            f"({nearest.name})"
        )
        if abs(point.longitude) <= 90.0:
            swapped = GeoPoint(latitude=point.longitude, longitude=point.latitude)
            if float(great_circle_matrix_m([swapped], positions).min()) <= max_distance_m:
                note += "; latitude and longitude look swapped"
        notes.append(note)
    return notes
