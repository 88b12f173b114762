"""Area search: how much a sweep wastes on concave polygons (DESIGN 3.11).

    python benchmarks/team_search.py                 # every polygon, drone (37 m) and boat widths
    python benchmarks/team_search.py --widths 37

The polygons are generated here, deterministically (fixed seeds): coastline-like radial polygons
with bays, and L, U, comb, crescent and star shapes, each scaled to 0.2-4 km2 (the published
multi-robot coverage benchmark's polygons cannot be downloaded here). For each polygon and sweep
width it prints the coverage path length over ``A / w`` (the area divided by the sweep width: no
turns, no overlap), once with the lanes along the minimum rectangle's long axis (the old rule) and
once along the direction ``delegation.coverage.sweep_direction`` chooses, then the geometric mean
and the worst of each. Pure geometry: no broker, no clock beyond the timing of the choice.
"""

from __future__ import annotations

import argparse
import math
import random
import time

import numpy as np
from shapely.geometry import Polygon

from delegation.coverage import coverage_length, sweep_axes, sweep_direction

#: Sweep widths (m): a drone at 40 m with a 60 degree camera, and a boat at 10 m.
WIDTHS = (37.0, 9.2)
#: Areas (km2) the shapes are scaled to, in turn.
AREAS_KM2 = (0.2, 0.5, 1.0, 2.0, 4.0)


def _coast(seed: int, n: int = 48) -> np.ndarray:
    """A star-shaped polygon with a ragged, coastline-like boundary and two or three deep bays."""
    rng = random.Random(seed)
    bays = [(rng.uniform(0, 2 * math.pi), rng.uniform(0.25, 0.5), rng.uniform(0.2, 0.45))
            for _ in range(rng.randint(2, 3))]
    pts = []
    for i in range(n):
        a = 2 * math.pi * i / n
        r = 1.0 + 0.12 * rng.uniform(-1, 1)
        for centre, width, depth in bays:
            d = abs((a - centre + math.pi) % (2 * math.pi) - math.pi)
            if d < width:
                r -= depth * (1 - d / width)
        stretch = 1.6 if seed % 2 else 1.0
        pts.append((stretch * r * math.cos(a), r * math.sin(a)))
    return np.array(pts)


def _shapes() -> dict[str, np.ndarray]:
    shapes = {
        "L": np.array([[0, 0], [3, 0], [3, 1], [1, 1], [1, 3], [0, 3]], dtype=float),
        "U": np.array([[0, 0], [3, 0], [3, 2], [2, 2], [2, 1], [1, 1], [1, 2], [0, 2]],
                      dtype=float),
        "comb": np.array([[0, 0], [5, 0], [5, 3], [4, 3], [4, 1], [3, 1], [3, 3], [2, 3],
                          [2, 1], [1, 1], [1, 3], [0, 3]], dtype=float),
        "crescent": np.array(
            [[math.cos(a), math.sin(a)] for a in np.linspace(0.0, math.pi, 24)]
            + [[0.6 * math.cos(a), 0.45 * math.sin(a)] for a in np.linspace(math.pi, 0.0, 24)]
        ),
        "star": np.array([[(1.0 if i % 2 == 0 else 0.5) * math.cos(math.pi * i / 5 + 0.3),
                           (1.0 if i % 2 == 0 else 0.5) * math.sin(math.pi * i / 5 + 0.3)]
                          for i in range(10)]),
    }
    for seed in range(5):
        shapes[f"coast{seed}"] = _coast(seed)
    return shapes


def concave_polygons() -> dict[str, np.ndarray]:
    """Name -> (N, 2) polygon in metres: every shape rotated by a fixed angle and scaled to one of
    ``AREAS_KM2`` in turn (deterministic)."""
    out = {}
    for i, (name, shape) in enumerate(sorted(_shapes().items())):
        area_km2 = AREAS_KM2[i % len(AREAS_KM2)]
        a = math.radians(17.0 * i + 5.0)
        rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
        centred = (shape - shape.mean(axis=0)) @ rot.T
        scale = math.sqrt(area_km2 * 1e6 / Polygon(centred).area)
        out[f"{name}-{area_km2:g}km2"] = centred * scale
    return out


def _geo_mean(xs: list[float]) -> float:
    return math.exp(sum(math.log(x) for x in xs) / len(xs))


def sweep_overhead(widths: tuple[float, ...]) -> None:
    """Print path / (A / w) per polygon and width, old rule and chosen direction."""
    old_all: list[float] = []
    new_all: list[float] = []
    print(f"{'polygon':<20} {'w m':>5} {'A/w m':>9} {'old':>6} {'chosen':>7} {'choose s':>9}")
    for name, poly in concave_polygons().items():
        area = Polygon(poly).area
        for w in widths:
            ideal = area / w
            old = coverage_length(poly, w, along=sweep_axes(poly)[0]) / ideal
            t0 = time.perf_counter()
            along = sweep_direction(poly, w)
            took = time.perf_counter() - t0
            new = coverage_length(poly, w, along=along) / ideal
            old_all.append(old)
            new_all.append(new)
            print(f"{name:<20} {w:5.1f} {ideal:9.0f} {old:6.3f} {new:7.3f} {took:9.3f}")
    print(f"sweep overhead path/(A/w): long-axis rule geo-mean {_geo_mean(old_all):.3f} "
          f"worst {max(old_all):.3f}; chosen direction geo-mean {_geo_mean(new_all):.3f} "
          f"worst {max(new_all):.3f} ({len(new_all)} sweeps)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--widths", type=float, nargs="+", default=list(WIDTHS))
    args = parser.parse_args()
    sweep_overhead(tuple(args.widths))


if __name__ == "__main__":
    main()
