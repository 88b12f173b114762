"""The water filling of DESIGN 3.11 solved exactly (``sharing.fill_time``) and the cut that
finds its area by regula falsi (``sharing.cut``): checked against the equation itself.

Pure arithmetic and geometry: no clock, no network.
"""

from __future__ import annotations

import math
import random

import numpy as np
import pytest
from shapely.geometry import Polygon

from delegation.allocation.sharing import Sharer, cut, fill_time, region_of


def swept(t: float, sharers: list[Sharer]) -> float:
    """The left side of the equation: what the sharers have swept by ``t``."""
    return sum(min(s.cap, s.rate * max(0.0, t - s.arrive)) for s in sharers)


def random_sharers(rng: random.Random) -> list[Sharer]:
    return [Sharer(k, rng.choice([0.0, rng.uniform(0.0, 2000.0)]),
                   rng.choice([0.0, rng.uniform(1.0, 300.0), rng.uniform(1.0, 300.0)]),
                   rng.choice([math.inf, 0.0, rng.uniform(0.0, 6e5), rng.uniform(0.0, 6e5)]))
            for k in range(rng.randint(1, 9))]


@pytest.mark.parametrize("seed", range(4))
def test_fill_time_solves_the_equation_and_is_the_first_such_time(seed: int) -> None:
    rng = random.Random(seed)
    for _ in range(500):
        sharers = random_sharers(rng)
        area = rng.uniform(1.0, 1.5e6)
        t = fill_time(area, sharers)
        reachable = sum(s.cap for s in sharers if s.rate > 0.0)
        if reachable < area:
            assert t == math.inf
            continue
        assert math.isfinite(t)
        assert swept(t, sharers) == pytest.approx(area, rel=1e-9)
        assert swept(t * (1.0 - 1e-6) - 1e-6, sharers) < area  # (not later than needed)


def test_fill_time_edge_cases() -> None:
    assert fill_time(100.0, []) == math.inf
    assert fill_time(0.0, [Sharer(0, 7.0, 1.0), Sharer(1, 3.0, 1.0)]) == 3.0
    # Capped units' rates cancel out exactly where the uncapped one goes on alone.
    sharers = [Sharer(0, 0.0, 10.0, 100.0), Sharer(1, 0.0, 0.1)]
    assert fill_time(200.0, sharers) == pytest.approx(10.0 + 100.0 / 0.1 * (1 - 1.0 / 100.0))
    assert swept(fill_time(200.0, sharers), sharers) == pytest.approx(200.0)
    # Caps exactly enough: the time the last cap is swept.
    assert fill_time(300.0, [Sharer(0, 0.0, 10.0, 100.0), Sharer(1, 5.0, 20.0, 200.0)]) == \
        pytest.approx(15.0)
    # Units that sweep nothing (rate 0) or may sweep nothing (cap 0) do not count.
    assert fill_time(10.0, [Sharer(0, 0.0, 0.0), Sharer(1, 0.0, 5.0, 0.0)]) == math.inf


@pytest.mark.parametrize("fraction", [0.04, 0.3, 0.5, 0.77, 0.96])
def test_a_cut_holds_its_fraction_of_a_concave_area(fraction: float) -> None:
    comb = 200.0 * np.array([[0, 0], [5, 0], [5, 3], [4, 3], [4, 1], [3, 1], [3, 3], [2, 3],
                             [2, 1], [1, 1], [1, 3], [0, 3]], dtype=float)
    region = region_of([comb])
    for axis in (np.array([1.0, 0.0]), np.array([0.6, 0.8])):
        near, far = cut(region, axis, fraction)
        assert near.area == pytest.approx(fraction * region.area, rel=1e-5)
        assert near.area + far.area == pytest.approx(region.area, rel=1e-9)
        assert near.intersection(far).area <= 1e-6 * region.area
        assert Polygon(comb).buffer(1e-6).contains(near.union(far))
