"""A local search of its own for the longest route (min-max), on top of the routing solver.

(With ``MinMaxModel.total`` the same search minimises the total instead: min-sum.)

The routing solver's guided local search penalises arcs, not the longest route, so on min-max it
stalls a few per cent above the best known. This search works on the same transit matrices (per
unit: ticks from node i to node j, the routing model's node numbering) and improves the sorted
route lengths, longest first (so a tie for the longest still makes progress):

- moves between the longest route and each other one: relocate a task, swap two tasks, exchange
  the two routes' tails (2-opt*); then 2-opt within the routes that changed;
- when no move helps (a local optimum), an iterated local search: remove some tasks (nearby ones,
  a stretch of the longest route, or random ones) and reinsert each where it raises the longest
  route least, descend again, keep the result when it is at most a shrinking threshold worse
  than the current one (else go back to the run's best with some probability);
- restarts: when a run stops making progress, the next starts from a sweep (the tasks by angle
  around the units' starts, one sector per unit) at a random angle.

Every move respects the units' capabilities, battery (route time against capacity) and keeps
tasks that share an alias (and so must share a unit) on their unit. Pure and deterministic for a
given seed and number of iterations; the time limit only stops it sooner.
"""

from __future__ import annotations

import random
import time
from dataclasses import dataclass, field

import numpy as np

#: Tasks removed by one perturbation of the iterated local search, as a share of all tasks: a
#: random share between these two.
RUIN_MIN = 0.08
RUIN_MAX = 0.3
#: Half of the perturbations reinsert with each place's cost times a random factor in
#: [1 - NOISE, 1 + NOISE].
NOISE = 0.2
#: Probability of going back to the best solution after a perturbation that made things worse.
RESTART_PROBABILITY = 0.1
#: Threshold acceptance: at first a perturbation may lengthen the longest route by this share.
THRESHOLD = 0.01
#: A run of the iterated local search ends after this many perturbations per task (at least
#: ``STALL_MIN``) that did not shorten its longest route.
STALL_PER_TASK = 3
STALL_MIN = 100
#: Moves one descent makes at most (each strictly improves, so this only guards against slow
#: convergence on huge instances).
MAX_MOVES = 100_000

#: What a move finder returns: per (i, j) the two routes' new lengths, and where not allowed.
_Moves = tuple[np.ndarray, np.ndarray, np.ndarray]


@dataclass
class RouteSet:
    """Routes (task node lists per unit) and their lengths in ticks."""

    routes: list[list[int]]
    lengths: np.ndarray
    rounds: int = 0  # perturbations the search made to find these (for notes)
    restarts: int = 0  # runs it began after the first (for notes)
    total: bool = False  # judged on the total first (min-sum), else on the longest route

    def key(self) -> tuple[float, float]:
        """The longest route, then the total (``total``: the other way): smaller is better."""
        longest, total = float(self.lengths.max()), float(self.lengths.sum())
        return (total, longest) if self.total else (longest, total)

    def copy(self) -> RouteSet:
        return RouteSet([list(r) for r in self.routes], self.lengths.copy(), total=self.total)


@dataclass
class MinMaxModel:
    """What the search needs: per unit its matrix, start and end node, capacity; which units may
    take each task, and the tasks that must stay on their unit."""

    matrices: list[np.ndarray]  # per unit (size, size) ticks, float64
    starts: list[int]
    ends: list[int]
    capacity: np.ndarray  # (U,) ticks
    allowed: np.ndarray  # (U, n) bool: unit u may take task node k
    pinned: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))  # (n,)
    #: (n,) each task's angle around the units' starts (radians), for sweep starts; empty: none
    angle: np.ndarray = field(default_factory=lambda: np.zeros(0))
    #: Minimise the total (min-sum) instead of the longest route.
    total: bool = False
    #: Every unit keeps at least one task (the published min-sum values require it).
    every_unit: bool = False

    @property
    def n_units(self) -> int:
        return len(self.starts)

    def length(self, u: int, route: list[int]) -> float:
        seq = [self.starts[u], *route, self.ends[u]]
        m = self.matrices[u]
        return float(m[seq[:-1], seq[1:]].sum())

    def route_set(self, routes: list[list[int]]) -> RouteSet:
        return RouteSet([list(r) for r in routes],
                        np.array([self.length(u, r) for u, r in enumerate(routes)], dtype=float),
                        total=self.total)


