"""The runtime commands: ``delegation demo`` end to end, ``submit`` and ``agents`` on a broker."""

from __future__ import annotations

import json
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

import cli_forks
from delegation.cli import main
from delegation.cli.demo import DEMO_FLEET_TICKS_PER_S, demo_rates
from delegation.cli.inputs import find_scenario, read_mission
from delegation.errors import InputError
from delegation.local import LocalSystem
from delegation.runtime.settings import BrokerSettings
from delegation.scenario import load_scenario

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def assert_png(path: Path) -> None:
    import matplotlib.image

    assert path.read_bytes()[:8] == PNG_MAGIC
    image = matplotlib.image.imread(path)
    assert image.ndim == 3 and image.shape[0] > 200 and image.shape[1] > 200


@pytest.mark.mqtt
@pytest.mark.slow
def test_demo_runs_to_success_and_writes_a_map(tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    for var in ("WARAPS_BROKER", "WARAPS_PORT"):
        monkeypatch.delenv(var, raising=False)  # the demo must start its own broker
    out = tmp_path / "out"
    assert main(["demo", "--speedup", "60", "--out", str(out)]) == 0
    assert_png(out / "map.png")
    assert_png(out / "gantt.png")  # planned vs flown
    plan = json.loads((out / "plan.json").read_text())
    assert plan["feasible"] and plan["strategy"] == "auction"


@pytest.mark.slow
def test_demo_runs_the_mission_twice_and_prints_plan_vs_flown(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Without the fleet's profile the service plans with default speeds, learns the real ones
    while the first mission flies, and says so; the same mission runs again with fresh uuids.
    (How close the second plan gets is a figure: benchmarks/learning.py.)"""
    for var in ("WARAPS_BROKER", "WARAPS_PORT"):
        monkeypatch.delenv(var, raising=False)
    out = tmp_path / "out"
    assert main(["demo", "--speedup", "60", "--missions", "2", "--no-profiles",
                 "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "plan vs flown, per mission" in text
    assert "mission 1: plan" in text and "mission 2: plan" in text
    assert text.count(" started") >= 2
    assert_png(out / "map.png")


def test_scenarios_are_found_by_name_from_anywhere(tmp_path: Path,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    found = find_scenario("demo.yaml")
    assert found.is_file() and found.name == "demo.yaml"
    assert find_scenario("demo") == found
    with pytest.raises(InputError, match="no-such-scenario"):
        find_scenario("no-such-scenario")


def test_mission_files_of_every_kind(tmp_path: Path) -> None:
    tree = {"name": "move-to", "params": {"waypoint": {"latitude": 57.0, "longitude": 16.0}}}
    (tmp_path / "tree.json").write_text(json.dumps(tree))
    (tmp_path / "cmd.json").write_text(json.dumps({"command": "start-tst", "com-uuid": "x",
                                                   "tst": tree}))
    assert read_mission(str(tmp_path / "tree.json")) == tree
    assert read_mission(str(tmp_path / "cmd.json")) == tree
    assert read_mission(str(find_scenario("demo")))["name"] == "conc"
    (tmp_path / "bad.json").write_text("[1]")
    with pytest.raises(InputError, match="object"):
        read_mission(str(tmp_path / "bad.json"))


@pytest.fixture
def running(mqtt_settings: BrokerSettings, prefix: str) -> Iterator[list[str]]:
    """The demo scenario's fleet, engine and service on the test broker; yields CLI flags."""
    scenario = load_scenario(find_scenario("demo"))
    with LocalSystem.from_scenario(scenario, settings=mqtt_settings, prefix=prefix, speedup=60.0):
        yield ["--broker", mqtt_settings.host, "--port", str(mqtt_settings.port),
               "--prefix", prefix]


@pytest.mark.mqtt
@pytest.mark.slow
def test_submit_follows_a_mission_and_agents_lists_units(
    running: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["agents", "--wait", "1.5", "--format", "json", *running]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert {"dji0", "dji1", "usv0", "op0", "delegator0"} <= {r["name"] for r in rows}

    mission = tmp_path / "mission.json"
    tree = {"name": "seq", "common_params": {"node-uuid": str(uuid.uuid4())},
            "children": [{"name": "move-to", "params": {
                "waypoint": {"latitude": 57.7609, "longitude": 16.6805, "altitude": 30.0}}}]}
    mission.write_text(json.dumps(tree))
    assert main(["submit", str(mission), "--speedup", "60", *running]) == 0
    out = capsys.readouterr().out
    assert "succeeded" in out and "move-to" in out

    impossible = tmp_path / "impossible.json"
    impossible.write_text(json.dumps({"name": "image-object-detection", "params": {}}))
    assert main(["submit", str(impossible), *running]) == 1
    assert "image-object-detection" in capsys.readouterr().out


@pytest.mark.mqtt
def test_submit_without_a_service_fails_clearly(mqtt_settings: BrokerSettings, prefix: str,
                                                tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    mission = tmp_path / "m.json"
    mission.write_text(json.dumps({"name": "move-to", "params": {
        "waypoint": {"latitude": 57.0, "longitude": 16.0}}}))
    code = main(["submit", str(mission), "--broker", mqtt_settings.host, "--port",
                 str(mqtt_settings.port), "--prefix", prefix, "--service", "nobody",
                 "--wait", "1"])
    assert code == 1
    assert "nobody" in capsys.readouterr().err


@pytest.mark.mqtt
@pytest.mark.slow
def test_serve_answers_on_the_broker_and_stops_on_sigterm(mqtt_settings: BrokerSettings,
                                                          prefix: str, tmp_path: Path) -> None:
    import os
    import signal

    from delegation.runtime.client import ServiceClient

    proc = cli_forks.spawn_piped(  # a process of its own, forked with the CLI imported
        ["serve", "--broker", mqtt_settings.host, "--port", str(mqtt_settings.port),
         "--prefix", prefix, "--name", "svc7", "--state", str(tmp_path / "state.sqlite")],
        dict(os.environ), tmp_path, stderr=True)
    try:
        with ServiceClient(mqtt_settings, prefix=prefix, service="svc7",
                           service_timeout=20) as client:
            base = client.wait_service(20)
            assert base.endswith("/svc7")
            assert client.request({"command": "ping"}, timeout=10)["response"] == "pong"
            agents = client.request({"command": "list-agents"}, timeout=10)
            assert agents["response"] == "ok" and agents["agents"] == []
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=20)
        assert proc.returncode == 0, err
        assert "svc7 stopped" in out
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()


def test_serve_profiles_from_a_scenario_or_a_plain_file(tmp_path: Path) -> None:
    from delegation.cli.inputs import read_profiles

    profiles = read_profiles(str(find_scenario("demo")))
    assert set(profiles) == {"dji0", "dji1", "usv0"}
    assert profiles["dji0"]["speeds"]["standard"] == 8.0
    plain = tmp_path / "p.yaml"
    plain.write_text("air: {speeds: {standard: 5.0}}\ndji7: {endurance: 900}\n")
    assert read_profiles(str(plain)) == {"air": {"speeds": {"standard": 5.0}},
                                          "dji7": {"endurance": 900}}
    plain.write_text("air: fast\n")
    with pytest.raises(InputError, match="air"):
        read_profiles(str(plain))
    plain.write_bytes(b"\xff\xfeair: {}\n")
    with pytest.raises(InputError, match=r"p\.yaml: not UTF-8 text"):
        read_profiles(str(plain))


def test_demo_rates_keep_the_fleet_within_the_brokers_budget() -> None:
    # Three units (the demo): as before, speedup / 2 up to 10 Hz, never below the scenario's rate.
    assert demo_rates([("a", 2.0), ("b", None), ("c", 2.0)], 5.0) == {"a": 2.5, "b": 2.5, "c": 2.5}
    assert demo_rates([("a", 2.0)], 1.0) == {"a": 2.0}
    assert demo_rates([("a", None)], 100.0) == {"a": 10.0}
    # Twenty units at speedup 20: the fleet's budget, not 10 Hz each.
    rates = demo_rates([(f"u{i}", None) for i in range(20)], 20.0)
    assert sum(rates.values()) == pytest.approx(DEMO_FLEET_TICKS_PER_S)
    # A scenario's own rate is kept even past the budget.
    assert demo_rates([(f"u{i}", 3.0) for i in range(40)], 20.0)["u0"] == 3.0
