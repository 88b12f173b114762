"""The operator's commands, run as an operator runs them: child processes against a real broker
with a live fleet, engine and service (`LocalSystem`), output not on a terminal. One-shot commands
are forked from a process that imported the CLI once (`cli_forks`); long-running ones, stopped by
signals, are started afresh."""

from __future__ import annotations

import json
import os
import queue
import signal
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

import cli_forks
from conftest import one_broker
from delegation.local import LocalSystem
from delegation.runtime.broker import LocalBroker
from delegation.scenario import load_scenario
from delegation.service import ServiceConfig

# The commands are under test, not the broker (on amqtt, in this process, the fleet and the
# broker share one interpreter and every case took twice as long to test the same): one broker.
pytestmark = [pytest.mark.mqtt, one_broker()]

ROOT = Path(__file__).resolve().parents[1]
#: Simulated seconds per wall second: the usv0's 270 m move-to (90 s) takes under 2 s.
SPEEDUP = 50.0
#: Every command first waits for the service's heartbeat (not retained): at 10 Hz that is at most
#: 0.1 s instead of up to a second, on each of the ~40 commands here. The units beat at 5 Hz so
#: that ``agents --wait 1`` sees each of them five times.
SERVICE_RATE = 10.0
UNIT_RATE = 5.0
WP = {"latitude": 57.7608, "longitude": 16.6800, "altitude": 40.0}


def open_ended(root: str, unit: str) -> dict[str, Any]:
    """A seq that flies a little, then looks until told ``$enough``: it stays running."""
    return {"name": "seq", "common_params": {"node-uuid": root}, "children": [
        {"name": "move-to", "common_params": {"execunit": unit},
         "params": {"waypoint": WP, "speed": "fast"}},
        {"name": "look-at-position", "common_params": {"execunit": unit},
         "params": {"geopoint": WP}},
    ]}


@pytest.fixture(scope="module")
def live(broker: LocalBroker) -> Iterator[dict[str, str]]:
    scenario = load_scenario(ROOT / "scenarios" / "demo.yaml")
    prefix = f"test-{uuid.uuid4().hex[:10]}"
    config = replace(ServiceConfig(), profiles=scenario.profiles(), rate=SERVICE_RATE)
    units = scenario.units()
    with LocalSystem(units, settings=broker.settings(), config=config, prefix=prefix,
                     speedup=SPEEDUP, rates={u.name: UNIT_RATE for u in units}):
        yield {"port": str(broker.settings().port), "prefix": prefix}


def cli(live: dict[str, str], args: list[str], timeout: float = 60.0,
        cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    """A one-shot command, in a child process forked with the CLI imported (`cli_forks`)."""
    return cli_forks.run(_argv(live, args)[3:], _env(), cwd, timeout)


def _argv(live: dict[str, str], args: list[str]) -> list[str]:
    return [sys.executable, "-m", "delegation", *args, "--port", live["port"],
            "--prefix", live["prefix"]]


def _env() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("WARAPS_")}
    env.update(PYTHONPATH=str(ROOT / "src"), COLUMNS="80")
    return env


class Child:
    """A long-running command; its output lines are collected by a thread (waited on with a
    deadline, never slept on). Its own process, forked with the CLI imported (`cli_forks`),
    stdout and stderr on pipes (FIFOs in ``workdir``)."""

    def __init__(self, argv: list[str], workdir: Path) -> None:
        self.proc = cli_forks.spawn_piped(argv[3:], _env(), workdir, stderr=True)
        self.lines: queue.Queue[str] = queue.Queue()
        self.out: list[str] = []
        self.err: list[str] = []
        self.readers = [threading.Thread(target=self._read, args=(stream, sink), daemon=True)
                        for stream, sink in ((self.proc.stdout, self.out),
                                             (self.proc.stderr, self.err))]
        for reader in self.readers:
            reader.start()

    def _read(self, stream: Any, sink: list[str]) -> None:
        for line in stream:
            sink.append(line)
            self.lines.put(line)

    def wait_line(self, text: str, timeout: float = 20.0) -> str:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                line = self.lines.get(timeout=max(0.01, deadline - time.monotonic()))
            except queue.Empty:
                break
            if text in line:
                return line
        raise AssertionError(f"no line with {text!r} in {timeout:g} s: {self.out + self.err}")

    def stop(self, sig: int, within: float = 15.0) -> tuple[int, float]:
        """Signal the child; its exit code (``TimeoutExpired`` if it has not stopped ``within``
        seconds: a generous bound, so that a loaded machine does not fail a correct stop)."""
        t0 = time.monotonic()
        self.proc.send_signal(sig)
        code = self.proc.wait(within)
        took = time.monotonic() - t0
        for reader in self.readers:  # the last lines are read once the pipes close
            reader.join(5.0)
        return code, took


def _mission_file(tmp_path: Path, name: str, tree: dict[str, Any]) -> str:
    path = tmp_path / name
    path.write_text(json.dumps(tree))
    return str(path)


