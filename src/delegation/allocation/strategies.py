"""The allocation vocabulary: what a plan minimises (``Objective``) and the strategies by name.

``STRATEGIES`` maps a strategy's name to one function with one signature (``StrategyFn``). It is
a registry (docs/strategies.md): the built-ins, then every entry point of the group
``delegation.strategies`` (installed plugins, listed by name and imported only when used), then
``package.module:function`` specs that a command line named (``resolve_strategy``). A name sent
over the network is only looked up, never imported, so a remote client cannot make the service
import a module. The module is light (the strategies are imported when first run), so
command-line parsers can offer the names without loading numpy or OR-Tools.
"""

from __future__ import annotations

import importlib
import logging
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from importlib import metadata
from typing import TYPE_CHECKING, Protocol, cast

if TYPE_CHECKING:
    from delegation.allocation.problem import Problem
    from delegation.allocation.schedule import Schedule

log = logging.getLogger(__name__)

#: The entry point group plugins register their strategies in (pyproject
#: ``[project.entry-points."delegation.strategies"]``).
ENTRY_POINT_GROUP = "delegation.strategies"


class Objective(StrEnum):
    """What a plan minimises; the other measure breaks ties."""

    MAKESPAN = "makespan"  # when the last task ends (units with a home: when back home)
    TOTAL = "total"  # travel + work of all units, ways home included


@dataclass
class StrategyResult:
    """A strategy's schedule, a proven lower bound on the objective (s) if any, and notes on
    what it did."""

    schedule: Schedule
    bound: float | None = None
    notes: list[str] = field(default_factory=list)
    #: The strategy whose plan this is, when this one fell back to it (else None).
    fallback: str | None = None


class StrategyFn(Protocol):
    """A strategy: plan ``problem`` for ``objective`` within ``time_limit`` seconds (a limit
    only the search strategies use). Never raises for infeasibility: tasks no unit can take
    stay unassigned (``assign`` -1)."""

    def __call__(
        self, problem: Problem, objective: Objective, time_limit: float, /
    ) -> StrategyResult: ...


def nearest_strategy(
    problem: Problem, objective: Objective, time_limit: float, /
) -> StrategyResult:
    from delegation.allocation.nearest import nearest

    return StrategyResult(nearest(problem, objective))


def auction_strategy(
    problem: Problem, objective: Objective, time_limit: float, /
) -> StrategyResult:
    from delegation.allocation.auction import auction

    return StrategyResult(auction(problem, objective))


def optimal_strategy(
    problem: Problem, objective: Objective, time_limit: float, /
) -> StrategyResult:
    from delegation.allocation.optimal import optimise

    result = optimise(problem, objective, time_limit)
    return StrategyResult(result.schedule, result.bound, result.notes,
                          "auction" if result.kept_auction else None)


#: The built-in strategies, in the order they are offered (baseline first); pyproject declares
#: the same functions in the entry point group (a test checks they agree).
BUILTIN_STRATEGIES: dict[str, StrategyFn] = {
    "nearest": nearest_strategy,
    "auction": auction_strategy,
    "optimal": optimal_strategy,
}


def _installed_entry_points() -> Iterable[metadata.EntryPoint]:
    return metadata.entry_points(group=ENTRY_POINT_GROUP)


