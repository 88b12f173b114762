"""Which searches to share, among whom, and the tree that carries the parts (DESIGN 3.11).

Pure: no network, no clock. ``planner.plan_mission`` plans the tree as given first; for each
search a strategy may share (``sharing.SHAREABLE``, its ``execunit`` free), this module reads from
that schedule when each unit could be at the area (``a_i``: free of the tasks it does that need not
wait for the search, then its flight there), how fast it sweeps and how much endurance it has left,
sizes the parts by water filling and cuts the area (``sharing``). The node becomes a ``conc`` with
the node's own uuid and every other common field, holding one ``search-area`` per unit (a part in
several pieces: a ``search-areas``) with that unit fixed, every other parameter copied. The
planner then plans the tree with the parts (the rest of the tree is allocated around them) and
keeps whichever of the two plans is better. Once the parts are cut, their real sweep lengths are
known: the shares are sized again with each unit's real overhead and flight to where its sweep
starts, and the area cut again (``REFINEMENTS`` times).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np
import shapely

from delegation.allocation.sharing import (
    MIN_SHARE,
    PLAN_OVERHEAD,
    SHAREABLE,
    Sharer,
    band,
    divide,
    extent,
    falsi,
    fill_time,
    lower_bound,
    pieces_xy,
    region_of,
    shares,
)
from delegation.errors import InputError
from delegation.tst import ExecUnitKind, TstNode, classify_execunit, map_tree

if TYPE_CHECKING:
    from delegation.allocation.problem import Problem
    from delegation.allocation.schedule import Schedule
    from delegation.costs import CostTables
    from delegation.geo import LocalFrame

#: Parameters that say where a search is: replaced by each part's own.
_GEOMETRY = ("area", "areas", "geopoint", "radius")
#: A search is worth sharing when its 3.11 bound is below this share of what the quickest unit
#: alone needs (travel and sweep): small searches stay whole (cutting them costs more planning
#: time than it saves mission time).
WORTH_SHARING = 0.6
#: How many times the shares are sized again from the parts' real sweeps.
REFINEMENTS = 2
#: The parts are sized again for what the plan with them has the units do before the search
#: (``seen_in``) when that would end a search at least this much sooner (``lateness``): each
#: try costs a plan (0.05-0.1 s), and below a few per cent it seldom shortens the makespan.
RESEAT_GAIN = 1.05
#: How many times at most the parts are cut again when a unit cannot fly its part within its
#: endurance (``overrun``): each time the units that fell short get a smaller share.
ENDURANCE_ROUNDS = 4
#: When endurance is tight (some part sized above ``FIT_NEAR`` of what its unit's endurance
#: could sweep: the parts are then judged as flown, ``_cut_search``) and the usual cut's parts
#: do not all fit their units (``_fitted``): how many times the usual cut is sized again from
#: its own parts (``_damped``); how many directions strips are tried across (every 360 /
#: FIT_AXES degrees, ``_filled``); at most how many sweeps find each strip's width and how close
#: to its unit's endurance it is then (``_widest``); the share of the whole area's sweep
#: overhead below which the area is out of reach and no cut is tried (``_may_fit``).
FIT_NEAR = 0.8
FIT_ROUNDS = 6
FIT_AXES = 12
FIT_STEPS = 8
FIT_TOL = 0.002
FIT_HOPE = 0.95
#: A rest of the area under this fraction of it is left to the cut's rounding.
_CUT_EPS = 1e-6
#: Fraction of a unit's remaining endurance a part may be sized to use (the sweep's real overhead
#: is known only once the part is cut; the refinement and the plan's check do the rest).
ENDURANCE_MARGIN = 0.97


@dataclass(frozen=True, slots=True)
class Fit:
    """What a unit's earlier part measured: its sweep overhead (path / (A / w)), where its
    sweep may start (east, north m: each way's to fly it, ``coverage.flown_ways``; the unit
    flies there from the nearest) and how far from its end the unit's home is (m; None: not
    measured, the area's nearest point is used)."""

    overhead: float
    starts: tuple[tuple[float, float], ...] = ()
    home: float | None = None


#: Per shared search uuid, per unit index: what its part measured.
Fits = dict[str, dict[int, Fit]]


@dataclass(frozen=True)
class Part:
    """One unit's part of a shared search, as planned."""

    node_uuid: str
    unit: str
    area_m2: float
    polygons_xy: tuple[np.ndarray, ...]


