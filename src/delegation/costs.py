"""The cost model of docs/plan.md §2: what each unit would need to do each task, as numpy tables.

Every strategy plans on the same ``CostTables`` so that their plans mean the same thing:

* **distance**: straight lines in a mission-local ENU frame (the geodesic within 0.1 % inside
  50 km), altitude ignored;
* **speed**: the unit's m/s for the task's ``speed`` class (default ``standard``); an explicit
  m/s (the seed's ``"speed": [7.0]``) is used as given, capped at the unit's ``fast``;
* **where a task starts and ends, and its work**:

  =========================  ================================  ===================================
  task                       start -> end                      work
  =========================  ================================  ===================================
  move-to                    waypoint                          none
  move-path, navigate        first -> last waypoint            polyline length / speed
                                                               (navigate with ``loop-flag`` or
                                                               ``hold-flag``: open-ended)
  search-area                the sweep's two ends              boustrophedon path length / speed
  search-areas               first sweep's start -> last end   all sweeps + connectors / speed
  search-around-position     the sweep's ends (circle)         boustrophedon path length / speed
  observe-position           geopoint                          ``duration`` s (open-ended if < 0
                                                               or missing)
  go-home                    the unit's ``home``               none (travel only)
  land                       ``p`` if given, else in place     ``LAND_TIME_S``
  take-off                   in place                          ``TAKE_OFF_TIME_S``
  look-at-*, image-object-   in place (no travel)              open-ended
  detection, others
  =========================  ================================  ===================================

* **sweep width**: the camera footprint ``w = 2 h tan(FOV/2) (1 - overlap)`` at the unit's sweep
  altitude, but never wider than the swath in which a target of ``target-size`` still spans
  ``MIN_TARGET_PIXELS`` of an ``IMAGE_PIXELS``-wide image (see ``sweep_width``);
* **capability**: the unit lists the task in ``tasks-available``, is alive, and its remaining
  endurance (``battery * endurance``) covers travel + work (+ the way home, where it has one) of the
  task on its own. Open-ended tasks count travel only.

Travel and work use the same speed. The tables are built with numpy over units x tasks; only the
per-task geometry (and one coverage path per distinct sweep width) is computed in Python.
"""

from __future__ import annotations

import itertools
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from delegation.coverage import (
    circle_polygon,
    coverage_length,
    coverage_path,
    flown_ways,
    path_length,
    pick_way,
    way_ends,
)
from delegation.errors import InputError
from delegation.fleet import SPEED_KEYS, UnitState
from delegation.geo import GeoPoint, LocalFrame, pairwise_xy_distances
from delegation.tst.node import TstNode
from delegation.tst.validate import read_geopoint

__all__ = [
    "IMAGE_PIXELS",
    "LAND_TIME_S",
    "MIN_TARGET_PIXELS",
    "SWEEP_OVERLAP",
    "TAKE_OFF_TIME_S",
    "CostTables",
    "TaskGeometry",
    "cost_tables",
    "coverage_length",
    "coverage_path",
    "search_polygons_xy",
    "sweep_width",
    "task_geometry",
    "task_path",
    "unit_speed",
]

log = logging.getLogger(__name__)

#: Overlap between neighbouring sweep lanes.
SWEEP_OVERLAP = 0.2
#: Width of the camera image in pixels, and how many pixels a target must span to be detected.
IMAGE_PIXELS = 1280
MIN_TARGET_PIXELS = 16
#: Fixed times for vertical manoeuvres (horizontal travel is not involved).
TAKE_OFF_TIME_S = 20.0
LAND_TIME_S = 30.0
#: ``target-size`` when a search task leaves it out (the catalogue default).
DEFAULT_TARGET_SIZE = 2.0

_SPEED_INDEX = {k: i for i, k in enumerate(SPEED_KEYS)}

# --------------------------------------------------------------------------- speeds, widths


def _speed_choice(value: object, where: str) -> tuple[int, float]:
    """(speed class index or -1, explicit m/s or NaN) of a ``speed`` parameter, or an
    ``InputError`` starting with ``where``.

    ``None`` means ``standard``; the seed's one-element list ``[7.0]`` is its element.
    """
    if isinstance(value, list) and len(value) == 1:
        value = value[0]
    if value is None:
        return _SPEED_INDEX["standard"], math.nan
    if isinstance(value, str):
        if value not in _SPEED_INDEX:
            raise InputError(f"{where}: {value!r} is not one of {', '.join(SPEED_KEYS)}")
        return _SPEED_INDEX[value], math.nan
    if isinstance(value, int | float) and not isinstance(value, bool):
        v = float(value)
        if math.isfinite(v) and v > 0.0:
            return -1, v
    raise InputError(f"{where}: must be a speed class or m/s > 0, not {value!r}")