class StrategyRegistry(Mapping[str, StrategyFn]):
    """Strategies by name: built-ins, entry points (loaded on first use), registered specs.

    Listing names imports nothing; looking a name up loads its entry point once. A plugin that
    cannot be imported, or is not callable, raises ``InputError`` naming it when it is used, and
    never breaks the listing. An entry point may not replace a built-in with another function
    (logged and ignored: the built-in names keep their meaning everywhere).
    """

    def __init__(
        self,
        builtins: Mapping[str, StrategyFn],
        entry_points: Callable[[], Iterable[metadata.EntryPoint]] = _installed_entry_points,
    ) -> None:
        self._builtins = dict(builtins)
        self._entry_points = entry_points
        self._found: dict[str, metadata.EntryPoint] | None = None
        self._loaded: dict[str, StrategyFn] = {}
        self._registered: dict[str, StrategyFn] = {}

    def _plugins(self) -> dict[str, metadata.EntryPoint]:
        if self._found is None:
            found: dict[str, metadata.EntryPoint] = {}
            for ep in self._entry_points():
                if ep.name in self._builtins:
                    if ep.value != _spec_of(self._builtins[ep.name]):
                        log.warning("entry point %s = %s ignored: %r is a built-in strategy",
                                    ep.name, ep.value, ep.name)
                    continue
                found.setdefault(ep.name, ep)
            self._found = found
        return self._found

    def __iter__(self) -> Iterator[str]:
        yield from self._builtins
        yield from sorted(self._plugins())
        yield from (n for n in self._registered if n not in self._plugins())

    def __len__(self) -> int:
        return sum(1 for _ in self)

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and (
            name in self._builtins or name in self._registered or name in self._plugins()
        )

    def __getitem__(self, name: str) -> StrategyFn:
        if name in self._builtins:
            return self._builtins[name]
        if name in self._registered:
            return self._registered[name]
        if name not in self._loaded:
            ep = self._plugins().get(name)
            if ep is None:
                raise KeyError(name)
            try:
                fn = ep.load()
            except Exception as exc:  # a broken plugin: named, not a traceback
                raise _input_error(name, f"entry point {ep.value!r} cannot be loaded: "
                                   f"{type(exc).__name__}: {exc}") from exc
            self._loaded[name] = _checked(name, fn)
        return self._loaded[name]

    def register(self, name: str, fn: Callable[..., StrategyResult]) -> None:
        """Add ``fn`` under ``name`` in this process (what ``--strategy module:function`` does)."""
        if name in self._builtins and self._builtins[name] is not fn:
            raise _input_error(name, "is a built-in strategy")
        self._registered[name] = _checked(name, fn)

    def unregister(self, name: str) -> None:
        """Forget a registered name (tests)."""
        self._registered.pop(name, None)

    def refresh(self) -> None:
        """Look the entry points up again (after installing a plugin in this process)."""
        self._found = None
        self._loaded.clear()


def _spec_of(fn: Callable[..., object]) -> str:
    return f"{fn.__module__}:{fn.__qualname__}"


def _input_error(name: str, message: str) -> Exception:
    from delegation.errors import InputError, InputProblem

    return InputError(InputProblem("options", "strategy", f"{name!r}: {message}"))


def _checked(name: str, fn: object) -> StrategyFn:
    if not callable(fn):
        raise _input_error(name, f"is not callable ({type(fn).__name__})")
    return cast(StrategyFn, fn)


#: The strategies by name, in the order they are offered (baseline first).
STRATEGIES = StrategyRegistry(BUILTIN_STRATEGIES)


def resolve_strategy(spec: str) -> str:
    """The registry name for ``spec``: a known name, or ``package.module:function`` imported and
    registered under that spec. Raises ``InputError`` for anything else (the CLI's way in)."""
    if spec in STRATEGIES:
        return spec
    module_name, sep, attr = spec.partition(":")
    if not sep or not module_name or not attr:
        raise _input_error(spec, "unknown strategy; choose one of " + ", ".join(STRATEGIES)
                           + ", or give package.module:function")
    try:
        target: object = importlib.import_module(module_name)
    except ImportError as exc:
        raise _input_error(spec, f"cannot import {module_name!r}: {exc}") from exc
    for part in attr.split("."):
        try:
            target = getattr(target, part)
        except AttributeError:
            raise _input_error(spec, f"{module_name!r} has no {attr!r}") from None
    STRATEGIES.register(spec, cast(Callable[..., StrategyResult], target))
    return spec


#: The objectives, in the order they are offered (the default first).
OBJECTIVES: tuple[Objective, ...] = tuple(Objective)
