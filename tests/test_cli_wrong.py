"""Wrong invocations, as an operator types them (docs/findings: operators.md, the table of 47):
each gives one line naming what is wrong and exit 2 (usage) or 1 (input), never a traceback.

Run as a user would: ``python -m delegation`` in a child process (forked from one that imported
the CLI once: `cli_forks`). Rows that need a broker use a closed local port ({closed}); the one
that needs a live broker is a test of its own. Left out of the findings' table: rows that need a
full mission run (impossible mission, no engine: unchanged and rated 5), the unreachable-host row
(a 10 s connect deadline) and ``demo`` rows (another engineer edits ``demo``). Rows that were
wrong and now work (B10, B11, B12) expect exit 0.
"""

from __future__ import annotations

import json
import os
import shlex
import subprocess
from pathlib import Path
from typing import Any

import pytest
import yaml

import cli_forks
from delegation.runtime.broker import LOOPBACK, free_port

ROOT = Path(__file__).resolve().parents[1]
DEMO = str(ROOT / "scenarios" / "demo.yaml")
FREE = {"name": "move-to", "params": {"waypoint": {"latitude": 57.761, "longitude": 16.68}}}
BADPARAM = {"name": "move-to", "params": {"speed": "quick",
                                          "waypoint": {"latitude": 157.76, "longitude": 16.68}}}
TYPO = {"name": "seq", "children": [FREE, {"name": "serach-area", "params": {}}]}