def unit_speed(unit: UnitState, speed_param: object) -> float:
    """The unit's m/s for a task's ``speed`` parameter.

    ``None`` means ``standard``; a class name uses the unit's value; an explicit positive number
    (or the seed's one-element list ``[7.0]``) is taken as m/s, capped at the unit's ``fast``.
    """
    cls, explicit = _speed_choice(speed_param, "speed")
    if cls >= 0:
        return float(unit.speeds[SPEED_KEYS[cls]])
    return min(explicit, float(unit.speeds["fast"]))


def footprint_width(unit: UnitState) -> float:
    """The camera footprint across track (m): ``2 h tan(FOV/2) (1 - overlap)``."""
    h = unit.effective_sweep_altitude
    fov = math.radians(unit.camera_fov_deg)
    return 2.0 * h * math.tan(fov / 2.0) * (1.0 - SWEEP_OVERLAP)


def detection_width(target_size: float) -> float:
    """The widest swath (m) in which a target of ``target_size`` m spans enough pixels."""
    return float(target_size) * IMAGE_PIXELS / MIN_TARGET_PIXELS


def sweep_width(unit: UnitState, target_size: float) -> float:
    """Lane spacing (m) for a search by ``unit`` for targets of ``target_size`` m.

    The narrower of the unit's footprint and the detection swath: a drone at 40 m with a 60 degree
    camera sweeps 37 m lanes; looking for 0.3 m targets narrows them to 24 m.
    """
    if not math.isfinite(target_size) or target_size <= 0.0:
        raise InputError(f"target-size must be a positive number of metres, not {target_size!r}")
    width = min(footprint_width(unit), detection_width(target_size))
    if not width > 0.0:
        raise InputError(f"unit {unit.name} has no usable sensor footprint (width {width})")
    return width


# --------------------------------------------------------------------------- task geometry


@dataclass(frozen=True, slots=True)
class TaskGeometry:
    """Where a task happens, in GeoPoints (frame-free), as the cost model reads it.

    ``kind`` is one of ``point`` (start = end = ``points[0]``), ``path`` (a polyline through
    ``points``), ``areas`` (polygons to sweep), ``home`` (the unit's home) or ``inplace``.
    """

    kind: str
    points: tuple[GeoPoint, ...] = ()
    areas: tuple[tuple[GeoPoint, ...], ...] = ()
    circle: tuple[GeoPoint, float] | None = None
    target_size: float = DEFAULT_TARGET_SIZE
    fixed_time: float = 0.0
    open_ended: bool = False


def _target_size(params: dict[str, Any]) -> float:
    value = params.get("target-size")
    if isinstance(value, int | float) and not isinstance(value, bool) and value > 0:
        return float(value)
    return DEFAULT_TARGET_SIZE


def task_geometry(node: TstNode) -> TaskGeometry:
    """Read a (validated) task node's geometry per the table in the module docstring."""
    p = node.params
    name = node.name
    if name == "move-to":
        return TaskGeometry("point", (read_geopoint(p["waypoint"]),))
    if name in ("move-path", "navigate"):
        pts = tuple(read_geopoint(v) for v in p["waypoints"])
        # navigate with loop-flag or hold-flag loops the waypoints or holds after the last one
        # until $enough (seed 9.14): open-ended, like an observe-position without a duration.
        until_enough = name == "navigate" and (p.get("loop-flag") is True
                                               or p.get("hold-flag") is True)
        if not pts:
            return TaskGeometry("inplace", open_ended=until_enough)
        return TaskGeometry("path", pts, open_ended=until_enough)
    if name == "search-area":
        area = tuple(read_geopoint(v) for v in p["area"])
        return TaskGeometry("areas", areas=(area,), target_size=_target_size(p))
    if name == "search-areas":
        areas = tuple(tuple(read_geopoint(v) for v in area) for area in p["areas"])
        return TaskGeometry("areas", areas=areas, target_size=_target_size(p))
    if name == "search-around-position":
        centre = read_geopoint(p["geopoint"])
        radius = p.get("radius", 50.0)
        return TaskGeometry(
            "areas", points=(centre,), circle=(centre, float(radius)), target_size=_target_size(p)
        )
    if name == "observe-position":
        duration = p.get("duration")
        if isinstance(duration, int | float) and not isinstance(duration, bool) and duration >= 0:
            return TaskGeometry(
                "point", (read_geopoint(p["geopoint"]),), fixed_time=float(duration)
            )
        return TaskGeometry("point", (read_geopoint(p["geopoint"]),), open_ended=True)
    if name == "go-home":
        return TaskGeometry("home")
    if name == "land":
        if p.get("p") is not None and not p.get("land-at-current-position-flag", False):
            return TaskGeometry("point", (read_geopoint(p["p"]),), fixed_time=LAND_TIME_S)
        return TaskGeometry("inplace", fixed_time=LAND_TIME_S)
    if name == "take-off":
        return TaskGeometry("inplace", fixed_time=TAKE_OFF_TIME_S)
    # look-at-*, image-object-detection and anything else: done where the unit is, until $enough.
    return TaskGeometry("inplace", open_ended=True)