@dataclass(frozen=True)
class SharedSearch:
    """A search node shared among units: its parts and the lower bound of 3.11 for it."""

    node_uuid: str
    name: str
    area_m2: float
    bound: float
    parts: tuple[Part, ...]


@dataclass
class SharedTree:
    """The tree with the shared searches replaced by their parts."""

    tree: TstNode
    searches: list[SharedSearch] = field(default_factory=list)

    def parts_of(self) -> dict[str, list[str]]:
        """Operator node uuid -> its parts' uuids."""
        return {s.node_uuid: [p.node_uuid for p in s.parts] for s in self.searches}


def shareable(node: TstNode) -> bool:
    """A search whose unit the service chooses (a fixed unit or an alias is never shared)."""
    if node.name not in SHAREABLE or node.is_control:
        return False
    try:
        kind, _ = classify_execunit(node.execunit)
    except TypeError:
        return False
    return kind is ExecUnitKind.FREE


@dataclass(frozen=True, slots=True)
class Busy:
    """What a unit does before a search in some schedule: until when (``free``, s from mission
    start), how much of its endurance that took (``used``, s) and where it is then (``here``,
    east/north m; None: where it starts). A part sized for a unit free sooner than it is in the
    plan that flies it makes the whole search late."""

    free: float
    used: float = 0.0
    here: tuple[float, float] | None = None


@dataclass(frozen=True, slots=True)
class Before:
    """What the units do before one search in some schedule: when the search is activated and,
    per unit index, its ``Busy`` (a unit not listed is free from ``act`` where it starts)."""

    act: float
    units: dict[int, Busy]


#: Nothing before the search: every unit free at once (the bound's default).
FREE = Before(0.0, {})


def before_search(problem: Problem, tables: CostTables, schedule: Schedule | None,
                  own: list[int]) -> Before:
    """What each unit does before the search whose tasks in ``problem`` are ``own`` (the search
    itself, or its parts in a tree where it is shared) in ``schedule`` (None: nothing,
    ``FREE``): a unit with a task of the search, what precedes it in its order; another, every
    task in its order that need not wait for the search (it could be done after, but the plan
    gave it that unit)."""
    if schedule is None or not own:
        return FREE
    first = own[0]
    act = 0.0
    if schedule.node_act is not None:
        node_act = float(schedule.node_act[problem.structure.node_of_task[first]])
        act = node_act if math.isfinite(node_act) else 0.0
    mine, after = set(own), problem.before[first]
    ends, travel, work = schedule.end, schedule.travel_time, schedule.work_time
    units: dict[int, Busy] = {}
    for u, order in enumerate(schedule.orders):
        first_own = next((i for i, k in enumerate(order) if k in mine), len(order))
        prior = [k for k in order[:first_own] if not after[k]]
        if not prior:
            continue
        last = max(prior, key=lambda k: float(ends[k]))
        end = (tables.end_for(u, last) if schedule.end_xy is None
               or np.isnan(schedule.end_xy[last]).any() else schedule.end_xy[last])
        units[u] = Busy(float(ends[last]), sum(float(travel[k] + work[k]) for k in prior),
                        None if end is None else (float(end[0]), float(end[1])))
    return Before(act, units)


@dataclass(frozen=True, slots=True)
class _Ready:
    """A unit that could sweep part of a search: free from ``free`` (s), having used ``used`` s
    of its endurance, at ``here`` (east, north m) by then."""

    unit: int
    free: float
    used: float
    here: tuple[float, float]


def _ready(problem: Problem, tables: CostTables, before: Before, t: int) -> list[_Ready]:
    """The units that could sweep part of task ``t``'s area, free after what ``before`` says
    they do first."""
    act = before.act
    width_col, speed_col = tables.width[:, t].tolist(), tables.speed[:, t].tolist()
    listed = tables.listed[:, t].tolist()
    ready = None if problem.ready is None else problem.ready.tolist()
    rows: list[_Ready] = []
    for u, unit in enumerate(tables.units):
        width, speed = width_col[u], speed_col[u]
        if not (unit.alive and "search-area" in unit.tasks and listed[u]
                and math.isfinite(width) and width > 0.0 and speed > 0.0):
            continue
        if tables.exclude_busy and unit.busy:
            continue
        free = act if ready is None else max(act, ready[u])
        used, here = 0.0, tables.unit_xy[u]
        busy = before.units.get(u)
        if busy is not None:
            free, used = max(free, busy.free), busy.used
            here = here if busy.here is None else busy.here
        rows.append(_Ready(u, free, used, (float(here[0]), float(here[1]))))
    return rows


