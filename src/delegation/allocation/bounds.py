"""A cheap lower bound on the makespan of any plan (docs/plan.md §3), for reports.

Two bounds, the larger taken:
- chain: a task cannot end before its cheapest unit flies straight to it from where that unit is
  and does its work, nor before its tree predecessors (earlier ``seq`` children) end plus its
  least work;
- load: the vehicle tasks' least work, shared evenly by every unit that can take some task.

Travel between tasks is ignored beyond the first leg, so the bound is far below the optimum on
spread-out missions; it is a floor, not an estimate.
"""

from __future__ import annotations

import numpy as np

from delegation.allocation.problem import Problem


def makespan_lower_bound(problem: Problem) -> float:
    """The larger of the chain and the load bound (s); 0 without tasks or units."""
    n_units, n_tasks = problem.n_units, problem.n_tasks
    if not n_units or not n_tasks:
        return 0.0
    allowed = problem.allowed
    work = np.where(allowed, problem.work_time, np.inf)
    first = np.full((n_units, n_tasks), np.inf)
    vehicle = problem.vehicle
    every = np.arange(n_tasks)
    if problem.to_home is None or not problem.to_home.any():
        # Every unit at once (the same arithmetic; a search starts where the unit's sweep does).
        start, travels = problem.unit_points()[0], problem.travels
        xy = problem.unit_xy
        d = np.hypot(start[..., 0] - xy[:, 0][:, None],
                     start[..., 1] - xy[:, 1][:, None]) * (travels & vehicle)[None, :]
        first[:] = d / problem.speed + problem.work_time
        units: range = range(0)
    else:
        units = range(n_units)
    for u in units:
        start, _, travels = problem.points_for(u, every)
        d = np.hypot(*(start - problem.unit_xy[u]).T) * (travels & vehicle)
        first[u] = d / problem.speed[u] + problem.work_time[u]
    first = np.where(allowed, first, np.inf)
    least_work = work.min(axis=0)
    least_first = first.min(axis=0)
    takeable = np.isfinite(least_work)
    least_work = np.where(takeable, least_work, 0.0)
    least_first = np.where(takeable, least_first, 0.0)
    before = problem.before
    ends = np.zeros(n_tasks)
    for t in range(n_tasks):  # tree order is a linear extension of the seq order
        preds = before[:t, t]
        after = float(ends[:t][preds].max()) + least_work[t] if preds.any() else 0.0
        ends[t] = max(least_first[t], after)
    capable_units = int(allowed.any(axis=1).sum())
    load = float(least_work[vehicle].sum()) / max(1, capable_units)
    return max(float(ends.max()), load)
