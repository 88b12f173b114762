"""Every unit's bid tables in one array, while they are small (the general auction's fast path).

The general auction rebids waiting tasks on every unit whose route or times changed: a task may go
at any position from the first one after what starts before it can be activated, at the cheapest
of those (the suffix minima of the unit's insertion table). Unit by unit that is a handful of
numpy calls per unit and round, which on 10 units x 20 tasks cost more than the arithmetic; with
the tables stacked (units x positions x tasks) and the routes as a padded index matrix it is a
few calls for all units at once, and gives the same numbers. Above ``STACK_LIMIT`` entries the
auction keeps to the unit-by-unit tables (memory grows with the longest route).
"""

from __future__ import annotations

import numpy as np

#: Most units x positions x tasks entries kept stacked (two arrays of 8 bytes an entry).
STACK_LIMIT = 300_000


class StackedTables:
    """Per unit: the suffix minima of its insertion table and where they are (rows: route
    positions, padded with inf / 0), and its route as task indices (padded with ``n_tasks``)."""

    def __init__(self, n_units: int, n_tasks: int) -> None:
        self.n_units, self.n_tasks = n_units, n_tasks
        self.low = np.full((n_units, 2, n_tasks), np.inf)
        self.arg = np.zeros((n_units, 2, n_tasks), dtype=int)
        self.route = np.full((n_units, 2), n_tasks, dtype=int)
        self.length = np.zeros(n_units, dtype=int)

    @staticmethod
    def fits(n_units: int, n_tasks: int, rows: int = 2) -> bool:
        return n_units * rows * n_tasks <= STACK_LIMIT

    def set(self, u: int, low: np.ndarray, arg: np.ndarray) -> bool:
        """Unit ``u``'s new tables; False when they no longer fit (drop the stack then)."""
        rows = low.shape[0]
        if rows > self.low.shape[1]:
            grown = 2 * rows
            if not self.fits(self.n_units, self.n_tasks, grown):
                return False
            extra = grown - self.low.shape[1]
            self.low = np.concatenate(
                [self.low, np.full((self.n_units, extra, self.n_tasks), np.inf)], axis=1)
            self.arg = np.concatenate(
                [self.arg, np.zeros((self.n_units, extra, self.n_tasks), dtype=int)], axis=1)
        self.low[u, :rows] = low
        self.low[u, rows:] = np.inf
        self.arg[u, :rows] = arg
        self.arg[u, rows:] = 0
        return True

    def insert(self, u: int, spot: int, t: int) -> None:
        """Task ``t`` joins unit ``u``'s route at ``spot``."""
        n = int(self.length[u])
        if n + 1 > self.route.shape[1]:
            pad = np.full((self.n_units, self.route.shape[1]), self.n_tasks, dtype=int)
            self.route = np.concatenate([self.route, pad], axis=1)
        self.route[u, spot + 1 : n + 1] = self.route[u, spot:n].copy()
        self.route[u, spot] = t
        self.length[u] = n + 1

    def lookup(
        self, us: np.ndarray, cs: np.ndarray, earliest: np.ndarray, start: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For pairs (unit ``us[i]``, task ``cs[i]``): the first position after the unit's
        tasks that start before ``earliest[cs[i]]`` (``np.searchsorted`` on the route's start
        times, which a unit's order keeps ascending), the cheapest cost from there and its row."""
        starts = np.append(start, np.inf)[self.route[us]]
        lo = (starts < earliest[cs][:, None]).sum(axis=1)
        return lo, self.low[us, lo, cs], self.arg[us, lo, cs]