def minmax_search(
    model: MinMaxModel, routes: list[list[int]], deadline: float, seed: int = 0,
    max_rounds: int | None = None, sweep_first: bool = False,
) -> RouteSet:
    """The best routes found from ``routes`` before ``deadline`` (``time.perf_counter``) or
    after ``max_rounds`` perturbations; never worse than ``routes`` (by ``RouteSet.key``; with
    ``model.every_unit``, routes leaving a unit idle are worse than any that do not).

    Runs of the iterated local search: the first from ``routes``, each next one (after
    ``stall_rounds`` perturbations without a shorter longest route) from a sweep of the tasks
    around the units' starts cut into one sector per unit, at a random angle (``model.angle``;
    without it, from the best so far). Measured on berlin52 with 3 units: every run from the
    auction's routes ends at +1.4 %, half of the runs from sweeps at the best known.
    ``sweep_first``: the first run too starts from a sweep (a portfolio's second search: the
    first explores the basin of ``routes``)."""
    search = _Search(model, deadline, seed)
    began = time.perf_counter()
    span = max(deadline - began, 1e-9)
    current = model.route_set(routes)
    search.descend(current)
    best = current.copy()
    if sweep_first:
        current = search.restart(best)
        if search.rank(current) < search.rank(best):
            best = current.copy()
    run_best = current.copy()
    rounds = stalled = restarts = 0
    stall = stall_rounds(sum(len(r) for r in routes))
    while not search.out_of_time() and (max_rounds is None or rounds < max_rounds):
        if stalled >= stall:
            current = search.restart(best)
            run_best, stalled = current.copy(), 0
            restarts += 1
            continue
        rounds += 1
        stalled += 1
        trial = current.copy()
        if not search.perturb(trial):
            break
        search.descend(trial)
        if search.rank(trial) < search.rank(best):
            best = trial.copy()
        if search.rank(trial)[:2] < (search.rank(run_best)[0], run_best.key()[0] - search.eps):
            run_best, stalled = trial.copy(), 0
        # Threshold acceptance: a slightly longer longest route is accepted early on (to leave
        # a basin), less and less towards the deadline.
        left = max(0.0, 1.0 - (time.perf_counter() - began) / span)
        idle = search.rank(trial)[0] - search.rank(current)[0]  # -1: trial leaves no unit idle
        within = trial.key()[0] <= current.key()[0] * (1.0 + THRESHOLD * left) and (
            trial.key() <= current.key() or left > 0.0
        )
        if idle < 0 or (idle == 0 and within):
            current = trial
        elif search.rng.random() < RESTART_PROBABILITY:
            current = run_best.copy()
    best.rounds, best.restarts = rounds, restarts
    return best


def stall_rounds(n_tasks: int) -> int:
    """Perturbations without progress after which a run ends (measured: runs on 50-100 tasks
    find their last improvement within about 4 per task, mostly far sooner; on a loaded
    machine more, shorter runs do better)."""
    return max(STALL_MIN, STALL_PER_TASK * n_tasks)