def _sharers(problem: Problem, tables: CostTables, before: Before, t: int,
             region: shapely.Geometry, fits: dict[int, Fit], margin: float = ENDURANCE_MARGIN
             ) -> list[Sharer]:
    """The units that could sweep part of task ``t``'s area, free after what ``before`` says
    they do first; ``margin``: the share of what endurance is left that a part may be sized to
    use."""
    return _sharers_of(_ready(problem, tables, before, t), tables, t, region, fits, margin)


def _sharers_of(rows: list[_Ready], tables: CostTables, t: int, region: shapely.Geometry,
                fits: dict[int, Fit], margin: float) -> list[Sharer]:
    """``_sharers`` for the units ``rows``: each one's arrival, sweep rate (over its fit's
    overhead) and the area its endurance left can sweep."""
    if not rows:
        return []
    # Distances to the area in one vectorised call each (a shapely call per unit cost ~20 us).
    to_area = shapely.distance(region, shapely.points([r.here for r in rows])).tolist()
    back_d = _to_home(tables, [r.unit for r in rows], region)
    width_col, speed_col = tables.width[:, t].tolist(), tables.speed[:, t].tolist()
    out = []
    for row, near, back_m in zip(rows, to_area, back_d, strict=True):
        u, here = row.unit, row.here
        width, speed = width_col[u], speed_col[u]
        fit = fits.get(u, Fit(PLAN_OVERHEAD))
        if fit.starts:
            near = min(math.hypot(x - here[0], y - here[1]) for x, y in fit.starts)
        if fit.home is not None:
            back_m = fit.home
        travel = near / speed
        rate = speed * width / fit.overhead
        cap = math.inf
        endurance = float(tables.endurance[u])
        if math.isfinite(endurance):
            left = (endurance - row.used - travel - back_m / speed) * margin
            cap = max(0.0, left) * rate
        out.append(Sharer(u, row.free + travel, rate, cap, here))
    return out


def _to_home(tables: CostTables, units: list[int], region: shapely.Geometry) -> list[float]:
    """Metres from ``region`` to each of ``units``' homes (0 without a home)."""
    homes = tables.home_xy[units]
    has_home = ~np.isnan(homes).any(axis=1)
    back_d = np.zeros(len(units))
    if has_home.any():
        back_d[has_home] = shapely.distance(region, shapely.points(homes[has_home]))
    return [float(d) for d in back_d.tolist()]


def _part_node(original: TstNode, polygons: list[np.ndarray], frame: LocalFrame, unit: str,
               uuid: str) -> TstNode:
    """One unit's part: the original over ``polygons`` (`searched_over`), the unit fixed."""
    name, params = searched_over(original, polygons, frame)
    return TstNode(name=name, common_params={"execunit": "/" + unit, "node-uuid": uuid},
                   params=params)


def searched_over(original: TstNode, polygons: list[np.ndarray], frame: LocalFrame
                  ) -> tuple[str, dict[str, Any]]:
    """(name, params) of the search ``original`` over ``polygons`` (east/north m in ``frame``):
    a ``search-area`` (one piece) or ``search-areas`` (several), its other parameters copied,
    flown at its altitude. A unit's part, or a lost unit's unswept remainder."""
    altitude = _altitude(original)
    rings = []
    for poly in polygons:
        lat, lon = frame.to_geo(poly[:, 0], poly[:, 1])
        rings.append([{"latitude": float(a), "longitude": float(b), "altitude": altitude}
                      for a, b in zip(np.atleast_1d(lat), np.atleast_1d(lon), strict=True)])
    params: dict[str, Any] = {k: v for k, v in original.params.items() if k not in _GEOMETRY}
    if len(rings) == 1:
        return "search-area", {**params, "area": rings[0]}
    return "search-areas", {**params, "areas": rings}


def _altitude(node: TstNode) -> float:
    """The altitude the original search is flown at (its first point's, or its centre's)."""
    p = node.params
    first: Any = p.get("geopoint")
    if node.name == "search-area":
        first = p["area"][0]
    elif node.name == "search-areas":
        first = p["areas"][0][0]
    if isinstance(first, list) and first:
        first = first[0]
    value = first.get("altitude", 0.0) if isinstance(first, dict) else 0.0
    return float(value) if isinstance(value, int | float) else 0.0


