"""``--transport`` on the command line: ROS 2 without the extra is one line and exit 2 (no
traceback), a bad ``WARAPS_TRANSPORT`` is a usage error; every command that joins a broker has
the flag."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from delegation.cli import build_parser

#: Runs the CLI with rclpy made unimportable (what a machine without the [ros2] extra sees).
_WITHOUT_ROS = (
    "import sys; sys.modules['rclpy'] = None; from delegation.cli import main; "
    "sys.exit(main(sys.argv[1:]))"
)


def _run(*argv: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-c", _WITHOUT_ROS, *argv], capture_output=True, text=True,
        timeout=60, env={**os.environ, **(env or {})},
    )


@pytest.mark.parametrize("argv", [
    ["agents", "--transport", "ros2", "--wait", "0.1"],
    ["engine", "--transport", "ros2"],
])
def test_ros2_without_the_extra_says_how_to_install_it(argv: list[str]) -> None:
    done = _run(*argv)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert "pip install 'delegation[ros2]'" in lines[0]
    assert "Traceback" not in done.stderr


def test_the_environment_can_choose_the_transport() -> None:
    done = _run("agents", "--wait", "0.1", env={"WARAPS_TRANSPORT": "ros2"})
    assert done.returncode == 2 and "delegation[ros2]" in done.stderr
    bad = _run("agents", "--wait", "0.1", env={"WARAPS_TRANSPORT": "carrier-pigeon"})
    assert bad.returncode == 2 and "WARAPS_TRANSPORT" in bad.stderr


@pytest.mark.parametrize("command", ["serve", "engine", "sim", "demo", "submit", "agents",
                                     "missions", "ui"])
def test_every_command_that_joins_a_broker_takes_the_flag(command: str) -> None:
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    commands = sub.choices  # type: ignore[attr-defined]
    target = commands[command]
    nested = [a for a in target._actions if a.dest in ("missions_command", "action")]
    parsers = [target] if not nested else list(nested[0].choices.values())  # type: ignore[union-attr]
    for p in parsers:
        assert any("--transport" in a.option_strings for a in p._actions), (command, p.prog)
