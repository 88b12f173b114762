"""What a lost unit had swept of its search is subtracted (issue 21 item 4, issue 22 item 3;
`service.sweep_progress`): a simulated vehicle (the real kinematics) flies part of a search and
reports its position at 2 Hz; the remainder is what its reported track had not swept. Nothing it
had not really swept is dropped (its true trajectory, w/2 either side, and the remainder cover the
area), the remainder is no larger than the unflown share needs, and a track that tells nothing
(none, or elsewhere) credits nothing."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
import shapely

from delegation.allocation.sharing import region_of
from delegation.costs import search_polygons_xy, sweep_width, task_geometry
from delegation.fleet import make_unit
from delegation.geo import GeoPoint, LocalFrame
from delegation.service.sweep_progress import MIN_REMAINDER, swept_region, unswept
from delegation.sim.flown import footprint
from delegation.sim.vehicle import SimVehicle
from delegation.tst.node import TstNode

HOME = GeoPoint(latitude=57.7600, longitude=16.6800, altitude=20.0)
SPEED = 5.0


def square(lat: float, lon: float, dlat: float = 0.0018, dlon: float = 0.0030
           ) -> list[dict[str, float]]:
    return [{"latitude": a, "longitude": b, "altitude": 20.0}
            for a, b in ((lat, lon), (lat + dlat, lon), (lat + dlat, lon + dlon),
                         (lat, lon + dlon))]


def search(name: str = "search-area") -> TstNode:
    area = square(57.7620, 16.6800)
    params: dict[str, Any] = {"speed": "standard"}
    if name == "search-area":
        params["area"] = area
    else:
        params["areas"] = [area, square(57.7650, 16.6800)]
    return TstNode(name=name, common_params={"execunit": "/u0", "node-uuid": "p0"},
                   params=params)


def flight(node: TstNode, share: float, report_every: float = 0.5
           ) -> tuple[SimVehicle, list[GeoPoint], list[GeoPoint]]:
    """A vehicle that flew ``share`` of its task's time: (it, its true trajectory sampled
    finely, the positions it reported every ``report_every`` s)."""
    unit = make_unit("u0", "air", HOME, ["search-area", "search-areas"],
                     {"slow": 2.0, "standard": SPEED, "fast": 10.0})
    v = SimVehicle(unit)
    assert v.start_task(node.name, node.params, "t0") is None
    legs = np.array([(v.east, v.north)] + [leg[:2] for leg in v.tasks["t0"].legs])
    total = float(np.hypot(*np.diff(legs, axis=0).T).sum()) / SPEED
    # Where it was (east/north in its own frame), made GeoPoints at the end in one conversion:
    # `SimVehicle.position` converts one point at a time (most of this test's time when it did).
    xy, is_report, t, dt = [(v.east, v.north, v.altitude)], [True], 0.0, 0.25
    while t < share * total:
        v.step(dt)
        t += dt
        xy.append((v.east, v.north, v.altitude))
        is_report.append(round(t / dt) % round(report_every / dt) == 0)
    east, north, up = np.array(xy).T
    lat, lon = v.frame.to_geo(east, north)
    truth = [GeoPoint(latitude=float(a), longitude=float(b), altitude=float(h))
             for a, b, h in zip(lat, lon, up, strict=True)]
    return v, truth, [p for p, report in zip(truth, is_report, strict=True) if report]


def region(node: TstNode, frame: LocalFrame | None = None
           ) -> tuple[shapely.Geometry, LocalFrame]:
    g = task_geometry(node)
    frame = frame or LocalFrame.around([p for a in g.areas for p in a])
    return region_of(search_polygons_xy(node, frame)), frame


@pytest.mark.parametrize("share", [0.3, 0.6, 0.9])
@pytest.mark.parametrize("name", ["search-area", "search-areas"])
def test_nothing_unswept_is_dropped_and_what_is_left_is_the_unflown_share(
        share: float, name: str) -> None:
    node = search(name)
    vehicle, truth, reported = flight(node, share)
    left, done = unswept(node, vehicle.unit, reported)
    assert 0.0 < done < 1.0
    assert left.node_uuid == "p0" and left.execunit == "/u0"
    assert left.params["speed"] == "standard" and left.name in ("search-area", "search-areas")
    whole, frame = region(node)
    rest, _ = region(left, frame)
    width = sweep_width(vehicle.unit, task_geometry(node).target_size)
    # The camera's footprint along the true trajectory (square, as the sweeps are planned: lanes
    # end w/2 inside the border, `coverage.turns_inside`).
    really = footprint(frame.points_xy(truth), width)
    # What the unit's whole sweep never images (corner slivers where lanes end w/2 inside a
    # slanted border) is no piece the remainder dropped.
    _, whole_flight, _ = flight(node, 1.01)
    never = whole.difference(footprint(frame.points_xy(whole_flight), width))
    missed = whole.difference(shapely.union_all([really, rest, never]))
    assert missed.area <= 0.005 * whole.area, "an unswept piece was dropped"
    assert rest.difference(whole).area <= 0.005 * whole.area  # inside the area
    # Left: no more than what the true flight had not covered, plus the last report's lag (half
    # a second of flight, a lane wide), plus the slivers' rounding.
    not_covered = whole.difference(really).area
    assert rest.area <= not_covered + width * SPEED * 0.5 + 0.01 * whole.area


def test_no_track_or_one_elsewhere_credits_nothing() -> None:
    node = search()
    vehicle, _, _ = flight(node, 0.5)
    assert unswept(node, vehicle.unit, []) == (node, 0.0)
    far = [GeoPoint(latitude=57.7500, longitude=16.6500 + 0.0001 * i, altitude=20.0)
           for i in range(10)]
    assert unswept(node, vehicle.unit, far) == (node, 0.0)


def test_a_sweep_almost_done_is_not_made_a_task_of_nothing() -> None:
    node = search()
    vehicle, _, reported = flight(node, 1.0)
    assert unswept(node, vehicle.unit, reported) == (node, 0.0)
    assert MIN_REMAINDER > 0.0


def test_positions_far_apart_are_a_gap_not_a_flight() -> None:
    track = np.array([(0.0, 0.0), (10.0, 0.0), (500.0, 0.0), (510.0, 0.0)])
    swept = swept_region(track, 20.0)
    assert len(shapely.get_parts(swept)) == 2
    assert not swept.contains(shapely.Point(250.0, 0.0))