def _geo_points(g: TaskGeometry) -> list[GeoPoint]:
    pts = list(g.points)
    for area in g.areas:
        pts.extend(area)
    return pts


def _polygons_xy(g: TaskGeometry, frame: LocalFrame) -> list[np.ndarray]:
    return _polygons_from(g, frame.points_xy(_geo_points(g)))


def _polygons_from(g: TaskGeometry, xy: np.ndarray) -> list[np.ndarray]:
    """The polygons of an ``areas`` task from its ``_geo_points`` in the frame (``xy``)."""
    if g.circle is not None:
        return [circle_polygon(xy[0], g.circle[1])]
    bounds = np.cumsum([0] + [len(area) for area in g.areas]).tolist()
    return [xy[a:b] for a, b in itertools.pairwise(bounds)]


def search_polygons_xy(node: TstNode, frame: LocalFrame) -> list[np.ndarray]:
    """The polygons (east/north m in ``frame``) a search task sweeps: its ``area``, each of its
    ``areas``, or the polygon standing in for its circle; empty for other tasks."""
    g = task_geometry(node)
    if g.kind != "areas":
        return []
    return _polygons_xy(g, frame)


def task_path(node: TstNode, unit: UnitState, frame: LocalFrame | None = None,
              here: GeoPoint | None = None) -> list[GeoPoint]:
    """The points the unit moves through to do the task's work (for simulators and maps).

    ``move-to``/``observe-position``: the point; ``move-path``: the waypoints; searches: the
    boustrophedon sweep with the unit's own sweep width, at the altitude of the area's first point
    (the centre for ``search-around-position``), flown the way that costs least from ``here``
    (where the unit is when the task starts; default its ``position``), as the planner's schedule
    chooses it (``coverage.pick_way``); ``go-home``: the home (if known); in-place tasks: an empty
    list.
    """
    g = task_geometry(node)
    if g.kind in ("point", "path"):
        return list(g.points)
    if g.kind == "home":
        return [unit.home] if unit.home is not None else []
    if g.kind != "areas":
        return []
    pts = _geo_points(g)
    frame = frame or LocalFrame.around(pts)
    ways = flown_ways(_polygons_xy(g, frame), sweep_width(unit, g.target_size))
    if not ways:
        return []
    at = frame.point_xy(here if here is not None else unit.position)
    path = ways[pick_way(way_ends(ways), (float(at[0]), float(at[1])))]
    altitude = pts[0].altitude
    lat, lon = frame.to_geo(path[:, 0], path[:, 1])
    return [
        GeoPoint(latitude=float(a), longitude=float(b), altitude=altitude)
        for a, b in zip(np.atleast_1d(lat), np.atleast_1d(lon), strict=True)
    ]


# --------------------------------------------------------------------------- the tables