@pytest.mark.slow
def test_submit_list_status_signal_follow_cancel(live: dict[str, str], tmp_path: Path) -> None:
    base = uuid.uuid4().hex[:6]
    a, b = f"{base}a0-0000-4000-8000-000000000001", f"{base}b0-0000-4000-8000-000000000002"
    fa = _mission_file(tmp_path, "a.json", open_ended(a, "/dji0"))
    # b spelt as the seed's 11.1 examples spell it: common-params, not common_params
    fb = _mission_file(tmp_path, "b.json", json.loads(
        json.dumps(open_ended(b, "/dji1")).replace('"common_params"', '"common-params"')))

    # submit stops following (timeout): full id, plain progress lines, and how to go on
    r = cli(live, ["submit", fa, "--speedup", str(SPEEDUP), "--timeout", "2"])
    assert r.returncode == 1, r.stdout + r.stderr
    assert f"mission {a} started" in r.stdout
    assert f"mission {a[:8]} running" in r.stdout  # a plain line, not a live table
    assert f"re-attach: delegation follow {a[:8]}" in r.stdout
    assert "delegation cancel" in r.stdout
    r = cli(live, ["submit", fb, "--timeout", "1"])
    assert r.returncode == 1 and f"mission {b} started" in r.stdout, r.stdout

    r = cli(live, ["missions", "--json"])
    rows = {m["root-uuid"]: m for m in json.loads(r.stdout)}
    assert rows[a]["status"] in ("started", "running") and b in rows
    r = cli(live, ["missions", "--status", "active"])
    assert r.returncode == 0 and a[:8] in r.stdout
    assert all(len(line) <= 80 for line in r.stdout.splitlines())
    assert cli(live, ["missions", "--status", "succeeded", "--json"]).stdout.count(a) == 0

    # ids: unique prefixes; ambiguous and unknown ones are one line, exit 1
    r = cli(live, ["status", base])
    assert r.returncode == 1 and "ambiguous" in r.stderr and len(r.stderr.splitlines()) == 1
    r = cli(live, ["status", "ffffffff-nope"])
    assert r.returncode == 1 and "no mission id starts with" in r.stderr
    r = cli(live, ["status", a[:12], "--speedup", str(SPEEDUP)])
    assert r.returncode == 0, r.stderr
    assert "look-at-position" in r.stdout and "running" in r.stdout and "/dji0" in r.stdout
    assert all(len(line) <= 80 for line in r.stdout.splitlines())
    mission = json.loads(cli(live, ["status", a, "--json"]).stdout)
    assert {n["name"] for n in mission["nodes"]} == {"seq", "move-to", "look-at-position"}

    r = cli(live, ["signal", a[:10], "$pause", "--json"])
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout) == {"root-uuid": a, "signal": "$pause", "response": "ok"}
    assert cli(live, ["signal", a[:10], "$continue"]).returncode == 0

    # re-attach, end the open-ended task, see it succeed
    r = cli(live, ["follow", a[:10], "--enough", "--speedup", str(SPEEDUP), "--timeout", "40"])
    assert r.returncode == 0, r.stdout + r.stderr
    assert f"mission {a} succeeded" in r.stdout

    r = cli(live, ["cancel", b[:10]])
    assert r.returncode == 0, r.stderr
    assert f"mission {b} cancelled" in r.stdout
    assert json.loads(cli(live, ["status", b, "--json"]).stdout)["status"] == "aborted"
    r = cli(live, ["cancel", b])
    assert r.returncode == 1 and "already ended" in r.stderr


@pytest.mark.slow
def test_bids_and_plan_for_the_live_fleet(live: dict[str, str], tmp_path: Path) -> None:
    tree = {"name": "conc", "children": [
        {"name": "move-to", "params": {"waypoint": WP}},
        {"name": "search-area", "params": {"area": [
            {"latitude": 57.7613, "longitude": 16.6825},
            {"latitude": 57.7613, "longitude": 16.6837},
            {"latitude": 57.7618, "longitude": 16.6837}]}},
    ]}
    f = _mission_file(tmp_path, "m.json", tree)
    r = cli(live, ["bids", f])
    assert r.returncode == 0, r.stderr
    assert "dji0" in r.stdout and "usv0" in r.stdout and "search-area" in r.stdout
    assert all(len(line) <= 80 for line in r.stdout.splitlines())
    bids = json.loads(cli(live, ["bids", f, "--json"]).stdout)
    assert {b["unit"] for b in bids} >= {"/dji0", "/dji1", "/usv0"}
    r = cli(live, ["agents", "--wait", "1"])  # piped: 80 columns, nothing dropped
    assert r.returncode == 0 and all(len(line) <= 80 for line in r.stdout.splitlines())
    assert "move-to" in r.stdout and "usv0" in r.stdout
    r = cli(live, ["submit", f, "--json", "--speedup", str(SPEEDUP), "--timeout", "60"])
    assert r.returncode == 0, r.stderr
    done = json.loads(r.stdout)  # the JSON alone on stdout; progress went to stderr
    assert done["status"] == "succeeded" and "running" in r.stderr
    r = cli(live, ["follow", done["root-uuid"][:8], "--json"])
    assert r.returncode == 0 and json.loads(r.stdout)["status"] == "succeeded"
    r = cli(live, ["plan", f, "--live", "--format", "json"])
    assert r.returncode == 0, r.stderr
    plan = json.loads(r.stdout)
    assert plan["feasible"] and {a["execunit"] for a in plan["assignments"]} <= {
        "/dji0", "/dji1", "/usv0"}