# (argv, extra environment, exit code, what stderr must say). {closed}: a port nobody listens on.
CASES: list[tuple[str, dict[str, str], int, str]] = [
    ("", {}, 2, ""),  # the help, on stdout
    ("bogus", {}, 2, "invalid choice: 'bogus'"),
    ("serve -v --port {closed}", {}, 1, "cannot connect to mqtt://127.0.0.1:{closed}"),
    ("plan nope.yaml", {}, 1, "nope.yaml"),
    ("plan demo --format json", {}, 0, ""),  # scenario names resolve in every command (B12)
    ("plan scenarios/", {}, 1, "scenarios"),
    (f"plan {DEMO} --strategy greedy", {}, 2, "invalid choice: 'greedy'"),
    (f"plan {DEMO} --time-limit abc", {}, 2, "--time-limit"),
    (f"plan {DEMO} --time-limit -1 --strategy optimal", {}, 1, "time-limit"),
    ("plan free.json", {}, 1, "this is a mission (a TST), not a scenario"),
    ("plan bad.yaml", {}, 1, "not valid YAML"),
    ("plan free.json --fleet nope.yaml", {}, 1, "nope.yaml"),
    ("plan free.json --fleet nodesc.yaml --json", {}, 0, ""),  # a mission for a fleet file (B13)
    ("plan free.json --fleet demo", {}, 0, ""),
    ("plan free.json --fleet free.json", {}, 1, "agents"),
    ("plan controls.json --fleet demo", {}, 1, "root: children: the tree has no task node (3 "
                                               "control nodes only): there is nothing to plan"),
    ("plan impossible.yaml --format json", {}, 1, ""),  # infeasible: the plan, and exit 1
    ("bench", {}, 1, "give scenario files/folders"),
    (f"bench {DEMO} --strategies greedy,auction", {}, 1, "'greedy': unknown strategy"),
    (f"bench {DEMO} --objectives speed", {}, 1, "unknown 'speed'"),
    (f"bench {DEMO} --repeat 0", {}, 1, "repeat"),
    ("bench --generate --units abc", {}, 2, "comma-separated integers"),
    ("bench --generate --site mars", {}, 1, "unknown site 'mars'"),
    ("bench --generate --mix move-to=x", {}, 1, "'x' is not a number"),
    ("bench --generate --units 0", {}, 1, "at least 1"),
    ("bench --scale scenarios", {}, 1, "--scale"),
    (f"bench --in-process --run-timeout 3 {DEMO}", {}, 1, "--run-timeout"),
    ("agents --broker 127.0.0.1 --port {closed}", {}, 1, "cannot connect"),
    ("agents --broker no-such-host.invalid --wait 1", {}, 1, "cannot connect"),
    ("agents --broker 127.0.0.1 --port abc", {}, 2, "argument --port: 'abc' is not a port"),
    ("agents --broker 127.0.0.1 --port 99999", {}, 2, "99999 is not a port number"),
    ("agents", {"WARAPS_BROKER": "127.0.0.1", "WARAPS_PORT": "abc"}, 2, "WARAPS_PORT: 'abc'"),
    ("agents", {"WARAPS_PORT": "70000"}, 2, "WARAPS_PORT: 70000"),
    ("agents", {"WARAPS_TLS_CONNECTION": "maybe"}, 2, "WARAPS_TLS_CONNECTION: 'maybe'"),
    ("agents --broker 127.0.0.1 --tls --port {closed}", {}, 1, "mqtts://127.0.0.1:{closed}"),
    ("engine --port {closed} --duration 1", {}, 1, "cannot connect to mqtt://127.0.0.1:{closed}"),
    ("sim demo --port {closed} --duration 1", {}, 1, "cannot connect to mqtt://127.0.0.1:{closed}"),
    ("serve --port {closed}", {}, 1, "cannot connect to mqtt://127.0.0.1:{closed}"),
    ("sim nope --broker 127.0.0.1", {}, 1, "no such scenario file"),
    ("sim demo --speedup 0 --port {closed}", {}, 1, "--speedup"),
    ("sim demo --role bogus", {}, 2, "invalid choice: 'bogus'"),
    ("engine --agent-type spaceship", {}, 2, "invalid choice: 'spaceship'"),
    ("serve --profiles free.json", {}, 1, "this is a mission (a TST), not a profiles file"),
    ("serve --profiles command.json", {}, 1, "this is a command, not a profiles file"),
    ("serve --profiles badprofile.json", {}, 1, "a profile must be an object"),
    ("serve --time-limit -1", {}, 2, "--time-limit: must be a positive number, not -1"),
    ("serve --time-limit 0", {}, 2, "--time-limit: must be a positive number, not 0"),
    ("serve --time-limit 61", {}, 2, "--time-limit: 61 s is above the service's maximum of 60"),
    ("serve --max-speed -5", {}, 2, "--max-speed: must be a positive number"),
    ("submit nope.json", {}, 1, "cannot read"),
    ("submit list.json", {}, 1, "must hold a JSON/YAML object"),
    ("submit obj.json", {}, 1, "no TST found"),
    ("submit badparam.json", {}, 1, "params.speed: 'quick' is not one of"),
    ("submit typo.json", {}, 1, "unknown task 'serach-area'"),
    ("submit free.json --time-limit -3 --strategy optimal", {}, 2, "--time-limit"),
    ("submit free.json --speedup 0", {}, 2, "--speedup: must be a positive number"),
    ("validate", {}, 2, "FILE"),
    ("validate free.yaml", {}, 0, ""),  # YAML, as submit and plan read it (B11)
    (f"validate {DEMO}", {}, 0, ""),  # a scenario: checked as one (B11)
    ("validate nodesc.yaml", {}, 0, ""),  # description is optional (B10)
    ("plan nodesc.yaml", {}, 0, ""),
    # new commands and flags
    ("serve --log-level loud", {}, 2, "--log-level: invalid choice: 'loud'"),
    ("missions --status lost", {}, 2, "--status: invalid choice: 'lost'"),
    ("status", {}, 2, "ID"),
    ("signal abc '$stop'", {}, 2, "invalid choice: '$stop'"),
    ("follow abc --timeout 0", {}, 2, "--timeout: must be a positive number"),
    ("completion fish", {}, 2, "invalid choice: 'fish'"),
    ("status abc --port {closed}", {}, 1, "cannot connect"),
    ("bids nope.json", {}, 1, "cannot read"),
]


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("operator")
    (d / "free.json").write_text(json.dumps(FREE))
    (d / "free.yaml").write_text(yaml.safe_dump(FREE))
    (d / "nodesc.yaml").write_text(yaml.safe_dump({
        "name": "tiny", "mission": FREE, "agents": [{
            "name": "dji0", "type": "air", "tasks": ["move-to"],
            "position": {"latitude": 57.76, "longitude": 16.68}}]}))
    (d / "badparam.json").write_text(json.dumps(BADPARAM))
    (d / "typo.json").write_text(json.dumps(TYPO))
    (d / "list.json").write_text("[1, 2]")
    (d / "controls.json").write_text(json.dumps(
        {"name": "seq", "children": [{"name": "conc", "children": []}] * 2}))
    (d / "command.json").write_text(json.dumps({"command": "start-tst", "com-uuid": "c1",
                                                "tst": FREE}))
    (d / "badprofile.json").write_text(json.dumps({"dji0": {"speeds": {}}, "ugv": 3}))
    (d / "obj.json").write_text('{"a": 1}')
    (d / "bad.yaml").write_text("name: [x\nagents:\n")
    (d / "scenarios").mkdir()
    (d / "impossible.yaml").write_text((ROOT / "scenarios" / "granso-impossible.yaml").read_text())
    return d


