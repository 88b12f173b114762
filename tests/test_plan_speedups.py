"""The planner's shortcuts of issue 19 give exactly what the computations they skip give.

Each shortcut is checked against the plain computation on generated inputs (as
``test_auction_speedups`` does for the auction's): the flown sweep of a convex area skips
``transitions_inside`` (every leg between points inside a convex area stays inside); the
precedence matrix is filled one block per ``seq`` instead of one per pair of its children.
"""

from __future__ import annotations

import math
import random

import numpy as np
import pytest

import delegation.coverage as coverage
from allocation_helpers import SHAPES, random_instance
from delegation.allocation.problem import Structure, flatten_tree, precedence
from delegation.coverage import circle_polygon, flown_sweep


def _convex_polygons(seed: int) -> list[np.ndarray]:
    """Rotated rectangles, triangles, regular polygons and circles of many sizes."""
    rng = random.Random(seed)
    out = []
    for _ in range(12):
        cx, cy = rng.uniform(-2000, 2000), rng.uniform(-2000, 2000)
        a = rng.uniform(0, math.pi)
        w, h = rng.uniform(20, 400), rng.uniform(20, 400)
        rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
        rect = np.array([[0, 0], [w, 0], [w, h], [0, h]]) @ rot.T + [cx, cy]
        out.append(rect)
        out.append(np.array([[cx, cy], [cx + w, cy + rng.uniform(-50, 50)], [cx + w / 3, cy + h]]))
        k = rng.randint(5, 9)
        angles = sorted(rng.uniform(0, 2 * math.pi) for _ in range(k))
        r = rng.uniform(30, 300)
        out.append(np.array([[cx + r * math.cos(t), cy + r * math.sin(t)] for t in angles]))
        out.append(circle_polygon((cx, cy), rng.uniform(20, 300)))
    return out


@pytest.mark.parametrize("seed", range(3))
def test_a_convex_areas_flown_sweep_is_its_path_inside(
    seed: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    polygons = _convex_polygons(seed)
    widths = (9.0, 37.0, 80.0)
    fast = [flown_sweep([p], w) for p in polygons for w in widths]
    fast_multi = flown_sweep(polygons[:3], 23.0)
    assert all(coverage._convex_area_of(coverage._clean_polygon(p)) for p in polygons)
    monkeypatch.setattr(coverage, "_convex_area_of", lambda poly: None)
    slow = [flown_sweep([p], w) for p in polygons for w in widths]
    for a, b in zip(fast, slow, strict=True):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(fast_multi, flown_sweep(polygons[:3], 23.0))


def test_a_concave_or_flat_area_is_not_taken_for_convex() -> None:
    u_shape = np.array([[0, 0], [300, 0], [300, 200], [200, 200], [200, 60], [100, 60],
                        [100, 200], [0, 200]], dtype=float)
    assert coverage._convex_area_of(u_shape) is None
    assert coverage._convex_area_of(np.array([[0, 0], [10, 0], [20, 0.0]])) is None
    star = circle_polygon((0, 0), 100, 5)[[0, 2, 4, 1, 3]]  # a pentagram winds twice
    assert coverage._convex_area_of(star) is None


def _precedence_pair_by_pair(structure: Structure, n_tasks: int) -> np.ndarray:
    """``precedence`` as it was written first: one block per pair of a seq's children."""
    before = np.zeros((n_tasks, n_tasks), dtype=bool)
    under: list[list[int]] = [[] for _ in range(structure.size)]
    for n in range(structure.size - 1, -1, -1):
        t = structure.task_of_node[n]
        under[n] = [t] if t >= 0 else [x for c in structure.children[n] for x in under[c]]
    for n in range(structure.size):
        if structure.kinds[n] == "seq":
            seen: list[int] = []
            for c in structure.children[n]:
                if seen and under[c]:
                    before[np.ix_(seen, under[c])] = True
                seen = seen + under[c]
    return before


@pytest.mark.parametrize("shape", SHAPES)
def test_precedence_one_block_per_seq_equals_pair_by_pair(shape: str) -> None:
    for seed in range(8):
        tree, _ = random_instance(seed, shape, n_tasks=25, n_units=3)
        structure, tree_leaves = flatten_tree(tree)
        np.testing.assert_array_equal(precedence(structure, len(tree_leaves)),
                                      _precedence_pair_by_pair(structure, len(tree_leaves)))