@dataclass(frozen=True, eq=False)
class CostTables:
    """Everything a strategy needs about units x tasks, as arrays (indices follow ``units`` and
    ``tasks``).

    ``start_xy``/``end_xy`` rows are NaN where the point depends on the unit (``go-home``: its home)
    or where the task is done in place (``travels`` False: the unit stays where it is); use
    ``start_for``/``end_for`` for one unit, or the ``dist_*`` methods, which handle both.
    For search tasks ``start_xy``/``end_xy`` are the ends of the sweep at the narrowest sweep width
    among the units that offer the task (the end lane depends on how many lanes a unit needs, and
    both ends on the lanes' direction, which ``coverage.sweep_direction`` chooses per width), flown
    as the first such unit flies it from where it is: the reference points; each unit's own are
    ``unit_start_xy``/``unit_end_xy`` (the way it flies the sweep from its position), which
    ``start_for``/``end_for``, ``dist_unit_to_start``, ``dist_end_to_home`` and the planner use;
    from elsewhere (after another task) a unit may fly another way (``sweep_ways``, ``way_for``).
    Open-ended tasks have ``work_time`` 0.
    """

    units: tuple[UnitState, ...]
    tasks: tuple[TstNode, ...]
    frame: LocalFrame
    unit_xy: np.ndarray
    home_xy: np.ndarray
    start_xy: np.ndarray
    end_xy: np.ndarray
    speed: np.ndarray
    work_time: np.ndarray
    work_distance: np.ndarray
    travels: np.ndarray
    open_ended: np.ndarray
    capable: np.ndarray
    endurance: np.ndarray
    #: (U, T) the unit lists the task in tasks-available.
    listed: np.ndarray
    #: (U, T) seconds the task alone needs: travel from the unit + work (+ the way home).
    need_time: np.ndarray
    #: (T,) True for go-home (start and end are the unit's home).
    to_home: np.ndarray
    #: (U, T) sweep width (m) for search tasks, NaN elsewhere.
    width: np.ndarray
    #: Whether busy units were excluded (``cost_tables(exclude_busy=True)``).
    exclude_busy: bool = False
    #: (T,) per search task its polygons in ``frame`` (east/north m), () for other tasks: the
    #: sharing of searches reads them again and again (DESIGN 3.11).
    polygons: tuple[tuple[np.ndarray, ...], ...] = ()
    #: (U, T, 2) where each unit starts and ends each task: for searches the ends of its own
    #: sweep (its width: the lanes, their direction and the last lane depend on it), elsewhere
    #: ``start_xy``/``end_xy``. None: those for every unit.
    unit_start_xy: np.ndarray | None = None
    unit_end_xy: np.ndarray | None = None
    #: Search task index -> (U, K, 6) the K ways each unit may fly its sweep (``coverage.
    #: flown_ways`` at its width), rows of (start east, north, end east, north, length m, work
    #: s), NaN rows for a unit that cannot sweep it (or a width with fewer ways). Which one a
    #: unit flies depends on where it is when it starts (``coverage.pick_way``): the schedule
    #: chooses from where the unit's previous task left it (``way_for``); ``unit_start_xy``,
    #: ``unit_end_xy`` and ``work_distance`` hold the way from the unit's position.
    sweep_ways: dict[int, np.ndarray] = field(default_factory=dict)
    #: Task index -> the one unit index it was costed for (``cost_tables(only=...)``): the
    #: other units have no sweep of it (work inf) and cannot take it.
    only: Mapping[int, int] = field(default_factory=dict)

    @property
    def n_units(self) -> int:
        return len(self.units)

    @property
    def n_tasks(self) -> int:
        return len(self.tasks)

    def unit_index(self, name: str) -> int | None:
        """Index of the unit called ``name`` (with or without ``/``), or None."""
        key = name.strip("/")
        for i, u in enumerate(self.units):
            if u.name == key:
                return i
        return None

    def reason(self, u: int, t: int) -> str | None:
        """Why unit ``u`` cannot take task ``t`` (None when it can)."""
        if self.capable[u, t]:
            return None
        unit, task = self.units[u], self.tasks[t]
        if not unit.alive:
            return f"{unit.name} is not alive (no recent heartbeat)"
        if not self.listed[u, t]:
            return f"{unit.name} does not offer {task.name}"
        if self.only.get(t, u) != u:
            return (f"{unit.name} was not costed for {task.name}: it is "
                    f"{self.units[self.only[t]].name}'s alone")
        if self.exclude_busy and unit.busy:
            return f"{unit.name} is busy with another task"
        need, have = float(self.need_time[u, t]), float(self.endurance[u])
        if not math.isfinite(need):
            return f"{unit.name} has no usable sensor footprint for {task.name}"
        if not need <= have:
            return (
                f"{unit.name} has {have:.0f} s of endurance left but {task.name} needs "
                f"{need:.0f} s" + (" including the way home" if unit.home is not None else "")
            )
        return f"{unit.name} cannot take {task.name}"  # pragma: no cover - all causes above

    def start_for(self, u: int, t: int) -> np.ndarray | None:
        """Where unit ``u`` starts task ``t`` (None: where it already is)."""
        return self._point_for(u, t, self.start_xy)

    def end_for(self, u: int, t: int) -> np.ndarray | None:
        """Where unit ``u`` is after task ``t`` (None: where it was before)."""
        return self._point_for(u, t, self.end_xy)

    def way_for(self, u: int, t: int, here: np.ndarray | None
                ) -> tuple[np.ndarray | None, np.ndarray | None, float, float]:
        """(start, end, work s, work m) of task ``t`` for unit ``u`` coming from ``here`` (east,
        north m; None: from its position): a search flown the way that costs least from there
        (``sweep_ways``, ``coverage.pick_way``), as the schedule flies it; other tasks as
        ``start_for``/``end_for`` and the work tables say."""
        ways = self.sweep_ways.get(t)
        rows = None if ways is None else ways[u][np.isfinite(ways[u, :, 4])]
        if rows is None or not len(rows) or not self.travels[t]:
            return (self.start_for(u, t), self.end_for(u, t), float(self.work_time[u, t]),
                    float(self.work_distance[u, t]))
        at = self.unit_xy[u] if here is None else here
        row = rows[pick_way(rows.tolist(), (float(at[0]), float(at[1])))]
        return row[0:2].copy(), row[2:4].copy(), float(row[5]), float(row[4])

    def _point_for(self, u: int, t: int, table: np.ndarray) -> np.ndarray | None:
        """Row ``t`` of ``table`` (the unit's own where it has one), the unit's home for
        ``go-home``, None for in-place tasks."""
        if not self.travels[t]:
            return None
        if self.to_home[t]:
            home = self.home_xy[u]
            return None if np.isnan(home).any() else home
        per_unit = self.unit_start_xy if table is self.start_xy else self.unit_end_xy
        if per_unit is not None:
            return np.asarray(per_unit[u, t])
        return np.asarray(table[t])

    def dist_unit_to_start(self) -> np.ndarray:
        """(U, T) metres from each unit's position to each task's start.

        0 for in-place tasks; for ``go-home`` the distance to the unit's home (0 when unknown).
        Searches start where the unit's own sweep starts.
        """
        if self.unit_start_xy is not None:
            gap = self.unit_start_xy - self.unit_xy[:, None, :]
            d = np.asarray(np.hypot(gap[..., 0], gap[..., 1]))
        else:
            d = pairwise_xy_distances(self.unit_xy, self.start_xy)
        d[:, ~self.travels] = 0.0
        if self.to_home.any():
            home_d = np.hypot(*(self.home_xy - self.unit_xy).T)
            home_d = np.where(np.isnan(home_d), 0.0, home_d)
            d[:, self.to_home] = home_d[:, None]
        return d

    def dist_end_to_start(self) -> np.ndarray:
        """(T, T) metres from the end of task i to the start of task j.

        The reference points (a search's sweep at the narrowest width): see ``unit_start_xy``
        for each unit's own. Column j is 0 when j is done in place; row i is NaN when i is done
        in place or is ``go-home`` (the unit's position then depends on the unit or on what it
        did before), and column j is NaN when j is ``go-home``.
        """
        d = pairwise_xy_distances(self.end_xy, self.start_xy)
        d[:, ~self.travels] = 0.0
        d[~self.travels | self.to_home, :] = np.nan
        d[:, self.to_home] = np.nan
        return d

    def dist_end_to_home(self) -> np.ndarray:
        """(T, U) metres from the end of task t to unit u's home; NaN where u has no home or the
        end is not a fixed point (in-place tasks); 0 for ``go-home``. A search ends where the
        unit's own sweep ends."""
        if self.unit_end_xy is not None:
            gap = self.unit_end_xy - self.home_xy[:, None, :]
            d = np.asarray(np.hypot(gap[..., 0], gap[..., 1]).T)
        else:
            d = pairwise_xy_distances(self.end_xy, self.home_xy)
        no_home = np.isnan(self.home_xy).any(axis=1)
        d[self.to_home, :] = 0.0
        d[:, no_home] = np.nan
        d[~self.travels, :] = np.nan
        return d