def _conc_of(original: TstNode, parts: list[TstNode]) -> TstNode:
    """The ``conc`` that replaces the original: its uuid and other common fields kept."""
    common = {k: v for k, v in original.common_params.items() if k != "execunit"}
    return TstNode(name="conc", children=tuple(parts), common_params=common,
                   extra=dict(original.extra))


def search_bound(problem: Problem, tables: CostTables, schedule: Schedule | None, t: int,
                 before: Before | None = None) -> float:
    """DESIGN 3.11's lower bound (s from mission start) for search task ``t``: each unit that
    could take part sweeps ``speed x width`` m2/s, with no turns, from when it could be at the
    area's nearest point (free of what it does first in ``schedule``, or as ``before`` says;
    neither: free at once)."""
    region = region_of(_polygons(tables, t))
    if before is None:
        before = before_search(problem, tables, schedule, [t])
    raw = [Sharer(s.key, s.arrive, s.rate * PLAN_OVERHEAD)
           for s in _sharers(problem, tables, before, t, region, {})]
    return lower_bound(float(region.area), raw)


def _polygons(tables: CostTables, t: int) -> list[np.ndarray]:
    """Search task ``t``'s polygons in the tables' frame (empty: not a search)."""
    if tables.polygons:
        return list(tables.polygons[t])
    from delegation.costs import search_polygons_xy

    return search_polygons_xy(tables.tasks[t], tables.frame)


def worth_sharing(problem: Problem, tables: CostTables, t: int) -> bool:
    """Task ``t`` may be shared (``shareable``) and sharing could end it much sooner than the
    quickest unit alone (``WORTH_SHARING``), or no unit can do it alone (endurance)."""
    if not shareable(problem.tasks[t].node):
        return False
    alone = tables.need_time[:, t][tables.listed[:, t]]
    single = float(alone.min()) if len(alone) else math.inf
    if not math.isfinite(single):
        return True
    if _arrival_floor(tables, t) >= WORTH_SHARING * single:
        return False  # (the bound is at least that: no need to compute it)
    return search_bound(problem, tables, None, t) < WORTH_SHARING * single


def _arrival_floor(tables: CostTables, t: int) -> float:
    """A lower bound of ``search_bound(..., None, t)`` without geometry: no unit sweeps before
    it could reach the area's bounding box. Most searches of a mission are small and far from
    the nearest unit compared with their sweep, and are not worth sharing by this alone."""
    polygons = _polygons(tables, t)
    if not polygons:
        return 0.0
    every = np.concatenate(polygons)
    lo, hi = every.min(axis=0), every.max(axis=0)
    gap = np.maximum(np.maximum(lo - tables.unit_xy, tables.unit_xy - hi), 0.0)
    speed = tables.speed[:, t]
    with np.errstate(divide="ignore", invalid="ignore"):
        times = np.hypot(gap[:, 0], gap[:, 1]) / speed
    times = times[speed > 0.0]
    return float(times.min()) if len(times) else 0.0


def share_searches(
    tree: TstNode,
    problem: Problem,
    tables: CostTables,
    schedule: Schedule,
    new_uuid: Callable[[], str],
    fits: Fits | None = None,
    margin: float = ENDURANCE_MARGIN,
    seen: dict[str, Before] | None = None,
) -> SharedTree | None:
    """``tree`` (the tree ``problem`` and ``tables`` were built from) with every search worth
    sharing replaced by its parts (None when none is): a search is shared when at least two units
    get a part, or when the one unit that can cover it is another than ``schedule``'s (or it had
    none: endurance). ``fits``: what earlier parts measured (the refinement); ``margin``: the
    share of each unit's endurance left that its part may be sized to use. The parts are sized
    for what the units do before each search in ``schedule``, or in ``seen`` (per search uuid:
    what a plan with the parts had them do, ``seen_in``); the bound is always ``schedule``'s."""
    frame = tables.frame
    replaced: dict[str, TstNode] = {}
    searches: list[SharedSearch] = []
    for t, task in enumerate(problem.tasks):
        if not worth_sharing(problem, tables, t):
            continue
        polygons = _polygons(tables, t)
        if not polygons:
            continue
        region = region_of(polygons)
        if region.is_empty or region.area <= 0.0:
            continue
        fit = (fits or {}).get(task.uuid, {})
        before = (seen or {}).get(task.uuid) or before_search(problem, tables, schedule, [t])
        geoms = _cut_search(problem, tables, before, t, region, fit, margin)
        if not geoms or (len(geoms) == 1 and int(schedule.assign[t]) in geoms):
            continue
        bound = search_bound(problem, tables, schedule, t)
        nodes, parts = [], []
        for u in sorted(geoms, key=lambda k: tables.units[k].name):
            pieces = pieces_xy(geoms[u])
            if not pieces:
                continue
            uuid = new_uuid()
            name = tables.units[u].name
            nodes.append(_part_node(task.node, pieces, frame, name, uuid))
            parts.append(Part(uuid, name, float(geoms[u].area), tuple(pieces)))
        replaced[task.uuid] = _conc_of(task.node, nodes)
        searches.append(SharedSearch(task.uuid, task.name, float(region.area), bound,
                                     tuple(parts)))
    if not replaced:
        return None

    def swap(node: TstNode, children: tuple[TstNode, ...]) -> TstNode:
        if not node.is_control and node.node_uuid in replaced:
            return replaced[node.node_uuid or ""]
        return replace(node, children=children) if node.is_control else node

    return SharedTree(map_tree(tree, swap), searches)


