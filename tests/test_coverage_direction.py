"""The sweep direction search's shortcut (``coverage._convex_floor``): on convex polygons a
direction whose lower bound is longer than a path already found is not swept. The floor must be
a true lower bound and the choice the same as sweeping every candidate.

Pure geometry: no clock, no network.
"""

from __future__ import annotations

import math
import random

import numpy as np
import pytest
from shapely.geometry import Polygon

from delegation import coverage
from delegation.coverage import candidate_directions, coverage_length, sweep_direction


def convex(rng: random.Random) -> np.ndarray:
    angles = sorted(rng.uniform(0.0, 2.0 * math.pi) for _ in range(rng.randint(3, 10)))
    a, b = rng.uniform(40.0, 900.0), rng.uniform(40.0, 900.0)
    pts = [(a * math.cos(t), b * math.sin(t)) for t in angles]
    hull = Polygon(pts).convex_hull
    ring = np.array(hull.exterior.coords)[:-1]
    return ring[::-1] if rng.random() < 0.5 else ring


def exhaustive(poly: np.ndarray, width: float) -> np.ndarray:
    """The direction the search picks when every candidate is swept (no floor)."""
    candidates = candidate_directions(poly)
    frame = coverage._sweep_frame(poly)
    short = frame.y_hi - frame.y_lo
    if short / width > coverage._SCREEN_LANES and len(candidates) > coverage._SCREEN_KEEP:
        coarse = short / coverage._SCREEN_LANES
        rough = np.array([coverage_length(poly, coarse, along=v) for v in candidates])
        bar = np.sort(rough)[coverage._SCREEN_KEEP - 1] * (1.0 + coverage._SAME_LENGTH)
        candidates = candidates[np.union1d(np.flatnonzero(rough <= bar), [0])]
    scores = [(coverage_length(poly, width, along=v), len(coverage.sweep_lanes(poly, width, v)))
              for v in candidates]
    shortest = min(length for length, _ in scores)
    near = [i for i, (length, _) in enumerate(scores)
            if length <= shortest * (1 + coverage._SAME_LENGTH)]
    return np.asarray(candidates[min(near, key=lambda i: (scores[i][1], i))])


@pytest.mark.parametrize("seed", range(3))
def test_the_floor_is_a_lower_bound_and_the_choice_is_unchanged(seed: int) -> None:
    rng = random.Random(seed)
    for _ in range(60):
        poly = convex(rng)
        if len(poly) < 3:
            continue
        width = rng.choice([9.2, 24.0, 37.0, 80.0])
        area = coverage._convex_area(poly)
        assert area == pytest.approx(Polygon(poly).area, rel=1e-9)
        for v in candidate_directions(poly):
            floor = coverage._convex_floor(poly, area, width, v)
            assert floor <= coverage_length(poly, width, along=v) * (1 + 1e-9)
        assert sweep_direction(poly, width) == pytest.approx(exhaustive(poly, width), abs=1e-12)


def test_only_convex_polygons_get_a_floor() -> None:
    square = np.array([[0.0, 0.0], [100.0, 0.0], [100.0, 100.0], [0.0, 100.0]])
    assert coverage._convex_area(square) == pytest.approx(1e4)
    assert coverage._convex_area(square[::-1]) == pytest.approx(1e4)
    ell = np.array([[0, 0], [3, 0], [3, 1], [1, 1], [1, 3], [0, 3]], dtype=float)
    assert coverage._convex_area(ell) is None
    star = np.array([[math.cos(4 * math.pi * i / 5), math.sin(4 * math.pi * i / 5)]
                     for i in range(5)])  # every turn the same way, but it winds twice
    assert coverage._convex_area(star) is None


def test_a_remembered_path_is_not_changed_by_its_caller() -> None:
    poly = np.array([[0.0, 0.0], [300.0, 0.0], [300.0, 120.0], [0.0, 120.0]])
    first = coverage.coverage_path(poly, 25.0)
    first[:] = 0.0
    again = coverage.coverage_path(poly, 25.0)
    assert coverage.path_length(again) > 0.0


def test_the_chosen_direction_is_swept_once() -> None:
    # Choosing sweeps the winner; the cells and ways asked for next are that sweep, remembered
    # (a convex area's sweep is the same with or without gap lanes, and is remembered as one).
    poly = np.array([[0.0, 0.0], [301.0, 0.0], [301.0, 97.0], [0.0, 97.0]])
    coverage._swept.cache_clear()
    sweep_direction(poly, 9.5)
    swept = coverage._swept.cache_info().misses
    coverage.sweep_cells(poly, 9.5)
    coverage.coverage_path(poly, 9.5)
    coverage.flown_ways([poly], 9.5)
    assert coverage._swept.cache_info().misses == swept