@pytest.mark.slow
def test_follow_stops_on_sigint_and_says_how_to_go_on(live: dict[str, str],
                                                       tmp_path: Path) -> None:
    root = str(uuid.uuid4())
    f = _mission_file(tmp_path, "c.json", open_ended(root, "/usv0"))
    assert cli(live, ["submit", f, "--timeout", "1"]).returncode == 1
    child = Child(_argv(live, ["follow", root[:8]]), tmp_path)
    child.wait_line(f"mission {root[:8]}")
    code, _ = child.stop(signal.SIGINT)
    assert code == 130
    assert any(f"re-attach: delegation follow {root[:8]}" in line for line in child.out), (
        child.out + child.err)
    assert any("stopped by SIGINT" in line for line in child.err)
    assert cli(live, ["cancel", root]).returncode == 0


@pytest.mark.slow  # a fresh ``python -m delegation``, started and stopped
def test_submit_stops_on_sigterm_and_the_mission_goes_on(live: dict[str, str],
                                                        tmp_path: Path) -> None:
    root = str(uuid.uuid4())
    f = _mission_file(tmp_path, "d.json", open_ended(root, "/dji1"))
    child = Child(_argv(live, ["submit", f]), tmp_path)
    child.wait_line(f"mission {root} started")
    code, _ = child.stop(signal.SIGTERM)
    assert code == 0
    assert any(f"re-attach: delegation follow {root[:8]}" in line for line in child.out), (
        child.out + child.err)
    status = json.loads(cli(live, ["status", root, "--json"]).stdout)["status"]
    assert status in ("started", "running")
    assert cli(live, ["cancel", root]).returncode == 0


@pytest.mark.slow
def test_serve_logs_mission_events_and_stops_on_sigterm(live: dict[str, str],
                                                        tmp_path: Path) -> None:
    """A second service (no profiles) on the same fleet: its log, in JSON, at INFO by default,
    says what happened to each mission and unit; SIGTERM stops it with exit 0."""
    name = f"delegator{uuid.uuid4().hex[:4]}"
    serve = Child(_argv(live, ["serve", "--name", name, "--log-json"]), tmp_path)
    try:
        serve.wait_line("serving on")
        serve.wait_line("appeared")
        ok = _mission_file(tmp_path, "ok.json", {
            "name": "move-to", "common_params": {"execunit": "usv0"},
            "params": {"waypoint": WP}})
        r = cli(live, ["submit", ok, "--service", name, "--speedup", str(SPEEDUP),
                       "--timeout", "40"])
        assert r.returncode == 0, r.stdout + r.stderr
        bad = _mission_file(tmp_path, "bad.json", {
            "name": "move-to", "common_params": {"execunit": "/dji9"},
            "params": {"waypoint": WP}})
        assert "note: root (move-to" in r.stdout and "is an alias" in r.stdout  # notes shown
        assert cli(live, ["submit", bad, "--service", name]).returncode == 1
        serve.wait_line("refused")
    finally:
        code, _ = serve.stop(signal.SIGTERM)
    assert code == 0
    logs = [json.loads(line) for line in serve.err]
    text = "\n".join(entry["message"] for entry in logs)
    for expected in ("unit dji0 appeared", "received on delegation", "planned: auction/makespan",
                     "makespan", "sent to engine op0", "succeeded", "refused", "/dji9",
                     "is an alias", "defaults (slow", "stopped by SIGTERM"):
        assert expected in text, expected


@pytest.mark.slow  # five fresh ``python -m delegation`` processes, started and stopped
@pytest.mark.parametrize(("command", "sig", "code", "ready"), [
    (["engine"], signal.SIGTERM, 0, "TST engine"),
    (["sim", "demo"], signal.SIGINT, 130, "simulated units"),
    (["sim", "demo"], signal.SIGTERM, 0, "simulated units"),
    (["serve"], signal.SIGINT, 130, "serving on"),
    (["demo", "--speedup", "20", "--out", "{tmp}"], signal.SIGTERM, 0, "units, speedup"),
])
def test_long_running_commands_stop_on_signals(live: dict[str, str], command: list[str],
                                               sig: int, code: int, ready: str,
                                               tmp_path: Path) -> None:
    """Each on a prefix of its own (a second simulated dji0 would confuse the shared fleet)."""
    own = {**live, "prefix": f"sig-{uuid.uuid4().hex[:8]}"}
    child = Child(_argv(own, [c.replace("{tmp}", str(tmp_path)) for c in command]), tmp_path)
    child.wait_line(ready)
    got, _ = child.stop(sig)
    assert got == code, child.out + child.err
    assert any(f"stopped by {signal.Signals(sig).name}" in line for line in child.err)
