"""The strategy plugin point (docs/strategies.md): entry points, ``module:function`` specs, the
example plugin in ``examples/greedy_plugin``, and the same names in plan, bench and the service."""

from __future__ import annotations

import json
import os
import subprocess
import tomllib
from collections.abc import Iterator
from importlib import metadata
from pathlib import Path

import pytest

import cli_forks
from delegation.allocation import STRATEGIES, check_invariants, plan_mission
from delegation.allocation.strategies import (
    BUILTIN_STRATEGIES,
    ENTRY_POINT_GROUP,
    StrategyRegistry,
    resolve_strategy,
)
from delegation.errors import InputError

ROOT = Path(__file__).resolve().parents[1]
PLUGIN_DIR = ROOT / "examples" / "greedy_plugin"
SPEC = "greedy_plugin.strategy:least_loaded"


@pytest.fixture
def plugin_path(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    monkeypatch.syspath_prepend(str(PLUGIN_DIR))
    yield
    STRATEGIES.unregister(SPEC)


def _ep(name: str, value: str) -> metadata.EntryPoint:
    return metadata.EntryPoint(name=name, value=value, group=ENTRY_POINT_GROUP)


def _demo() -> tuple:
    from delegation.scenario import load_scenario

    scenario = load_scenario(ROOT / "scenarios" / "demo.yaml")
    return scenario.tree(), scenario.units()


def test_pyproject_registers_the_builtins_in_the_entry_point_group() -> None:
    data = tomllib.loads((ROOT / "pyproject.toml").read_text())
    declared = data["project"]["entry-points"][ENTRY_POINT_GROUP]
    assert list(declared) == list(BUILTIN_STRATEGIES)
    for name, value in declared.items():
        assert _ep(name, value).load() is BUILTIN_STRATEGIES[name]
    # and the registry takes those entry points as the built-ins, not as a second copy
    registry = StrategyRegistry(
        BUILTIN_STRATEGIES, lambda: [_ep(n, v) for n, v in declared.items()]
    )
    assert list(registry) == ["nearest", "auction", "optimal"]


def test_entry_point_plugin_is_listed_without_loading_and_loaded_on_use(plugin_path: None) -> None:
    from greedy_plugin.strategy import least_loaded

    registry = StrategyRegistry(
        BUILTIN_STRATEGIES,
        lambda: [_ep("least-loaded", SPEC), _ep("broken", "no_such_module_xyz:fn"),
                 _ep("nearest", "elsewhere:fn")],
    )
    assert list(registry) == ["nearest", "auction", "optimal", "broken", "least-loaded"]
    assert "least-loaded" in registry and "broken" in registry
    assert registry["least-loaded"] is least_loaded
    assert registry["nearest"] is BUILTIN_STRATEGIES["nearest"]  # a plugin cannot shadow it
    with pytest.raises(InputError, match="'broken': entry point 'no_such_module_xyz:fn' cannot"):
        registry["broken"]
    with pytest.raises(KeyError):
        registry["missing"]


def test_installed_plugin_reaches_the_planner_and_the_service(
    plugin_path: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The process-wide registry with a fake installed distribution's entry point: the planner
    and the service's option check accept the name with no change of their own."""
    from delegation.service.jobs import PlanOptions, plan_options

    monkeypatch.setattr(STRATEGIES, "_entry_points", lambda: [_ep("least-loaded", SPEC)])
    STRATEGIES.refresh()
    try:
        options = plan_options("least-loaded", None, None, max_time_limit=10,
                               defaults=PlanOptions("auction", "makespan", 5.0))
        assert options.strategy == "least-loaded"
        tree, units = _demo()
        plan = plan_mission(tree, units, strategy="least-loaded")
        assert plan.strategy == "least-loaded" and plan.feasible
        assert list(check_invariants(plan, tree, units)) == []
    finally:
        monkeypatch.undo()
        STRATEGIES.refresh()
    assert "least-loaded" not in STRATEGIES


def test_a_spec_sent_to_the_service_is_not_imported() -> None:
    from delegation.service.jobs import PlanOptions, plan_options

    with pytest.raises(InputError, match="unknown strategy 'os:system'"):
        plan_options("os:system", None, None, max_time_limit=10,
                     defaults=PlanOptions("auction", "makespan", 5.0))
    assert "os:system" not in STRATEGIES


def test_module_function_spec_is_resolved_and_registered(plugin_path: None) -> None:
    assert resolve_strategy(SPEC) == SPEC
    assert SPEC in STRATEGIES
    tree, units = _demo()
    plan = plan_mission(tree, units, strategy=SPEC, objective="total")
    assert plan.strategy == SPEC and plan.feasible


@pytest.mark.parametrize(
    ("spec", "why"),
    [
        ("no_such_module_xyz:fn", "cannot import 'no_such_module_xyz'"),
        ("greedy_plugin.strategy:nothing", "has no 'nothing'"),
        ("greedy_plugin.strategy:np", "is not callable"),
        ("bogus", "unknown strategy; choose one of nearest, auction, optimal"),
    ],
)
def test_bad_specs_are_refused_with_the_reason(plugin_path: None, spec: str, why: str) -> None:
    with pytest.raises(InputError, match=why):
        resolve_strategy(spec)


def test_bench_runs_a_plugin_spec(plugin_path: None) -> None:
    from delegation.bench.generate import generate_scenario
    from delegation.bench.runner import run_bench, scenarios_from_dicts

    items = scenarios_from_dicts([generate_scenario(units=3, tasks=8, seed=1)])
    result = run_bench(items, strategies=["nearest", SPEC], objectives=["makespan"])
    assert [r.strategy for r in result.records] == ["nearest", SPEC]
    assert not result.violations and not result.failures


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), str(PLUGIN_DIR)])}
    return cli_forks.run(list(args), env, ROOT, timeout=120)  # forked with the CLI imported


def test_plan_cli_runs_the_example_plugin_by_spec() -> None:
    done = _cli("plan", "scenarios/demo.yaml", "--strategy", SPEC, "--format", "json")
    assert done.returncode == 0, done.stderr
    plan = json.loads(done.stdout)
    assert plan["strategy"] == SPEC and plan["feasible"] is True


@pytest.mark.slow  # fresh plan and serve processes
def test_plan_and_serve_refuse_an_unimportable_spec_with_its_reason() -> None:
    for command in (["plan", "scenarios/demo.yaml"], ["serve"]):
        done = _cli(*command, "--strategy", "no_such_module_xyz:fn")
        assert done.returncode == 2
        assert "cannot import 'no_such_module_xyz'" in done.stderr.strip().splitlines()[-1]