def cost_tables(
    units: Sequence[UnitState],
    tasks: Sequence[TstNode],
    frame: LocalFrame | None = None,
    *,
    exclude_busy: bool = False,
    only: Mapping[int, int] | None = None,
) -> CostTables:
    """Build the cost tables for ``units`` x ``tasks`` (task nodes, in the order given).

    ``frame`` defaults to one centred on every unit, home and task point. With ``exclude_busy``,
    units already executing a task cannot take new ones (the live service's choice); offline
    planning leaves it off. ``only``: task index -> the one unit index that task is costed for
    (a shared search's part, fixed to its unit, DESIGN 3.11): the task is swept at that unit's
    width alone, its reference points are that sweep's ends, and no other unit can take it
    (work inf). Sweeping each part at every width of the fleet was most of the cost of planning
    the parts (issue 21); the unit's own figures are the same either way.
    """
    units_t = tuple(units)
    tasks_t = tuple(tasks)
    geoms = [task_geometry(node) for node in tasks_t]
    if frame is None:
        frame = _frame_around(units_t, geoms)
    unit_xy, home_xy, task_xy = _points_xy(units_t, geoms, frame)
    speed = _speed_table(units_t, tasks_t)
    listed = _listed_table(units_t, tasks_t)
    width = _width_table(units_t, geoms)
    costed = _costed(len(units_t), len(tasks_t), only or {})
    start_xy, end_xy, work_distance, polygons, unit_ends, ways = _task_ends_and_work(
        geoms, task_xy, width if costed is None else np.where(costed, width, np.nan),
        listed if costed is None else listed & costed, unit_xy)
    open_ended = np.array([g.open_ended for g in geoms], dtype=bool).reshape(len(geoms))
    fixed_time = np.array([g.fixed_time for g in geoms], dtype=float).reshape(len(geoms))
    with np.errstate(divide="ignore", invalid="ignore"):
        work_time = np.where(work_distance > 0.0, work_distance / speed, 0.0) + fixed_time[None, :]
    work_time = np.where(open_ended[None, :], 0.0, work_time)
    for t, rows in ways.items():
        with np.errstate(divide="ignore", invalid="ignore"):
            rows[..., 5] = rows[..., 4] / speed[:, t, None] + fixed_time[t]
    kinds = [g.kind for g in geoms]
    tables = CostTables(
        units=units_t, tasks=tasks_t, frame=frame, unit_xy=unit_xy, home_xy=home_xy,
        start_xy=start_xy, end_xy=end_xy, speed=speed, work_time=work_time,
        work_distance=work_distance,
        travels=np.array([k != "inplace" for k in kinds], dtype=bool).reshape(len(kinds)),
        open_ended=open_ended,
        capable=np.zeros(speed.shape, dtype=bool),
        endurance=np.array(
            [math.inf if u.remaining_endurance is None else u.remaining_endurance
             for u in units_t], dtype=float,
        ).reshape(len(units_t)),
        listed=listed,
        need_time=np.zeros(speed.shape),
        to_home=np.array([k == "home" for k in kinds], dtype=bool).reshape(len(kinds)),
        width=width,
        exclude_busy=exclude_busy,
        polygons=polygons,
        unit_start_xy=unit_ends[0] if unit_ends is not None else None,
        unit_end_xy=unit_ends[1] if unit_ends is not None else None,
        only=dict(only or {}),
        sweep_ways=ways,
    )
    _fill_capability(tables, costed)
    return tables