def _cut_search(problem: Problem, tables: CostTables, before: Before, t: int,
                region: shapely.Geometry, fit: dict[int, Fit], margin: float
                ) -> dict[int, shapely.Geometry]:
    """Unit index -> its part of task ``t``'s ``region`` (empty: no parts): sized by water
    filling with what earlier parts measured (``fit``) and cut by ``divide``. When endurance
    may limit some unit (its part sized above ``FIT_NEAR`` of what it could sweep, or the
    units together short of the area) and a part so cut is over what its unit has left (its
    real sweep, flight there and home), other cuts are tried (``_fitted``)."""
    rows = _ready(problem, tables, before, t)
    sharers = _sharers_of(rows, tables, t, region, fit, margin)
    wanted = shares(float(region.area), sharers)
    geoms = divide(region, wanted, {s.key: s.point for s in sharers}) if wanted else {}
    if wanted and not any(wanted.get(s.key, 0.0) > FIT_NEAR * s.cap for s in sharers):
        return geoms  # (endurance is not what limits any part: nothing to judge)
    if geoms and _judged(geoms, rows, tables, t)[0] <= 1.0:
        return geoms
    return _fitted(rows, tables, t, region) or geoms


def _judged(geoms: dict[int, shapely.Geometry], rows: list[_Ready], tables: CostTables, t: int
            ) -> tuple[float, dict[int, Fit]]:
    """(the largest over the parts ``geoms`` of what its unit needs for it, flight there from
    where it is, its real sweep flown the way that costs least from there (``coverage.
    flown_ways``, ``pick_way``: what the cost tables count) and the way home, over the endurance
    it has left; what each part measured)."""
    from delegation.coverage import flown_ways, pick_way, way_ends

    by_unit = {r.unit: r for r in rows}
    worst = 0.0
    fits: dict[int, Fit] = {}
    for u, geom in geoms.items():
        row, width = by_unit[u], float(tables.width[u, t])
        speed, area = float(tables.speed[u, t]), float(geom.area)
        try:
            ways = way_ends(flown_ways(pieces_xy(geom), width))
        except InputError:  # (a cut left a degenerate sliver: such parts are not sent)
            return math.inf, fits
        if not ways or area <= 0.0:
            continue
        sx, sy, ex, ey, sweep = ways[pick_way(ways, row.here)]
        home = tables.home_xy[u]
        back = 0.0 if np.isnan(home).any() else math.hypot(ex - home[0], ey - home[1])
        need = (math.hypot(sx - row.here[0], sy - row.here[1]) + sweep + back) / speed
        left = float(tables.endurance[u]) - row.used
        worst = max(worst, need / left if left > 0.0 else math.inf)
        fits[u] = Fit(max(1.0, sweep / (area / width)), ((sx, sy),), back)
    return worst, fits