def run_cli(args: str, env: dict[str, str], cwd: Path, timeout: float = 60.0
            ) -> subprocess.CompletedProcess[str]:
    full = {k: v for k, v in os.environ.items() if not k.startswith("WARAPS_")}
    full.update(env)
    full["PYTHONPATH"] = str(ROOT / "src")
    full["COLUMNS"] = "80"
    return cli_forks.run(shlex.split(args), full, cwd, timeout)  # as a shell would split it


@pytest.fixture(scope="module")
def closed_port() -> int:
    return free_port(LOOPBACK)


@pytest.mark.parametrize(("args", "env", "code", "says"), CASES,
                         ids=[c[0] or "(nothing)" for c in CASES])
def test_wrong_invocation(args: str, env: dict[str, str], code: int, says: str, workdir: Path,
                          closed_port: int) -> None:
    values = {"closed": str(closed_port)}
    args, says = args.format(**values), says.format(**values)
    result = run_cli(args, env, workdir)
    output = result.stdout + result.stderr
    assert result.returncode == code, output
    assert "Traceback" not in output
    assert says in result.stderr or (not says), result.stderr
    if code == 2 and args:
        assert len(result.stderr.strip().splitlines()) == 1, result.stderr  # one line


@pytest.mark.mqtt
def test_submit_to_a_service_that_is_not_there(workdir: Path, mqtt_settings: Any) -> None:
    result = run_cli(f"submit free.json --service delegator9 --wait 1 --port {mqtt_settings.port}",
                     {}, workdir)
    assert result.returncode == 1
    assert "no heartbeat from 'delegator9'" in result.stderr
    assert "Traceback" not in result.stderr


@pytest.mark.mqtt
def test_tls_against_a_plain_port_names_tls(workdir: Path, mqtt_settings: Any) -> None:
    """A TLS client on a plain MQTT port sees the connection reset: the error says it was the
    TLS handshake and that the port may be plain, not just "Connection reset by peer"."""
    port = mqtt_settings.port
    result = run_cli(f"agents --broker 127.0.0.1 --tls --port {port} --wait 2", {}, workdir)
    assert result.returncode == 1, result.stdout + result.stderr
    assert "Traceback" not in result.stderr
    line = result.stderr.strip()
    assert len(line.splitlines()) == 1, line
    assert f"cannot connect to mqtts://127.0.0.1:{port}: the TLS handshake failed" in line
    assert f"is port {port} a plain MQTT port?" in line
