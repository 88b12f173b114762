"""Fly a plan on simulated vehicles, in process, and compare it with the plan (issue 21).

Pure (no network, no clock, no threads): each unit's route is flown on its own `SimVehicle`,
stepped ``dt`` simulated seconds at a time, each task started when the unit's previous one ended
(waits for other units' tasks are not simulated: the comparison is per task, and for a tree of
one shared search per unit too). A task's flown time runs from its start to its end in the
simulator; its planned time is the plan's travel + work. The track of a task's work (from the
first point of its path on) is kept exactly: every point the vehicle passed, in the plan's frame.

``footprint`` is what a unit's camera sees along a track: ``w/2`` either side, square at the
ends and at the corners (the footprint is about ``w`` long, ``costs.footprint_width``), so the
cover and the overlap of parts can be measured on what was flown (``swept``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import shapely

from delegation.allocation.plan import Plan
from delegation.coverage import footprint as footprint  # (re-exported: what was seen)
from delegation.fleet import UnitState
from delegation.geo import LocalFrame
from delegation.sim.vehicle import SimVehicle
from delegation.tst import TstNode
from delegation.tst.node import leaves

#: A task still on after this many times its planned time (plus a minute) is given up.
GIVE_UP = 3.0


@dataclass(frozen=True)
class FlownTask:
    """One task as flown: planned and flown seconds, the state it ended in, its work's track."""

    node_uuid: str
    name: str
    unit: str
    planned_s: float
    flown_s: float
    planned_travel_s: float
    flown_travel_s: float
    state: str
    #: (K, 2) east/north m in the plan's frame: the work's track (empty for tasks without one).
    track_xy: np.ndarray

    @property
    def ratio(self) -> float:
        """Flown over planned time (1.0 for a task planned to take no time and taking none)."""
        if self.planned_s > 0.0:
            return self.flown_s / self.planned_s
        return 1.0 if self.flown_s == 0.0 else math.inf


def fly_task(vehicle: SimVehicle, node: TstNode, frame: LocalFrame, planned: tuple[float, float],
             dt: float = 1.0) -> FlownTask:
    """Start ``node`` on ``vehicle`` and step it until the task ends (or ``GIVE_UP``).

    ``planned``: (travel, work) s of the plan. The flown time is counted in whole steps, except
    the last, which counts only the part the task used (the vehicle's own clock)."""
    uuid = node.node_uuid or f"flown-{node.name}"
    unit = vehicle.unit.name
    refused = vehicle.start_task(node.name, dict(node.params), uuid)
    if refused is not None:
        return FlownTask(uuid, node.name, unit, sum(planned), math.nan, planned[0], math.nan,
                         f"refused: {refused}", np.zeros((0, 2)))
    task = vehicle.tasks[uuid]
    first = len(task.legs)
    travel = (math.hypot(task.legs[0][0] - vehicle.east, task.legs[0][1] - vehicle.north)
              / task.speed if task.legs and task.speed > 0.0 else 0.0)
    points: list[tuple[float, float]] = []
    started = vehicle.sim_time
    limit = GIVE_UP * sum(planned) + 60.0
    state = "unfinished"
    while vehicle.sim_time - started <= limit:
        before = list(task.legs)
        events = vehicle.step(dt)
        gone = uuid not in vehicle.tasks
        points += [(e, n) for e, n, _ in before[: len(before) - (0 if gone else len(task.legs))]]
        if not gone and len(task.legs) < first:
            points.append((vehicle.east, vehicle.north))
        ended = [e for e in events if e.task_uuid == uuid]
        if ended or gone:
            state = ended[-1].status if ended else task.state.value
            break
    # The vehicle's own account (distance / speed + hold): the steps' sum without the last
    # step's rounding up.
    flown = (task.travelled / task.speed if task.speed > 0.0 else 0.0) + task.elapsed
    if state == "unfinished":
        flown = vehicle.sim_time - started
    return FlownTask(uuid, node.name, unit, sum(planned), flown, planned[0], travel, state,
                     _in_frame(points, vehicle, frame))


def _in_frame(points: list[tuple[float, float]], vehicle: SimVehicle, frame: LocalFrame
              ) -> np.ndarray:
    """Vehicle-frame (east, north) points in ``frame``."""
    if not points:
        return np.zeros((0, 2))
    xy = np.asarray(points, dtype=float)
    lat, lon = vehicle.frame.to_geo(xy[:, 0], xy[:, 1])
    east, north = frame.to_xy(lat, lon)
    return np.column_stack([np.atleast_1d(east), np.atleast_1d(north)])


def fly_plan(plan: Plan, units: Sequence[UnitState], frame: LocalFrame, dt: float = 1.0
             ) -> list[FlownTask]:
    """Every assignment of ``plan`` flown by its unit, each unit's route in order from where the
    unit is (the plan's sent tree, ``plan.planned``, holds shared searches' parts)."""
    nodes = {n.node_uuid: n for n in leaves(plan.planned or plan.tst)}
    by_name = {u.name: u for u in units}
    out = []
    for name, route in sorted(plan.routes.items()):
        unit = by_name[name.strip("/")]
        vehicle = SimVehicle(unit)
        for a in route:
            node = nodes[a.node_uuid]
            out.append(fly_task(vehicle, node, frame, (a.travel_time, a.work_time), dt))
    return out


# --------------------------------------------------------------------------- what was seen




def swept(area: shapely.Geometry, prints: Sequence[shapely.Geometry]) -> tuple[float, float]:
    """(share of ``area`` some footprint covers, share of it two or more cover (counted once per
    extra footprint))."""
    inside = [shapely.intersection(p, area) for p in prints]
    union = shapely.union_all(inside)
    total = float(area.area)
    return float(union.area) / total, (sum(float(p.area) for p in inside)
                                       - float(union.area)) / total


def outside(track_xy: np.ndarray, region: shapely.Geometry, tolerance: float) -> float:
    """Metres of the track farther than ``tolerance`` from ``region``."""
    if len(track_xy) < 2:
        return 0.0
    line = shapely.LineString(track_xy)
    return float(shapely.difference(line, region.buffer(tolerance)).length)