def _fitted(rows: list[_Ready], tables: CostTables, t: int, region: shapely.Geometry
            ) -> dict[int, shapely.Geometry] | None:
    """Parts of ``region`` that each fit their unit's endurance, or None when no cut tried
    does. The usual cut (``divide``: across each piece's long axis) sizes the parts for an
    overhead and a flight to where each sweep starts that the cut itself then changes; with
    endurance tight every part must fit as it will be flown (coast3-0.2km2, four drones at 40 %
    of one's need, 12 % slack: sizing again from what the parts measured went round in circles
    a few per cent over). So, unless the area is out of reach anyway (``_may_fit``): the usual
    cut sized again with damping (``_damped``), then strips across ``FIT_AXES`` directions,
    the units in the order they lie along each, then each strip to the unit with most room
    (``_filled``); the first whose every part fits is kept. Remembered (the planner cuts the
    same search again in each refinement)."""
    key = _fitted_key(rows, tables, t, region)
    if key in _FITTED:
        return _FITTED[key]
    found = None
    if _may_fit(rows, tables, t, region):
        found = _damped(rows, tables, t, region)
        tries = [(k, by_room) for by_room in (False, True) for k in range(FIT_AXES)]
        for k, by_room in tries if found is None else []:
            angle = 2.0 * math.pi * k / FIT_AXES
            axis = np.array([math.cos(angle), math.sin(angle)])
            found = _filled(rows, tables, t, region, axis, by_room)
            if found is not None:
                break
    if len(_FITTED) >= 32:
        _FITTED.pop(next(iter(_FITTED)))
    _FITTED[key] = found
    return found


def _may_fit(rows: list[_Ready], tables: CostTables, t: int, region: shapely.Geometry,
             whole_m2: float | None = None) -> bool:
    """Whether the units' endurance left could cover ``region`` (task ``t``'s area, or a part of
    it: ``whole_m2`` the area's): each flying to the region's nearest point (and home from it)
    and sweeping at ``FIT_HOPE`` of the whole area's sweep overhead at its width (parts measured
    1.13-1.24 where the whole area's was 1.17: a part's is seldom much less). When not, no cut
    is tried, or no strip more (each try costs sweeps)."""
    area = float(region.area)
    whole_m2 = area if whole_m2 is None else whole_m2
    fits: dict[int, Fit] = {}
    for row in rows:
        u = row.unit
        whole = float(tables.work_distance[u, t]) / (whole_m2 / float(tables.width[u, t]))
        fits[u] = Fit(max(1.0, FIT_HOPE * whole) if math.isfinite(whole) else 1.0)
    return sum(s.cap for s in _sharers_of(rows, tables, t, region, fits, 1.0)) >= area


def _damped(rows: list[_Ready], tables: CostTables, t: int, region: shapely.Geometry
            ) -> dict[int, shapely.Geometry] | None:
    """The usual cut (``divide``) sized again from what its own parts measured, ``FIT_ROUNDS``
    times, each time half way from the last sizing to the new one (undamped, a part's sweep
    start moving with the cut made the sizes go round in circles a few per cent over): the
    first whose every part fits, or None. When what endurance is left cannot cover the area as
    measured, every unit is sized at its cap (``_at_caps``)."""
    area = float(region.area)
    wanted: dict[int, float] = {}
    fits: dict[int, Fit] = {}
    for _ in range(FIT_ROUNDS):
        sharers = _sharers_of(rows, tables, t, region, fits, 1.0)
        target = shares(area, sharers) or _at_caps(area, sharers)
        if not target:
            return None
        wanted = {u: 0.5 * (wanted.get(u, target.get(u, 0.0)) + target.get(u, 0.0))
                  for u in set(wanted) | set(target)} if wanted else target
        geoms = divide(region, wanted, {s.key: s.point for s in sharers})
        worst, fits = _judged(geoms, rows, tables, t)
        if worst <= 1.0:
            return geoms
    return None


def _at_caps(area: float, sharers: list[Sharer]) -> dict[int, float]:
    """Every sharer's part at its cap, scaled to ``area`` (the caps together short of it)."""
    caps = {s.key: s.cap for s in sharers if 0.0 < s.cap < math.inf}
    total = sum(caps.values())
    return {k: c * area / total for k, c in caps.items()} if total > 0.0 else {}


