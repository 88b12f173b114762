"""Coverage sweeps of concave areas: lanes are clipped to the area, never flown across a gap.

Pure geometry: no clock, no network.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import shapely
from shapely.geometry import LineString, Polygon

from delegation.coverage import (
    candidate_directions,
    coverage_estimate,
    coverage_length,
    coverage_path,
    footprint,
    multi_coverage_path,
    path_length,
    sweep_axes,
    sweep_cells,
    sweep_direction,
    sweep_lanes,
)

#: A U open to the north: 300 m wide, 200 m tall, arms 100 m wide, the gap 100 m deep. The long
#: axis is east-west, so the lanes in the northern half cross the gap between the arms.
U_SHAPE = np.array(
    [
        [0.0, 0.0],
        [300.0, 0.0],
        [300.0, 200.0],
        [200.0, 200.0],
        [200.0, 100.0],
        [100.0, 100.0],
        [100.0, 200.0],
        [0.0, 200.0],
    ]
)

WIDTHS = [7.0, 10.0, 17.0, 33.0]


def rotate(poly: np.ndarray, degrees: float) -> np.ndarray:
    a = np.radians(degrees)
    r = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    return np.asarray(poly @ r.T + np.array([1234.0, -567.0]))


def covered_fraction(path: np.ndarray, shape: Polygon, width: float) -> float:
    band = LineString(path).buffer(width / 2.0 * 1.0001, cap_style="flat")
    return float(band.intersection(shape).area / shape.area)


@pytest.mark.parametrize("degrees", [0.0, 23.0, 90.0])
@pytest.mark.parametrize("width", WIDTHS)
def test_every_lane_segment_lies_within_the_u(width: float, degrees: float) -> None:
    poly = rotate(U_SHAPE, degrees)
    lanes = sweep_lanes(poly, width)
    inside = Polygon(poly).buffer(1e-6)
    assert shapely.within(shapely.linestrings(lanes), inside).all()
    # The lanes in the arms are split in two: more segments than lanes.
    assert len(lanes) > np.ceil(200.0 / width - 1e-9)


@pytest.mark.parametrize("width", WIDTHS)
def test_the_u_is_covered_and_every_lane_is_in_the_path(width: float) -> None:
    shape = Polygon(U_SHAPE)
    path = coverage_path(U_SHAPE, width)
    assert covered_fraction(path, shape, width) > 0.99
    # The path flies every segment (its two ends are consecutive points of the path).
    legs = {(tuple(np.round(a, 6)), tuple(np.round(b, 6))) for a, b in itertools.pairwise(path)}
    for a, b in sweep_lanes(U_SHAPE, width):
        ka, kb = tuple(np.round(a, 6)), tuple(np.round(b, 6))
        assert (ka, kb) in legs or (kb, ka) in legs


@pytest.mark.parametrize("width", WIDTHS)
def test_the_u_is_three_cells_and_the_gap_is_crossed_once(width: float) -> None:
    east = np.array([1.0, 0.0])  # (lanes across the arms; the chosen direction runs along them)
    cells = sweep_cells(U_SHAPE, width, along=east)
    assert len(cells) == 3  # the base and the two arms
    path = coverage_path(U_SHAPE, width, along=east)
    # Legs over the gap (outside the area) are transitions; with the cells flown one after the
    # other the gap is crossed at most once, not on every split lane.
    gap = Polygon([(100.0, 100.0), (200.0, 100.0), (200.0, 200.0), (100.0, 200.0)])
    legs = shapely.linestrings(np.stack([path[:-1], path[1:]], axis=1))
    crossings = shapely.length(shapely.intersection(legs, gap.buffer(-1.0))) > 0.0
    assert crossings.sum() <= 1


@pytest.mark.parametrize("width", WIDTHS)
def test_path_length_is_the_built_path_and_at_least_the_estimate(width: float) -> None:
    path = coverage_path(U_SHAPE, width)
    assert coverage_length(U_SHAPE, width) == pytest.approx(path_length(path), rel=1e-12)
    # The closed form uses the U's own area (not its convex hull's): the transitions between
    # cells come on top of it.
    assert Polygon(U_SHAPE).area == pytest.approx(50_000.0)
    assert path_length(path) >= coverage_estimate(U_SHAPE, width)
    # ... and it is shorter than sweeping the U's bounding rectangle (no lane crosses the gap).
    rect = np.array([[0.0, 0.0], [300.0, 0.0], [300.0, 200.0], [0.0, 200.0]])
    assert path_length(path) < coverage_length(rect, width)


def test_all_four_variants_fly_the_same_lanes() -> None:
    lengths = [path_length(coverage_path(U_SHAPE, 10.0, v)) for v in range(4)]
    starts = {tuple(coverage_path(U_SHAPE, 10.0, v)[0]) for v in range(4)}
    assert len(starts) == 4
    assert max(lengths) < 1.2 * min(lengths)


def test_multi_area_path_over_a_u_and_a_square() -> None:
    square = np.array([[400.0, 0.0], [500.0, 0.0], [500.0, 100.0], [400.0, 100.0]])
    path = multi_coverage_path([U_SHAPE, square], 10.0)
    alone = coverage_length(U_SHAPE, 10.0) + coverage_length(square, 10.0)
    assert path_length(path) > alone
    assert path[0] == pytest.approx(coverage_path(U_SHAPE, 10.0)[0])
    assert covered_fraction(path, Polygon(U_SHAPE).union(Polygon(square)), 10.0) > 0.99


def test_a_convex_case_is_unchanged() -> None:
    rect = np.array([[0.0, 0.0], [1000.0, 0.0], [1000.0, 200.0], [0.0, 200.0]])
    poly = rotate(rect, 30.0)
    lanes = sweep_lanes(poly, 40.0)
    assert len(lanes) == 5
    assert len(sweep_cells(poly, 40.0)) == 1
    path = coverage_path(poly, 40.0)
    assert len(path) == 10  # five lanes, flown alternately, joined at their ends
    assert path[2] == pytest.approx(lanes[1][1])
    assert path_length(path) == pytest.approx(5 * 1000.0 + 4 * 40.0)
    assert path_length(path) == pytest.approx(coverage_estimate(poly, 40.0))


def test_a_lane_along_an_inner_edge_is_one_segment() -> None:
    # 7 strips of 200/7 m: the fourth lane runs exactly along the bottom of the gap (y = 100).
    lanes = sweep_lanes(U_SHAPE, 33.0, along=np.array([1.0, 0.0]))
    on_edge = lanes[np.isclose(lanes[:, 0, 1], 100.0)]
    assert len(on_edge) == 1
    assert np.hypot(*(on_edge[0, 1] - on_edge[0, 0])) == pytest.approx(300.0)


# --------------------------------------------------------------------------- sweep direction


def test_the_u_is_swept_along_its_arms_in_one_cell() -> None:
    # Lanes north-south run along the arms: one cell, no transition over the gap, shorter than
    # the long axis (east-west) even with 50 % more lanes. Not at 7 m: 43 lanes spread evenly
    # over the 300 m put none within reach of the 2.3 m next to each arm's inner edge, and the
    # lanes that strip needs (``_gap_lanes``) make north-south longer than east-west there.
    for width in [w for w in WIDTHS if w != 7.0]:
        along = sweep_direction(U_SHAPE, width)
        assert abs(float(along[1])) == pytest.approx(1.0)
        assert len(sweep_cells(U_SHAPE, width)) == 1
        assert coverage_length(U_SHAPE, width) < coverage_length(
            U_SHAPE, width, along=np.array([1.0, 0.0])
        )


def test_a_strip_along_an_arm_that_the_even_lanes_miss_gets_a_lane() -> None:
    # North-south at 7 m: lanes 6.98 m apart, the two next to the gap's edges 2.3 m beyond a
    # lane's reach from it (a 2.3 m x 100 m strip along each arm, unseen without a lane of its own).
    north = np.array([0.0, 1.0])
    shape = Polygon(U_SHAPE)
    path = coverage_path(U_SHAPE, 7.0, along=north)
    assert covered_fraction(path, shape, 7.0) > 0.999
    strips = [shapely.box(98.0, 100.0, 100.0, 200.0), shapely.box(200.0, 100.0, 202.0, 200.0)]
    seen = footprint(path, 7.0)
    for strip in strips:
        assert seen.intersection(strip).area == pytest.approx(strip.area, rel=1e-6)
    assert coverage_length(U_SHAPE, 7.0) <= coverage_length(U_SHAPE, 7.0, along=north)


def test_candidates_are_the_rectangle_axes_and_the_edge_directions() -> None:
    poly = rotate(U_SHAPE, 23.0)
    candidates = candidate_directions(poly)
    assert np.allclose(np.hypot(*candidates.T), 1.0)
    # the long axis first; the U's edges have only two directions, the rectangle's axes
    assert candidates[0] == pytest.approx(sweep_axes(poly)[0])
    assert len(candidates) == 2
    tri = np.array([[0.0, 0.0], [100.0, 0.0], [30.0, 80.0]])
    assert len(candidate_directions(tri)) >= 3


@pytest.mark.parametrize("seed", range(6))
def test_the_chosen_sweep_is_the_shortest_candidate_covers_and_stays_inside(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = 20
    angles = np.sort(rng.uniform(0.0, 2.0 * np.pi, n))
    radii = rng.uniform(150.0, 400.0, n)
    poly = np.column_stack([radii * np.cos(angles), radii * np.sin(angles)])
    shape = Polygon(poly)
    assert shape.is_valid
    width = 20.0
    chosen = coverage_length(poly, width)
    every = [coverage_length(poly, width, along=v) for v in candidate_directions(poly)]
    assert chosen == pytest.approx(min(every), rel=1e-9)
    lanes = sweep_lanes(poly, width)
    assert shapely.within(shapely.linestrings(lanes), shape.buffer(1e-6)).all()
    assert covered_fraction(coverage_path(poly, width), shape, width) > 0.99
