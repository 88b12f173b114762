"""Bench runs on a Dask cluster: a scheduler and two workers started here as separate processes
on loopback give the same records as the local run, and a crashing run costs that run only."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import asdict
from pathlib import Path

import pytest

from delegation.bench.executor import DaskExecutor, LocalExecutor
from delegation.bench.generate import GeneratorOptions, generate_scenario
from delegation.bench.runner import RunRecord, run_bench, scenarios_from_dicts
from delegation.bench.scale import run_scale

#: One worker runs these: the Dask cluster (three Python processes) starts once.
pytestmark = [pytest.mark.xdist_group("dask"), pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[1]
#: Fields that measure time: the only ones allowed to differ between executors.
TIMES = ("wall_time", "solve_time")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _stop(process: subprocess.Popen[bytes]) -> None:
    process.terminate()
    try:
        process.wait(timeout=20)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait(timeout=10)


@pytest.fixture(scope="module")
def scheduler() -> Iterator[str]:
    """``dask scheduler`` and two ``dask worker`` processes on 127.0.0.1, stopped afterwards."""
    from distributed import Client

    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), str(ROOT / "tests")]),
        "DASK_DISTRIBUTED__WORKER__DAEMON": "False",  # so that a task may fork its run's child
    }
    processes = [subprocess.Popen(
        [sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
         "--port", str(port), "--no-dashboard"],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        for _ in range(2):
            processes.append(subprocess.Popen(
                [sys.executable, "-m", "distributed.cli.dask_worker", address, "--nthreads", "1",
                 "--host", "127.0.0.1", "--no-dashboard"],
                env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        with Client(address, timeout=60) as client:
            client.wait_for_workers(2, timeout=120)
        yield address
    finally:
        for process in reversed(processes):
            _stop(process)


def _untimed(records: list[RunRecord]) -> list[dict]:
    return [{k: v for k, v in asdict(r).items() if k not in TIMES} for r in records]


def _scenarios() -> list:
    return scenarios_from_dicts(
        [generate_scenario(units=u, tasks=t, seed=s) for u, t, s in ((3, 8, 1), (4, 12, 2))]
    )


def test_dask_cluster_gives_the_local_records(scheduler: str) -> None:
    options = dict(strategies=["nearest", "auction"], objectives=["makespan", "total"],
                   repeat=2, run_timeout=120)
    local = run_bench(_scenarios(), executor=LocalExecutor(isolate=True), **options)
    seen: list[tuple[int, int]] = []
    with DaskExecutor(scheduler) as executor:
        assert len(executor.client.scheduler_info()["workers"]) == 2
        remote = run_bench(_scenarios(), executor=executor,
                           progress=lambda done, total, label: seen.append((done, total)),
                           **options)
    assert not local.failures and not remote.failures
    assert len(remote.records) == 2 * 2 * 2 * 2
    assert _untimed(remote.records) == _untimed(local.records)
    assert set(remote.plans) == set(local.plans)
    assert seen[-1] == (16, 16) and [d for d, _ in seen] == list(range(1, 17))


def test_a_crash_on_a_worker_costs_one_run(scheduler: str) -> None:
    from delegation.allocation import STRATEGIES

    crash = "bench_crash_strategy:abort"
    try:
        with DaskExecutor(scheduler) as executor:
            result = run_bench(_scenarios()[:1], executor=executor, objectives=["makespan"],
                               strategies=["nearest", crash], run_timeout=120)
    finally:
        STRATEGIES.unregister(crash)  # registered in this process by the spec
    assert [r.strategy for r in result.records] == ["nearest"]
    assert len(result.failed) == 1
    assert "planner process died (SIGABRT" in result.failed[0].reason


def test_scale_sweep_on_dask_matches_the_local_sweep(scheduler: str) -> None:
    kwargs = dict(strategies=["nearest", "auction"], units=[2, 4], tasks=[5, 10], budget=60.0,
                  time_limit=1.0, generator=GeneratorOptions(seed=3))
    local = run_scale(executor=LocalExecutor(isolate=True), **kwargs)
    with DaskExecutor(scheduler) as executor:
        remote = run_scale(executor=executor, **kwargs)
    strip = ("wall_time", "solve_time", "relative_to_best")
    assert [{k: v for k, v in r.to_dict().items() if k not in strip} for r in remote] == [
        {k: v for k, v in r.to_dict().items() if k not in strip} for r in local
    ]
    assert all(r.status == "ok" for r in remote)