def _filled(rows: list[_Ready], tables: CostTables, t: int, region: shapely.Geometry,
            axis: np.ndarray, by_room: bool = False) -> dict[int, shapely.Geometry] | None:
    """Strips of ``region`` across ``axis``, one per unit, each as wide as its unit can fly
    within its endurance left (``_widest``), the last unit the rest: None when the rest is more
    than it can fly. The units take their strips in the order they lie along ``axis``, or
    (``by_room``) each strip goes to the unit that could fly most of the rest (the least over
    its endurance on all of it): a part's sweep starts where its lanes do, not where its unit
    comes from, so the order along the axis is not always the one that fits (coast3-0.2km2 at
    39-39.5 % of one unit's need: feasible only so). A unit whose strip would be under
    ``MIN_SHARE`` of the area gets none."""
    lo, hi = extent(region, axis)
    left = sorted(rows, key=lambda r: (float(np.dot(r.here, axis)), r.unit))
    area, at = float(region.area), lo
    out: dict[int, shapely.Geometry] = {}
    while left:
        rest = band(region, axis, at, hi + 1.0)
        if rest.is_empty or rest.area <= _CUT_EPS * area:
            at = hi
            break
        if out and not _may_fit(left, tables, t, rest, area):
            return None  # (the units left cannot cover the rest: no need to sweep it)
        overs = [(_judged({r.unit: rest}, [r], tables, t)[0] - 1.0, i)
                 for i, r in enumerate(left if by_room else left[:1])]
        over, i = min(overs)
        row = left.pop(i)
        if over <= 0.0:
            out[row.unit], at = rest, hi
            break
        if not left:
            return None
        line = _widest(region, axis, at, hi, over, row, tables, t)
        strip = band(region, axis, at, line)
        if strip.area >= MIN_SHARE * area:
            out[row.unit], at = strip, line
    return out if at >= hi and out else None


def _widest(region: shapely.Geometry, axis: np.ndarray, at: float, hi: float, over: float,
            row: _Ready, tables: CostTables, t: int) -> float:
    """The farthest line (projection on ``axis``, between ``at`` and ``hi``) such that the strip
    of ``region`` from ``at`` to it is within ``row``'s endurance left, its real sweep, flight
    there and home (``_judged``; ``over``: the whole rest's need over it, less 1, > 0). Regula
    falsi (Illinois) on need / endurance - 1, nearly linear in the strip's area: within
    ``FIT_TOL`` in a few sweeps, ``FIT_STEPS`` at most (``at``: none fits)."""
    def over_of(line: float) -> float:
        return _judged({row.unit: band(region, axis, at, line)}, [row], tables, t)[0] - 1.0

    def close(f: float, lo: float, hi: float) -> bool:
        return -FIT_TOL <= f <= 0.0

    return falsi(over_of, (at, -1.0), (hi, over), FIT_STEPS, close)[0]


#: ``_fitted``'s answers by ``_fitted_key``.
_FITTED: dict[tuple[Any, ...], dict[int, shapely.Geometry] | None] = {}


def _fitted_key(rows: list[_Ready], tables: CostTables, t: int, region: shapely.Geometry
                ) -> tuple[Any, ...]:
    """What ``_fitted``'s answer depends on: the area, each unit's state, speed, width,
    endurance and home (None, not NaN: NaN equals nothing), and how hard it looks."""
    homes = [None if np.isnan(h).any() else tuple(h.tolist()) for h in tables.home_xy]
    units = tuple((r, float(tables.speed[r.unit, t]), float(tables.width[r.unit, t]),
                   float(tables.endurance[r.unit]), homes[r.unit]) for r in rows)
    return (shapely.to_wkb(region), units, FIT_ROUNDS, FIT_AXES, FIT_STEPS, FIT_TOL, FIT_HOPE)


def seen_in(shared: SharedTree, problem: Problem, tables: CostTables, schedule: Schedule
            ) -> dict[str, Before]:
    """Per shared search uuid: what the units do before it in ``schedule``, a plan of
    ``shared.tree`` (``problem`` and ``tables`` are that tree's). The other tasks of the tree are
    allocated around the parts, not always as in the plan the parts were sized from: a unit
    that now does a task first is late for its part, and the parts are sized again from this."""
    index = {task.uuid: t for t, task in enumerate(problem.tasks)}
    out: dict[str, Before] = {}
    for search in shared.searches:
        own = [index[p.node_uuid] for p in search.parts if p.node_uuid in index]
        if own:
            out[search.node_uuid] = before_search(problem, tables, schedule, own)
    return out