def _costed(n_units: int, n_tasks: int, only: Mapping[int, int]) -> np.ndarray | None:
    """(U, T) the pairs ``cost_tables`` costs (``only``), None for all of them."""
    if not only:
        return None
    costed = np.ones((n_units, n_tasks), dtype=bool)
    for t, u in only.items():
        costed[:, t] = False
        costed[u, t] = True
    return costed


def _frame_around(units: Sequence[UnitState], geoms: Sequence[TaskGeometry]) -> LocalFrame:
    """The frame centred on every unit, home and task point."""
    pts: list[GeoPoint] = [u.position for u in units]
    pts += [u.home for u in units if u.home is not None]
    for g in geoms:
        pts += _geo_points(g)
    return LocalFrame.around(pts)


def _points_xy(
    units: Sequence[UnitState], geoms: Sequence[TaskGeometry], frame: LocalFrame
) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """(U, 2) unit positions, (U, 2) homes (NaN: none) and each task's points, in ``frame``:
    every point in one conversion (a call per task cost more than the arithmetic)."""
    n_u = len(units)
    homes = [(i, u.home) for i, u in enumerate(units) if u.home is not None]
    task_points = [_geo_points(g) for g in geoms]
    every = [u.position for u in units] + [h for _, h in homes]
    every += [p for pts_t in task_points for p in pts_t]
    every_xy = frame.points_xy(every).reshape(len(every), 2)
    unit_xy = every_xy[:n_u].copy()
    home_xy = np.full((n_u, 2), np.nan)
    if homes:
        home_xy[[i for i, _ in homes]] = every_xy[n_u : n_u + len(homes)]
    bounds = np.cumsum([n_u + len(homes)] + [len(pts_t) for pts_t in task_points])
    task_xy = [every_xy[a:b] for a, b in itertools.pairwise(bounds.tolist())]
    return unit_xy, home_xy, task_xy