class _Search:
    """The moves; ``eps`` keeps float noise from counting as an improvement."""

    def __init__(self, model: MinMaxModel, deadline: float, seed: int) -> None:
        self.m = model
        self.deadline = deadline
        self.rng = random.Random(seed)
        n = model.allowed.shape[1]
        self.movable = ~model.pinned if model.pinned.size else np.ones(n, dtype=bool)
        self.eps = 1e-6
        self.checks = 0

    def _uniform(self, n: int) -> np.ndarray:
        return np.array([self.rng.random() for _ in range(n)])

    def rank(self, rs: RouteSet) -> tuple[int, float, float]:
        """``rs.key()`` behind whether it leaves a unit idle that must not be (1) or not (0)."""
        idle = int(self.m.every_unit and not all(rs.routes))
        return (idle, *rs.key())

    def out_of_time(self) -> bool:
        return time.perf_counter() >= self.deadline

    # ------------------------------------------------------------------ descent

    def descend(self, rs: RouteSet) -> None:
        """Shorten the longest route, then the total (min-sum: the total alone), until no move
        helps (or time is up)."""
        for u in range(self.m.n_units):
            if self.out_of_time():
                return
            self.two_opt(rs, u)
        for _ in range(MAX_MOVES):
            if self.out_of_time():
                return
            r = int(np.argmax(rs.lengths))
            if (self.m.total or not self._improve_longest(rs, r)) and not self.improve_total(rs):
                return

    def _improve_longest(self, rs: RouteSet, r: int) -> bool:
        """The move between route ``r`` (a longest) and another that leaves the two shorter
        than ``r`` was and the longer of them shortest: True if one was made."""
        top = rs.lengths[r]
        best: tuple[float, float, int, str, tuple[int, int]] | None = None
        for v in range(self.m.n_units):
            if v == r:
                continue
            for kind, moves in self._moves(rs, r, v):
                new_r, new_v, bad = moves
                pair = np.where(bad, np.inf, np.maximum(new_r, new_v))
                i, j = np.unravel_index(int(np.argmin(pair)), pair.shape)
                key = (float(pair[i, j]), float(new_r[i, j] + new_v[i, j]))
                if key[0] < top - self.eps and (best is None or key < best[:2]):
                    best = (*key, v, kind, (int(i), int(j)))
        if best is None:
            return False
        _, _, v, kind, args = best
        self._apply(rs, r, v, kind, args)
        return True

    def improve_total(self, rs: RouteSet) -> bool:
        """The move between any two routes that shortens them most in sum without either
        becoming the longest (min-sum: whatever their lengths): True if one was made."""
        top = np.inf if self.m.total else float(rs.lengths.max())
        best: tuple[float, int, int, str, tuple[int, int]] | None = None
        for r in range(self.m.n_units):
            if self.out_of_time():
                break
            for v in range(self.m.n_units):
                if v == r:
                    continue
                # swap and 2-opt* are symmetric: once per pair; relocating goes both ways
                for kind, moves in self._moves(rs, r, v, relocate_only=v < r):
                    new_r, new_v, bad = moves
                    gain = new_r + new_v - rs.lengths[r] - rs.lengths[v]
                    gain = np.where(bad | (np.maximum(new_r, new_v) > top - self.eps), np.inf,
                                    gain)
                    i, j = np.unravel_index(int(np.argmin(gain)), gain.shape)
                    if gain[i, j] < -self.eps and (best is None or gain[i, j] < best[0]):
                        best = (float(gain[i, j]), r, v, kind, (int(i), int(j)))
        if best is None:
            return False
        _, r, v, kind, args = best
        self._apply(rs, r, v, kind, args)
        return True

    def _moves(
        self, rs: RouteSet, r: int, v: int, relocate_only: bool = False
    ) -> list[tuple[str, _Moves]]:
        out = []
        finders = (("relocate", self._relocate), ("swap", self._swap), ("cross", self._cross))
        for kind, finder in finders[:1] if relocate_only else finders:
            found = finder(rs, r, v)
            if found is not None:
                out.append((kind, found))
        return out

    def _seq(self, u: int, route: list[int]) -> np.ndarray:
        return np.array([self.m.starts[u], *route, self.m.ends[u]], dtype=int)

    def _relocate(
        self, rs: RouteSet, r: int, v: int
    ) -> _Moves | None:
        """Move a task of ``r`` to its best position in ``v``."""
        route = rs.routes[r]
        if not route or (self.m.every_unit and len(route) == 1):
            return None
        sr, sv = self._seq(r, route), self._seq(v, rs.routes[v])
        mr, mv = self.m.matrices[r], self.m.matrices[v]
        tasks = sr[1:-1]
        ok = self.m.allowed[v, tasks] & self.movable[tasks]
        if not ok.any():
            return None
        gain = mr[sr[:-2], tasks] + mr[tasks, sr[2:]] - mr[sr[:-2], sr[2:]]  # (k,)
        new_r = rs.lengths[r] - gain
        add = mv[sv[:-1][None, :], tasks[:, None]] + mv[tasks[:, None], sv[1:][None, :]] \
            - mv[sv[:-1], sv[1:]][None, :]  # (k, m+1)
        new_v = rs.lengths[v] + add
        bad = ~ok[:, None] | (new_v > self.m.capacity[v] + self.eps)
        return np.broadcast_to(new_r[:, None], new_v.shape), new_v, bad

    def _swap(self, rs: RouteSet, r: int, v: int) -> _Moves | None:
        """Exchange a task of ``r`` with one of ``v``, each taking the other's place."""
        if not rs.routes[r] or not rs.routes[v]:
            return None
        sr, sv = self._seq(r, rs.routes[r]), self._seq(v, rs.routes[v])
        mr, mv = self.m.matrices[r], self.m.matrices[v]
        a, b = sr[1:-1], sv[1:-1]
        ok = (self.m.allowed[v, a] & self.movable[a])[:, None] & \
            (self.m.allowed[r, b] & self.movable[b])[None, :]
        if not ok.any():
            return None
        out_r = mr[sr[:-2], a] + mr[a, sr[2:]]  # (k,)
        in_r = mr[sr[:-2][:, None], b[None, :]] + mr[b[None, :], sr[2:][:, None]]  # (k, m)
        out_v = mv[sv[:-2], b] + mv[b, sv[2:]]  # (m,)
        in_v = mv[sv[:-2][None, :], a[:, None]] + mv[a[:, None], sv[2:][None, :]]  # (k, m)
        new_r = rs.lengths[r] - out_r[:, None] + in_r
        new_v = rs.lengths[v] - out_v[None, :] + in_v
        return new_r, new_v, ~ok | self._over(r, new_r) | self._over(v, new_v)

    def _cross(self, rs: RouteSet, r: int, v: int) -> _Moves | None:
        """Exchange tails: r keeps its first i tasks and takes v's from j on, and vice versa."""
        sr, sv = self._seq(r, rs.routes[r]), self._seq(v, rs.routes[v])
        mr, mv = self.m.matrices[r], self.m.matrices[v]
        kr, kv = len(sr) - 2, len(sv) - 2
        # Tasks in a tail change unit: every task of the tail must be allowed on its new unit.
        tail_r_ok = _suffix_all(self.m.allowed[v, sr[1:-1]] & self.movable[sr[1:-1]])  # (kr+1,)
        tail_v_ok = _suffix_all(self.m.allowed[r, sv[1:-1]] & self.movable[sv[1:-1]])  # (kv+1,)
        ok = tail_r_ok[:, None] & tail_v_ok[None, :]
        ok[kr, kv] = False  # no change
        ok[0, 0] = False  # swaps the whole routes: relocating does that where it helps
        if self.m.every_unit:  # r keeps i + (kv - j) tasks, v keeps j + (kr - i)
            i, j = np.arange(kr + 1)[:, None], np.arange(kv + 1)[None, :]
            ok &= (i + kv - j > 0) & (j + kr - i > 0)
        if not ok.any():
            return None
        # head(i): start .. its i-th task; tail(j) with the other unit's matrix and end.
        head_r = _prefix(mr, sr)  # cost from start to the i-th task, i = 0..kr
        head_v = _prefix(mv, sv)
        tail_v_in_r = _suffix_into(mr, sv[1:-1], self.m.ends[r])  # (kv+1,) from task j on
        tail_r_in_v = _suffix_into(mv, sr[1:-1], self.m.ends[v])  # (kr+1,)
        last_r = sr[:-1]  # node before the cut: i = 0 -> start
        last_v = sv[:-1]
        first_v = np.append(sv[1:-1], self.m.ends[r])  # first node of v's tail (or r's end)
        first_r = np.append(sr[1:-1], self.m.ends[v])
        link_r = mr[last_r[:, None], first_v[None, :]]  # (kr+1, kv+1)
        link_v = mv[last_v[None, :], first_r[:, None]]  # (kr+1, kv+1)
        new_r = head_r[:, None] + link_r + tail_v_in_r[None, :]
        new_v = head_v[None, :] + link_v + tail_r_in_v[:, None]
        return new_r, new_v, ~ok | self._over(r, new_r) | self._over(v, new_v)

    def _over(self, u: int, lengths: np.ndarray) -> np.ndarray:
        """Where unit ``u``'s new route lengths exceed its battery."""
        return np.asarray(lengths > self.m.capacity[u] + self.eps)

    def _apply(self, rs: RouteSet, r: int, v: int, kind: str, args: tuple[int, ...]) -> None:
        i, j = args
        route_r, route_v = rs.routes[r], rs.routes[v]
        match kind:
            case "relocate":
                task = route_r.pop(i)
                route_v.insert(j, task)
            case "swap":
                route_r[i], route_v[j] = route_v[j], route_r[i]
            case _:
                rs.routes[r], rs.routes[v] = route_r[:i] + route_v[j:], route_v[:j] + route_r[i:]
        rs.lengths[r] = self.m.length(r, rs.routes[r])
        rs.lengths[v] = self.m.length(v, rs.routes[v])
        self.two_opt(rs, r)
        self.two_opt(rs, v)

    def two_opt(self, rs: RouteSet, u: int) -> None:
        """2-opt and or-opt on route ``u`` until neither shortens it."""
        while self._reverse(rs, u) | self._shift(rs, u):
            pass

    def _shift(self, rs: RouteSet, u: int) -> bool:
        """Move one task of route ``u`` elsewhere in the route while that shortens it."""
        m = self.m.matrices[u]
        moved = False
        while len(rs.routes[u]) >= 2:
            seq = self._seq(u, rs.routes[u])
            a = seq[1:-1]  # task i is seq[i + 1]; edge e joins seq[e] and seq[e + 1]
            gain = m[seq[:-2], a] + m[a, seq[2:]] - m[seq[:-2], seq[2:]]  # (k,)
            add = m[seq[:-1][None, :], a[:, None]] + m[a[:, None], seq[1:][None, :]] \
                - m[seq[:-1], seq[1:]][None, :]  # (k, edges)
            i = np.arange(a.size)[:, None]
            e = np.arange(len(seq) - 1)[None, :]
            delta = np.where((e == i) | (e == i + 1), np.inf, add - gain[:, None])
            bi, be = np.unravel_index(int(np.argmin(delta)), delta.shape)
            if not delta[bi, be] < -self.eps:
                return moved
            route = rs.routes[u]
            task = route.pop(int(bi))
            route.insert(int(be) if be < bi else int(be) - 1, task)
            rs.lengths[u] = self.m.length(u, route)
            moved = True
        return moved

    def _reverse(self, rs: RouteSet, u: int) -> bool:
        """Reverse the best segment of route ``u`` while that shortens it."""
        m = self.m.matrices[u]
        moved = False
        while len(rs.routes[u]) >= 2:
            seq = self._seq(u, rs.routes[u])
            fwd = np.concatenate([[0.0], np.cumsum(m[seq[:-1], seq[1:]])])
            bwd = np.concatenate([[0.0], np.cumsum(m[seq[1:], seq[:-1]])])
            n = len(seq)
            i = np.arange(1, n - 1)[:, None]  # segment seq[i..j], 1 <= i < j <= n-2
            j = np.arange(1, n - 1)[None, :]
            nxt = seq[j + 1]
            before = m[seq[i - 1], seq[i]] + (fwd[j] - fwd[i]) + m[seq[j], nxt]
            after = m[seq[i - 1], seq[j]] + (bwd[j] - bwd[i]) + m[seq[i], nxt]
            delta = np.where(j > i, after - before, np.inf)
            a, b = np.unravel_index(int(np.argmin(delta)), delta.shape)
            if not delta[a, b] < -self.eps:
                return moved
            moved = True
            lo, hi = int(a), int(b)  # task indices in the route: seq index - 1
            route = rs.routes[u]
            route[lo : hi + 1] = route[lo : hi + 1][::-1]
            rs.lengths[u] = self.m.length(u, route)
        return moved

    # ------------------------------------------------------------------ restarts

    def restart(self, best: RouteSet) -> RouteSet:
        """A new run's start: a sweep at a random angle, descended (when it respects every
        battery), else the best so far."""
        routes = self.sweep(best.routes, self.rng.random())
        if routes is not None and (all(routes) or not self.m.every_unit):
            start = self.m.route_set(routes)
            if (start.lengths <= self.m.capacity + self.eps).all():
                self.descend(start)
                return start
        return best.copy()

    def sweep(self, routes: list[list[int]], offset: float) -> list[list[int]] | None:
        """The tasks of ``routes`` by angle from ``offset`` (a share of a turn), cut into one
        sector of equal count per unit; pinned tasks, and tasks the sector's unit may not take,
        stay on their unit in ``routes``. None without angles."""
        if self.m.angle.size == 0:
            return None
        owner = {t: u for u, route in enumerate(routes) for t in route}
        tasks = np.array(sorted(owner), dtype=int)
        if tasks.size == 0:
            return None
        by_angle = tasks[np.argsort(self.m.angle[tasks], kind="stable")]
        by_angle = np.roll(by_angle, -int(offset * by_angle.size))
        out: list[list[int]] = [[] for _ in routes]
        first = self.rng.randrange(len(routes))  # which unit takes the first sector
        for i, sector in enumerate(np.array_split(by_angle, len(routes))):
            u = (first + i) % len(routes)
            for t in sector.tolist():
                keep = bool(self.m.pinned.size and self.m.pinned[t]) or not self.m.allowed[u, t]
                out[owner[t] if keep else u].append(t)
        return out

    # ------------------------------------------------------------------ perturbation

    def perturb(self, rs: RouteSet) -> bool:
        """Remove some tasks and reinsert each where the longest route grows least (then the
        cheapest place, judged with some noise). False when nothing can move.

        Which tasks: a random share between ``RUIN_MIN`` and ``RUIN_MAX`` of them, chosen as the
        tasks nearest a random one (a region changes hands), a stretch of a longest route (its
        work moves elsewhere), or at random (measured: one fixed kind and size of ruin lets every
        seed fall back into the same local optimum, e.g. berlin52 with 3 units at +1.4 %)."""
        assigned = [(u, t) for u, route in enumerate(rs.routes) for t in route if self.movable[t]]
        if not assigned:
            return False
        n_tasks = sum(len(r) for r in rs.routes)
        lo = max(2, round(RUIN_MIN * n_tasks))
        k = min(len(assigned), self.rng.randint(lo, max(lo, round(RUIN_MAX * n_tasks))))
        cands = np.array([t for _, t in assigned], dtype=int)
        kind = self.rng.random()
        if kind < 0.5:
            u0, seed_task = assigned[self.rng.randrange(len(assigned))]
            m0 = self.m.matrices[u0]
            near = cands[np.argsort(m0[seed_task, cands] + m0[cands, seed_task],
                                    kind="stable")][:k]
        elif kind < 0.8:  # min-sum: of a random route
            top = self.rng.randrange(len(rs.routes)) if self.m.total else int(
                np.argmax(rs.lengths))
            route = [t for t in rs.routes[top] if self.movable[t]]
            if not route:
                return False
            size = min(len(route), max(2, k // 2))
            first = self.rng.randrange(len(route) - size + 1)
            near = np.array(route[first:first + size], dtype=int)
        else:
            near = np.array(self.rng.sample(cands.tolist(), k), dtype=int)
        removed = set(near.tolist())
        for u, route in enumerate(rs.routes):
            if any(t in removed for t in route):
                rs.routes[u] = [t for t in route if t not in removed]
                rs.lengths[u] = self.m.length(u, rs.routes[u])
        order = near.tolist()
        self.rng.shuffle(order)
        noise = NOISE if self.rng.random() < 0.5 else 0.0
        for k, t in enumerate(order):
            empty = [u for u, route in enumerate(rs.routes) if not route]
            only = empty if self.m.every_unit and len(order) - k <= len(empty) else None
            self._insert_best(rs, t, noise, only)
        return True

    def _insert_best(
        self, rs: RouteSet, t: int, noise: float = 0.0, only: list[int] | None = None
    ) -> None:
        """Insert task ``t`` (into one of the units ``only`` where one may take it) where the
        longest route grows least (min-sum: not judged), then where it costs least (each cost
        times a random factor in [1 - noise, 1 + noise])."""
        top = float(rs.lengths.max()) if rs.lengths.size else 0.0
        if only is not None and not any(self.m.allowed[u, t] for u in only):
            only = None
        best: tuple[float, float, int, int] | None = None
        for u in range(self.m.n_units) if only is None else only:
            if not self.m.allowed[u, t]:
                continue
            seq = self._seq(u, rs.routes[u])
            m = self.m.matrices[u]
            add = m[seq[:-1], t] + m[t, seq[1:]] - m[seq[:-1], seq[1:]]
            new = rs.lengths[u] + add
            new = np.where(new > self.m.capacity[u] + self.eps, np.inf, new)
            grown = np.where(np.isfinite(new), 0.0, np.inf) if self.m.total else \
                np.maximum(new, top)
            if noise:
                add = add * (1.0 + noise * (2.0 * self._uniform(add.size) - 1.0))
            p = int(np.lexsort((add, grown))[0])  # growth of the longest route, then cost
            key = (float(grown[p]), float(add[p]))
            if np.isfinite(new[p]) and (best is None or key < best[:2]):
                best = (*key, u, p)
        if best is None:  # nowhere fits: back where it is cheapest regardless of battery
            u = int(np.nonzero(self.m.allowed[:, t])[0][0])
            best = (0.0, 0.0, u, 0)
        _, _, u, p = best
        rs.routes[u].insert(p, t)
        rs.lengths[u] = self.m.length(u, rs.routes[u])


def _prefix(m: np.ndarray, seq: np.ndarray) -> np.ndarray:
    """Cost from the start ``seq[0]`` to its i-th task, i = 0 .. len(seq) - 2."""
    return np.concatenate([[0.0], np.cumsum(m[seq[:-2], seq[1:-1]])])


def _suffix_into(m: np.ndarray, tasks: np.ndarray, end: int) -> np.ndarray:
    """Cost from task j of ``tasks`` through the rest to ``end``, j = 0 .. len(tasks) (the last:
    nothing left, 0)."""
    seq = np.append(tasks, end)
    legs = m[seq[:-1], seq[1:]]
    out = np.concatenate([np.cumsum(legs[::-1])[::-1], [0.0]])
    return out


def _suffix_all(flags: np.ndarray) -> np.ndarray:
    """(len + 1,) whether every flag from j on is set (True for the empty tail)."""
    out = np.ones(flags.size + 1, dtype=bool)
    if flags.size:
        out[:-1] = np.flip(np.logical_and.accumulate(np.flip(flags)))
    return out
