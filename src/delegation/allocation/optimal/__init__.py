"""The ``optimal`` strategy: OR-Tools, warm-started from the auction, under a time limit.

Which solver:
- the **routing solver** for larger trees where every task is activated at mission start (a
  ``conc`` of tasks: an mTSP with per-unit speeds, capabilities, aliases, homes and battery);
  guided local search from the auction's routes, then ``minmax`` (a local search of its own for
  the longest route, or the total, restarting from sweeps), also on the second core; it proves
  no bound;
- **CP-SAT** where the tree orders tasks across units (``seq``) or has conc children that are
  subtrees, and for small flat trees (it proves optimality there, so the plan carries a ``bound``):
  per-unit circuits over optional arcs, activation times from the tree, makespan and battery as
  linear constraints: the precedence graph (the tree's order plus each unit's), what every
  strategy plans for (docs/protocol.md §8), so its bound is a lower bound for any tree sent. Only
  for a problem with ``wrap_subtrees`` (the old rule, for benchmarks) does it add the whole-subtree
  serialisation sub-model (``cpsat_subtrees``);
- a **large neighbourhood search** (``lns``: ruin and recreate on the precedence-graph schedule,
  judged on the makespan of the tree it would be sent as) for trees that are not plain and have
  more than ``CP_MAX_FLAT_TASKS`` vehicle tasks: after CP-SAT (half the time) up to
  ``CP_SEARCH_TASKS`` tasks, alone above; with a second core, a helper process runs another
  search (another seed) and the better is kept; it proves no bound.

Solver costs are integers (ticks); durations are rounded down so that CP-SAT's bound stays a proven
lower bound. Whatever the solver returns is re-evaluated with the schedule simulator, and the
auction's schedule is kept (and said so in a note and a log line) when the solver found nothing
better: ``optimal`` is never worse than ``auction``.

The second core is used only when a composition root hands ``parallel.use_second_core`` a
launcher (``runtime.second_core.launch``); allocation starts no process by itself.

Modules: ``routing`` (the routing model), ``minmax`` (its local search), ``cpsat`` (the CP-SAT
model), ``cpsat_subtrees`` (its subtree-serialisation sub-model), ``lns`` (the search),
``parallel`` with ``helper`` (the second core), ``shared`` (ticks, task points, evaluating
routes); this one chooses the solver.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

from delegation.allocation.auction import auction
from delegation.allocation.optimal.cpsat import CP_EXACT_ARCS, candidates, solve_cpsat
from delegation.allocation.optimal.cpsat_subtrees import CP_EXACT_CHILDREN
from delegation.allocation.optimal.lns import lns, tree_key
from delegation.allocation.optimal.parallel import HelperLns, second_core
from delegation.allocation.optimal.routing import (
    ROUTING_MAKESPAN_PHASES,
    ROUTING_MAX_ENTRIES,
    solve_routing,
)
from delegation.allocation.optimal.shared import TICKS
from delegation.allocation.problem import Problem
from delegation.allocation.schedule import Schedule, better, evaluate
from delegation.allocation.schedule import better_key as _better_key
from delegation.allocation.strategies import Objective

log = logging.getLogger(__name__)

#: Flat trees with at most this many vehicle tasks go to CP-SAT (which proves optimality).
CP_MAX_FLAT_TASKS = 12
#: CP-SAT is not tried when even the pruned circuits would have more arcs than this (the pruning
#: starts above ``CP_EXACT_ARCS``).
CP_MAX_ARCS = 40_000

__all__ = [
    "CP_EXACT_ARCS",
    "CP_EXACT_CHILDREN",
    "CP_MAX_ARCS",
    "CP_MAX_FLAT_TASKS",
    "ROUTING_MAKESPAN_PHASES",
    "ROUTING_MAX_ENTRIES",
    "TICKS",
    "OptimalResult",
    "optimise",
]


#: The search stops at this share of the time limit: the plan's instantiation follows it.
LNS_SHARE = 0.9
#: The search's helper process (second core) is started when a round of the search has this
#: long (s) at least: it needs about 0.5 s to start and load its modules.
LNS_HELPER_MIN_SECONDS = 1.5
#: Rounds of the search on two cores (each: both search, the better result is where both go on).
#: Measured (``benchmarks/optimal_mixed.py 10``, load average 3-5): 2 rounds 0.44 x the old-rule
#: auction, 1 round 0.41 x; within the noise of a loaded machine, so the simpler one.
LNS_EPOCHS = 1
#: The helper stops this share of the time limit (plus 0.1 s) before this process's search: it
#: still has to send its answer, which is then evaluated here, and on a loaded machine it starts
#: late and runs slower ...
LNS_HELPER_MARGIN = 0.05
#: ... and its answer is waited for until this share of the time limit after the search's
#: deadline at most.
LNS_HELPER_WAIT = 0.03
#: Trees that are not plain with more vehicle tasks than this skip CP-SAT for the search (measured:
#: CP-SAT found no solution in 2.5-5 s on any generated mixed tree from 10x30 to 50x300).
CP_SEARCH_TASKS = 20


@dataclass
class OptimalResult:
    """The chosen schedule, a proven lower bound on the objective (s) if any, and what happened."""

    schedule: Schedule
    bound: float | None = None
    notes: list[str] = field(default_factory=list)
    solver: str = ""
    kept_auction: bool = True  # the schedule is the auction's (reported as a fallback)


def optimise(
    problem: Problem,
    objective: Objective | str = Objective.MAKESPAN,
    time_limit: float = 5.0,
    *,
    use_all_units: bool = False,
) -> OptimalResult:
    """Plan with OR-Tools within ``time_limit`` seconds; never worse than the auction.

    ``use_all_units`` (benchmarks only: the published mTSP min-sum values require it) makes every
    unit take at least one task; the auction's plan then counts only if it does so too.
    ``ValueError`` for an unknown objective.
    """
    began = time.perf_counter()
    objective = Objective(objective)
    base = auction(problem, objective)
    tasks = [t for t in range(problem.n_tasks) if problem.tasks[t].vehicle and base.assign[t] >= 0]
    result = OptimalResult(base)
    if not tasks:
        result.notes.append("no vehicle task to optimise; the auction's plan is optimal")
        log.info("optimal: %s", result.notes[-1])
        return result
    flat = problem.plain  # routing models a unit's own route only: exact for plain trees
    mask = candidates(problem, tasks, base)
    arcs = sum(int(mask[u, tasks].sum()) ** 2 for u in range(problem.n_units))
    remaining = max(0.05, time_limit - (time.perf_counter() - began))
    candidate: Schedule | None = None
    bound: float | None = None
    # Trees that are not plain and not tiny: CP-SAT gets half the time, the large neighbourhood
    # search the rest (``lns``); above ``CP_SEARCH_TASKS`` tasks the search gets it all.
    search = not flat and not use_all_units and len(tasks) > CP_MAX_FLAT_TASKS
    if search and len(tasks) > CP_SEARCH_TASKS:
        note = (f"CP-SAT not run: {len(tasks)} vehicle tasks on a tree that is not plain "
                f"(limit {CP_SEARCH_TASKS}); the large neighbourhood search alone")
    elif (not flat or len(tasks) <= CP_MAX_FLAT_TASKS) and arcs <= CP_MAX_ARCS:
        result.solver = "cp-sat"
        candidate, bound, note = solve_cpsat(
            problem, objective, base, tasks, remaining * (0.5 if search else 1.0), mask,
            use_all_units=use_all_units,
        )
    elif flat:
        result.solver = "routing"
        candidate, note = solve_routing(
            problem, objective, base, tasks, remaining, use_all_units=use_all_units
        )
    else:
        note = (
            f"CP-SAT not run: the model would have {arcs} arcs (limit {CP_MAX_ARCS}); "
            + ("the large neighbourhood search alone" if search else "keeping the auction's plan")
        )
    result.notes.append(note)
    base_counts = not use_all_units or all(base.orders)
    if candidate is not None and candidate.valid and (
        better(candidate, base, objective) or not base_counts
    ):
        result.schedule = candidate
        result.kept_auction = False
    elif candidate is not None:
        result.notes.append(
            f"{result.solver} found no better plan than the auction's; keeping the auction's plan"
        )
    result.bound = bound
    if search:
        _search(problem, objective, result, base, began + LNS_SHARE * time_limit, time_limit)
    for text in result.notes:
        log.info("optimal: %s", text)
    return result


def _search(
    problem: Problem, objective: Objective, result: OptimalResult, base: Schedule,
    deadline: float, limit: float,
) -> None:
    """Improve the better (judged on the tree it would be sent as) of ``result``'s schedule and
    the auction's ``base`` with the large neighbourhood search until ``deadline``.

    With a second core, in ``LNS_EPOCHS`` rounds: a helper process runs another search (another
    seed) from the same start while this one searches, and both go on from the better of the two
    (so the slower search's work is not lost)."""
    start = result.schedule
    if not start.valid or (start is not base and _better_key(
            tree_key(problem, objective, base), tree_key(problem, objective, start))):
        if start is not base:
            result.notes.append("the auction's plan gives the shorter tree; searching from it")
        start = base
    now = time.perf_counter()
    if now >= deadline or not start.valid:
        return
    epochs = max(1, min(LNS_EPOCHS, int((deadline - now) / LNS_HELPER_MIN_SECONDS)))
    if not second_core():
        epochs = 1
    best, first_value = start, tree_key(problem, objective, start)[1]
    mine, theirs = _Tally(), _Tally()
    for epoch in range(epochs):
        now = time.perf_counter()
        end = now + (deadline - now) / (epochs - epoch)
        helper = None
        if end - now >= LNS_HELPER_MIN_SECONDS:
            seconds = end - now - LNS_HELPER_MARGIN * limit - 0.1
            helper = HelperLns.start(problem, objective, best, seconds, seed=2 * epoch + 1)
        found = lns(problem, objective, best, end, seed=2 * epoch)
        mine.add(found.iterations, found.improvements, found.schedule is not best)
        best = found.schedule
        if helper is None:
            continue
        answer = helper.result(end + LNS_HELPER_WAIT * limit - time.perf_counter())
        if isinstance(answer, str):
            theirs.failures.append(answer)
            log.warning("optimal: large neighbourhood search on the second core: %s", answer)
            continue
        other = evaluate(problem, answer.assign, answer.orders)
        kept = other.valid and _better_key(tree_key(problem, objective, other),
                                           tree_key(problem, objective, best))
        theirs.add(answer.iterations, answer.improvements, kept)
        if kept:
            best = other
    value = tree_key(problem, objective, best)[1]
    change = (value - first_value) / first_value * 100 if first_value > 0 else 0.0
    result.notes.append(
        f"large neighbourhood search: {mine.iterations} iterations, {mine.improvements} "
        f"improvements, {objective.value} {first_value:.1f} -> {value:.1f} ({change:+.1f} %)"
        + (f", {epochs} rounds" if epochs > 1 else ""))
    if theirs.rounds or theirs.failures:
        result.notes.append(
            f"large neighbourhood search on the second core (another seed): "
            f"{theirs.iterations} iterations, {theirs.improvements} improvements, "
            f"better in {theirs.better} of {theirs.rounds} rounds"
            + "".join(f"; {failure}" for failure in theirs.failures))
    result.schedule = best
    result.kept_auction = best is base
    if best is not start:
        result.solver = f"{result.solver} + lns" if result.solver else "lns"


@dataclass
class _Tally:
    """One core's search over the rounds, for the notes."""

    iterations: int = 0
    improvements: int = 0
    rounds: int = 0
    better: int = 0  # rounds whose result was kept
    failures: list[str] = field(default_factory=list)

    def add(self, iterations: int, improvements: int, better: bool) -> None:
        self.iterations += iterations
        self.improvements += improvements
        self.rounds += 1
        self.better += better