def _speed_table(units: Sequence[UnitState], tasks: Sequence[TstNode]) -> np.ndarray:
    """(U, T) m/s: the unit's speed for the task's class, or the explicit m/s capped at fast."""
    n_u, n_t = len(units), len(tasks)
    unit_speeds = np.array(
        [[float(u.speeds[k]) for k in SPEED_KEYS] for u in units], dtype=float
    ).reshape(n_u, 3)
    specs = [_speed_choice(n.params.get("speed"), f"{n.name}: params.speed") for n in tasks]
    cls = np.array([s[0] for s in specs], dtype=int).reshape(n_t)
    explicit = np.array([s[1] for s in specs], dtype=float).reshape(n_t)
    speed = unit_speeds[:, np.clip(cls, 0, 2)]
    return np.asarray(
        np.where(cls[None, :] < 0, np.minimum(explicit[None, :], unit_speeds[:, 2:3]), speed)
    )


def _listed_table(units: Sequence[UnitState], tasks: Sequence[TstNode]) -> np.ndarray:
    """(U, T) the unit lists the task in tasks-available (one column per distinct name)."""
    names = sorted({n.name for n in tasks})
    name_col = {name: i for i, name in enumerate(names)}
    offers = np.array([[name in u.tasks for name in names] for u in units], dtype=bool)
    offers = offers.reshape(len(units), len(names))
    return np.asarray(offers[:, [name_col[n.name] for n in tasks]].reshape(len(units), len(tasks)))


def _width_table(units: Sequence[UnitState], geoms: Sequence[TaskGeometry]) -> np.ndarray:
    """(U, T) sweep width: the unit's footprint against the task's detection swath; NaN where
    the task is no search or the unit has no usable footprint (it cannot search)."""
    footprint = np.array([_footprint_or_nan(u) for u in units], dtype=float).reshape(len(units))
    detect = np.array(
        [detection_width(g.target_size) if g.kind == "areas" else np.nan for g in geoms]
    ).reshape(len(geoms))
    width = np.minimum(footprint[:, None], detect[None, :])
    return np.asarray(np.where(width > 0.0, width, np.nan))


def _task_ends_and_work(
    geoms: Sequence[TaskGeometry], task_xy: Sequence[np.ndarray], width: np.ndarray,
    listed: np.ndarray, unit_xy: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[tuple[np.ndarray, ...], ...],
           tuple[np.ndarray, np.ndarray] | None, dict[int, np.ndarray]]:
    """(T, 2) where each task starts and ends (NaN: depends on the unit, or in place), (U, T)
    the distance its work covers (inf: a search the unit cannot sweep), each search's
    polygons (``CostTables.polygons``), (U, T, 2) each unit's start and end (None without
    searches: ``CostTables.unit_start_xy``) and each search's ways (``CostTables.sweep_ways``,
    work s still to fill): a unit's start, end and work are those of the way it flies from
    where it is (``unit_xy``)."""
    n_t = len(geoms)
    start_xy = np.full((n_t, 2), np.nan)
    end_xy = np.full((n_t, 2), np.nan)
    path_len = np.zeros(n_t)
    work_distance = np.zeros(width.shape)
    polygons: list[tuple[np.ndarray, ...]] = [()] * n_t
    searches = np.array([g.kind == "areas" for g in geoms], dtype=bool).reshape(n_t)
    unit_ends = (np.full((width.shape[0], n_t, 2), np.nan), np.full((width.shape[0], n_t, 2),
                                                                    np.nan))
    ways: dict[int, np.ndarray] = {}
    for t, g in enumerate(geoms):
        if g.kind == "point":
            start_xy[t] = end_xy[t] = task_xy[t][0]
        elif g.kind == "path":
            xy = task_xy[t]
            start_xy[t], end_xy[t] = xy[0], xy[-1]
            path_len[t] = path_length(xy)
        elif g.kind == "areas":
            polygons[t] = tuple(_polygons_from(g, task_xy[t]))
            start_xy[t], end_xy[t], ways[t] = _sweep_work(
                g, polygons[t], width[:, t], listed[:, t], work_distance[:, t],
                (unit_ends[0][:, t], unit_ends[1][:, t]), unit_xy)
    work_distance += path_len[None, :]
    work_distance[np.isnan(width) & searches[None, :]] = np.inf
    if not searches.any():
        return start_xy, end_xy, work_distance, tuple(polygons), None, ways
    for ends, ref in zip(unit_ends, (start_xy, end_xy), strict=True):
        ends[:, ~searches] = ref[None, ~searches]
    return start_xy, end_xy, work_distance, tuple(polygons), unit_ends, ways


