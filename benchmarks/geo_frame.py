"""Cost of the mission-local ENU frame's conversions (issue 19: suite CPU and cost per mission).

    python benchmarks/geo_frame.py [--repeat 2000] [--array 1000]

Per call, in CPU µs (``time.process_time``, so the figure holds on a loaded machine; best of 5
rounds): ``LocalFrame.to_xy`` and ``to_geo`` on one point (what a simulated unit's status tick and
the planner's per-point look-ups do), ``geopoint``, and both on an array of ``--array`` points (per
point). Then a simulated flight: a `SimVehicle` flying a search, stepped 0.25 s at a time, reading
its ``position`` on every step (what ``delegation sim`` does for each status message): CPU µs per
step. The points are 0-40 km from an origin at 57.76 N 16.68 E (the demo's site).

Measured (2026-11-26, 2 CPUs shared, load average 13-17; before = pymap3d's ``geodetic2enu`` and
three ``enu2geodetic`` steps, after = the frame's own closed form, issue 19), CPU µs:

    to_xy, one point                   10.0 ->  1.1
    to_geo, one point                 288   ->  1.2
    geopoint, one point               287   ->  2.5
    to_xy, 1000 points, per point       0.10 -> 0.06
    to_geo, 1000 points, per point      0.70 -> 0.04
    sim flight, per 0.25 s step       293-325 -> 4.7   (reading the position each step)
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable

import numpy as np

from delegation.fleet import make_unit
from delegation.geo import GeoPoint, LocalFrame
from delegation.sim.vehicle import SimVehicle

ORIGIN = (57.7600, 16.6800)


def _per_call_us(fn: Callable[[int], object], n: int, rounds: int = 5) -> float:
    """Best-of-``rounds`` CPU µs per call of ``fn(i)``, ``n`` calls a round."""
    best = math.inf
    for _ in range(rounds):
        t0 = time.process_time()
        for i in range(n):
            fn(i)
        best = min(best, time.process_time() - t0)
    return best / n * 1e6


def _flight_us_per_step(steps: int) -> float:
    """CPU µs per 0.25 s step of a simulated search with the position read on each step."""
    unit = make_unit("u0", "air", GeoPoint(latitude=ORIGIN[0], longitude=ORIGIN[1], altitude=20),
                     ["search-area"], {"slow": 2.0, "standard": 5.0, "fast": 10.0})
    area = [{"latitude": ORIGIN[0] + dlat, "longitude": ORIGIN[1] + dlon, "altitude": 0.0}
            for dlat, dlon in [(0.0, 0.0), (0.0, 0.01), (0.005, 0.01), (0.005, 0.0)]]
    v = SimVehicle(unit)
    if v.start_task("search-area", {"area": area, "speed": "standard"}, "t0") is not None:
        raise RuntimeError("the simulated vehicle refused the search")
    t0 = time.process_time()
    for _ in range(steps):
        v.step(0.25)
        _ = v.position
    return (time.process_time() - t0) / steps * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=2000, help="scalar calls per round")
    parser.add_argument("--array", type=int, default=1000, help="points in the array calls")
    parser.add_argument("--steps", type=int, default=2000, help="simulated flight steps")
    args = parser.parse_args()

    frame = LocalFrame(*ORIGIN)
    rng = np.random.default_rng(19)
    r = rng.uniform(0.0, 40_000.0, args.repeat)
    a = rng.uniform(0.0, 2 * math.pi, args.repeat)
    east, north = (r * np.cos(a)).tolist(), (r * np.sin(a)).tolist()
    lat, lon = frame.to_geo(np.array(east), np.array(north))
    lats, lons = lat.tolist(), lon.tolist()
    ea, na = np.array(east[: args.array]), np.array(north[: args.array])
    la, lo = lat[: args.array], lon[: args.array]
    m = args.array

    rows = [
        ("to_xy, one point", _per_call_us(lambda i: frame.to_xy(lats[i], lons[i]), args.repeat)),
        ("to_geo, one point", _per_call_us(lambda i: frame.to_geo(east[i], north[i]),
                                           args.repeat)),
        ("geopoint, one point", _per_call_us(lambda i: frame.geopoint(east[i], north[i]),
                                             args.repeat)),
        (f"to_xy, {m} points, per point", _per_call_us(lambda i: frame.to_xy(la, lo), 20) / m),
        (f"to_geo, {m} points, per point", _per_call_us(lambda i: frame.to_geo(ea, na), 20) / m),
        ("sim flight, per 0.25 s step with position", _flight_us_per_step(args.steps)),
    ]
    for name, us in rows:
        print(f"{name:<45} {us:10.2f} µs CPU")


if __name__ == "__main__":
    main()
