"""The planner in a child process (`serve`'s default, ``--planner process``): the same plans as
on the thread, a child that dies answers its job and is replaced, and no child outlives the
service, even one killed with ``kill -9``; `serve` forks it (it does not spawn it)."""

from __future__ import annotations

import os
import select
import signal
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

import cli_forks
from delegation.cli import build_parser
from delegation.cli.serve import _planner
from delegation.runtime.broker import PrivateMosquitto
from delegation.service import ServiceConfig, ServiceCore, run_job
from delegation.service.jobs import Job, JobFailed, PlanDone
from delegation.service.planner_process import PlannerProcess
from test_service_core import BASE, PREFIX, feed_engine, feed_unit, partial_tree, start_tst

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def planner() -> Iterator[PlannerProcess]:
    started = PlannerProcess()
    try:
        yield started
    finally:
        started.close()


def _job() -> Job:
    core = ServiceCore(ServiceConfig(prefix=PREFIX))
    feed_unit(core, "dji0", 57.7605, 16.6815, ["move-to"], 100.0)
    feed_unit(core, "dji1", 57.7600, 16.6800, ["move-to"], 100.0)
    feed_engine(core, 100.0)
    (job,) = core.on_message(f"{BASE}/tst/command", start_tst(partial_tree()), 100.5).jobs
    return job


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except FileNotFoundError:
        return False
    return state != "Z"


def test_the_child_plans_what_the_thread_plans(planner: PlannerProcess) -> None:
    job = _job()
    there, here = planner(job), run_job(job)
    assert isinstance(there, PlanDone) and isinstance(here, PlanDone)
    timed = ("solve-time",)
    assert ({k: v for k, v in there.plan.to_json().items() if k not in timed}
            == {k: v for k, v in here.plan.to_json().items() if k not in timed})
    assert planner.pid != os.getpid() and planner.pid is not None and _alive(planner.pid)


def test_serve_plans_in_a_process_unless_told_thread() -> None:
    default = build_parser().parse_args(["serve"])
    assert default.planner == "process"
    assert _planner(build_parser().parse_args(["serve", "--planner", "thread"]).planner) \
        is run_job


@pytest.mark.slow  # planner processes killed and started again
def test_a_child_that_dies_answers_failed_and_is_replaced(planner: PlannerProcess) -> None:
    dead = planner.pid
    assert dead is not None
    os.kill(dead, signal.SIGKILL)
    failed = planner(_job())
    assert isinstance(failed, JobFailed) and "planner process died" in failed.reason
    assert planner.pid != dead
    assert isinstance(planner(_job()), PlanDone)


@pytest.mark.slow  # a planner process started and stopped
def test_close_ends_the_child() -> None:
    own = PlannerProcess()
    pid = own.pid
    assert pid is not None and _alive(pid)
    own.close()
    assert not _alive(pid)
    assert isinstance(own(_job()), JobFailed)  # after close: answered, never hangs


def _children(pid: int) -> list[int]:
    found: list[int] = []
    for task in Path(f"/proc/{pid}/task").glob("*/children"):
        found.extend(int(c) for c in task.read_text().split())
    return found


@pytest.mark.slow  # a real service killed -9
def test_no_planner_outlives_a_service_killed_with_kill_9(mosquitto: PrivateMosquitto,
                                                          tmp_path: Path) -> None:
    settings = mosquitto.settings()
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    serve = cli_forks.spawn_piped(  # a process of its own, forked with the CLI imported
        ["serve", "--broker", settings.host, "--port", str(settings.port), "--prefix", "pp",
         "--name", "pp0", "--state", str(tmp_path / "state.sqlite")],  # plans in a process
        env, tmp_path, stderr=Path(os.devnull))
    try:
        assert serve.stdout is not None
        for line in serve.stdout:  # the planner starts before the service says it is active
            if "active" in line:
                break
        children = _children(serve.pid)
        assert children, "serve started no planner process"
        for child in children:  # forked (the planner imported already), not spawned
            assert b"spawn_main" not in Path(f"/proc/{child}/cmdline").read_bytes()
        exits = [os.pidfd_open(c) for c in children]  # readable once that process has exited
        try:
            serve.kill()
            serve.wait(10)
            deadline = time.monotonic() + 15.0
            waiting = list(exits)
            while waiting:
                left = deadline - time.monotonic()
                assert left > 0, "a planner process outlived the killed service"
                ready, _, _ = select.select(waiting, [], [], left)
                waiting = [fd for fd in waiting if fd not in ready]
        finally:
            for fd in exits:
                os.close(fd)
        assert not [c for c in children if _alive(c)]
    finally:
        if serve.poll() is None:
            serve.kill()
            serve.wait(10)