def lateness(shared: SharedTree, seen: dict[str, Before], planned: Problem, schedule: Schedule,
             problem: Problem, tables: CostTables, fits: Fits) -> float:
    """The largest, over ``shared``'s searches, of when the search ends in ``schedule`` (a plan
    of ``shared.tree``, whose problem is ``planned``) over when parts sized for ``seen`` (what
    that plan has the units do first, ``seen_in``) would end it (the water filling's ``T``,
    with each unit's measured sweep in ``fits``): above 1 when sizing the parts again would end
    a search sooner. ``problem`` and ``tables`` are the tree's before sharing. 0 when no search
    can be judged (none seen, or no parts could cover it)."""
    index = {task.uuid: t for t, task in enumerate(problem.tasks)}
    planned_index = {task.uuid: t for t, task in enumerate(planned.tasks)}
    worst = 0.0
    for search in shared.searches:
        before, t = seen.get(search.node_uuid), index.get(search.node_uuid)
        if before is None or t is None:
            continue
        region = region_of(_polygons(tables, t))
        sharers = _sharers(problem, tables, before, t, region, fits.get(search.node_uuid, {}))
        refill = fill_time(float(region.area), sharers)
        ends = [float(schedule.end[planned_index[p.node_uuid]]) for p in search.parts]
        end = max(math.inf if math.isnan(e) else e for e in ends)
        if math.isfinite(refill) and refill > 0.0:
            worst = max(worst, end / refill)
    return worst


def measured(shared: SharedTree, tables: CostTables) -> Fits:
    """Per shared search, per unit index: its part's real sweep length over ``A / w`` (at the
    unit's width, flown the way that costs least from where the unit is) and where each way to
    fly it starts (``coverage.flown_ways``: the unit flies there from the nearest, wherever its
    earlier tasks leave it), for sizing the shares again. ``tables`` are those of the tree
    before sharing (the parts' widths are their search's)."""
    from delegation.coverage import flown_ways, pick_way, way_ends

    index = {node.node_uuid: t for t, node in enumerate(tables.tasks)}
    names = {unit.name: u for u, unit in enumerate(tables.units)}
    out: Fits = {}
    for search in shared.searches:
        t = index.get(search.node_uuid)
        if t is None:
            continue
        col = tables.width[:, t]
        per: dict[int, Fit] = {}
        for part in search.parts:
            u = names.get(part.unit)
            width = math.nan if u is None else float(col[u])
            if u is None or not width > 0.0 or part.area_m2 <= 0.0:
                continue

            ways = way_ends(flown_ways(list(part.polygons_xy), width))
            if not ways:
                continue
            here = (float(tables.unit_xy[u, 0]), float(tables.unit_xy[u, 1]))
            sweep = ways[pick_way(ways, here)][4]
            per[u] = Fit(max(1.0, sweep / (part.area_m2 / width)),
                         tuple((row[0], row[1]) for row in ways))
        out[search.node_uuid] = per
    return out


def overrun(shared: SharedTree, problem: Problem, tables: CostTables, schedule: Schedule
            ) -> dict[str, dict[int, float]]:
    """Per shared search uuid, per unit index (of ``tables``' units): how many times shorter
    the unit's sweep must be to fit what endurance it had left (its flight there unchanged), for
    each part ``schedule`` could not assign (> 1, at most 2; only parts left unassigned for want
    of endurance). ``problem`` and ``tables`` are those of ``shared.tree``."""
    index = {task.uuid: t for t, task in enumerate(problem.tasks)}
    names = {unit.name: u for u, unit in enumerate(tables.units)}
    out: dict[str, dict[int, float]] = {}
    for search in shared.searches:
        for part in search.parts:
            t, u = index.get(part.node_uuid), names.get(part.unit)
            if t is None or u is None or int(schedule.assign[t]) >= 0:
                continue
            have = float(tables.endurance[u]) - float(schedule.unit_used[u])
            need, sweep = float(tables.need_time[u, t]), float(tables.work_time[u, t])
            if math.isfinite(need) and need > have:
                # The flight there stays: the sweep must shrink by all of the excess.
                left = sweep - (need - have)
                ratio = sweep / left if left > 0.0 else 2.0
                out.setdefault(search.node_uuid, {})[u] = min(2.0, ratio * 1.02)
    return out


def strained(fits: Fits, strain: dict[str, dict[int, float]]) -> Fits:
    """``fits`` with each strained unit's sweep overhead multiplied by its strain (the parts
    are then sized as if that unit swept slower: it gets less)."""
    out: Fits = {uuid: dict(per) for uuid, per in fits.items()}
    for uuid, per in strain.items():
        mine = out.setdefault(uuid, {})
        for u, factor in per.items():
            fit = mine.get(u, Fit(PLAN_OVERHEAD))
            mine[u] = Fit(fit.overhead * factor, fit.starts)
    return out