def _sweep_work(
    g: TaskGeometry, polygons: Sequence[np.ndarray], col: np.ndarray, listed: np.ndarray,
    out: np.ndarray, unit_ends: tuple[np.ndarray, np.ndarray], unit_xy: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One search task: each unit's sweep length into ``out`` and where it starts and ends into
    ``unit_ends`` ((U, 2) each; the ways to fly it once per distinct width ``col``, each unit's
    the way it flies from where it is, ``unit_xy``; a unit that cannot sweep gets the reference
    ends); the reference start and end (``CostTables``: the way the first unit sweeping at the
    reference width flies from where it is) and (U, K, 6) every unit's ways
    (``CostTables.sweep_ways``, work s NaN)."""
    polygons = list(polygons)
    ref = _reference_width(col, listed)
    ends: tuple[np.ndarray, np.ndarray] | None = None
    at_ref = np.flatnonzero((col == ref) & listed) if math.isfinite(ref) else np.zeros(0, int)
    if not len(at_ref) and math.isfinite(ref):
        at_ref = np.flatnonzero(col == ref)
    per_width: dict[float, list[tuple[float, float, float, float, float]]] = {}
    for w in sorted(set(col[np.isfinite(col)].tolist())):  # (np.unique, cheaper here)
        ways = flown_ways(polygons, w)
        rows = per_width[w] = way_ends(ways)
        for u in np.flatnonzero(col == w).tolist():
            sx, sy, ex, ey, length = rows[pick_way(rows, (float(unit_xy[u, 0]),
                                                          float(unit_xy[u, 1])))]
            out[u] = length
            unit_ends[0][u], unit_ends[1][u] = (sx, sy), (ex, ey)
        if w == ref:
            ends = unit_ends[0][at_ref[0]].copy(), unit_ends[1][at_ref[0]].copy()
    if ends is None:  # no unit at all: a nominal sweep for the geometry
        rows = way_ends(flown_ways(polygons, detection_width(g.target_size)))
        first = rows[pick_way(rows, None)] if rows else (math.nan,) * 5
        ends = np.array(first[0:2]), np.array(first[2:4])
    unit_ends[0][~np.isfinite(col)], unit_ends[1][~np.isfinite(col)] = ends
    k = max((len(rows) for rows in per_width.values()), default=0)
    table = np.full((len(col), k, 6), np.nan)
    for w, rows in per_width.items():
        table[col == w, : len(rows), :5] = np.array(rows)
    return ends[0], ends[1], table


def _fill_capability(tables: CostTables, costed: np.ndarray | None = None) -> None:
    """``need_time`` (travel there, the work, and home again where the unit has a home) and
    ``capable`` (listed, alive, not busy where excluded, within endurance, costed: ``only``),
    in place."""
    units = tables.units
    alive = np.array([u.alive for u in units], dtype=bool).reshape(len(units))
    busy = np.array([u.busy for u in units], dtype=bool).reshape(len(units))
    with np.errstate(divide="ignore", invalid="ignore"):
        back = tables.dist_end_to_home().T  # (U, T), NaN where no home / in place
        back = np.where(np.isnan(back), 0.0, back)
        need = (tables.dist_unit_to_start() + back) / tables.speed + tables.work_time
    need_time = np.where(np.isfinite(need), need, np.inf)
    capable = tables.listed & alive[:, None] & (need_time <= tables.endurance[:, None])
    if tables.exclude_busy:
        capable &= ~busy[:, None]
    if costed is not None:
        capable &= costed
    tables.need_time[...] = need_time
    tables.capable[...] = capable


def _footprint_or_nan(unit: UnitState) -> float:
    try:
        return footprint_width(unit)
    except (ValueError, OverflowError):  # pragma: no cover - absurd FOV values
        return math.nan


def _reference_width(col: np.ndarray, listed: np.ndarray) -> float:
    """The narrowest width among units offering the task (else among all units), or NaN."""
    for mask in (listed & np.isfinite(col), np.isfinite(col)):
        if mask.any():
            return float(col[mask].min())
    return math.nan
