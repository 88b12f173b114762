"""docs/deployment.md's ``console`` blocks, run in order as one shell session against a private
mosquitto: each command must exit 0, or the code its ``# exit N`` comment names.

The simulated fleet flies at ``--speedup 50`` here, not the doc's 10 (the doc's pace is for a
person watching; the commands and what they must answer are the same), and ``submit`` gives up
following its open-ended mission after 1 s, not the doc's 3 s and 2 s (the exit code is the same:
the timeout starts once the mission has started). The one-shot commands are forked from a
process that imported the CLI once (`cli_forks.relay`), the long-running ones started as the doc
starts them."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

import cli_forks
from delegation.runtime.broker import PrivateMosquitto, mosquitto_binary

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "deployment.md"

pytestmark = [
    pytest.mark.mqtt,
    pytest.mark.slow,
    pytest.mark.skipif(mosquitto_binary() is None, reason="no mosquitto binary"),
]


#: What the test runs faster than the doc says: (as written, as run).
FASTER = [("--speedup 10", "--speedup 50"), ("--timeout 3 ", "--timeout 1 "),
          ("--timeout 2 ", "--timeout 1 ")]


def console_commands(text: str) -> list[tuple[str, int]]:
    """(command, expected exit code) for every ``$ `` line of every ``console`` block."""
    out = []
    for block in re.findall(r"```console\n(.*?)```", text, re.S):
        for line in block.splitlines():
            if line.startswith("$ "):
                command = line[2:].strip()
                for written, run in FASTER:
                    command = command.replace(written, run)
                m = re.search(r"#\s*exit (\d+)\s*$", command)
                out.append((command, int(m.group(1)) if m else 0))
    return out


def script(commands: list[tuple[str, int]]) -> str:
    lines = [
        "set -u",
        "trap 'kill $(jobs -p) 2>/dev/null; wait' EXIT",
    ]
    for i, (command, code) in enumerate(commands):
        if command.endswith("&"):
            lines.append(command)
            continue
        lines += [
            f"echo '>>> step {i}: '{shlex.quote(command)}",
            command,
            f'rc=$?; if [ "$rc" -ne {code} ]; then '
            f"echo 'FAILED step {i} (exit '$rc', wanted {code}): '{shlex.quote(command)} >&2; "
            "exit 1; fi",
        ]
    return "\n".join(lines) + "\n"


def test_the_doc_has_commands_to_check() -> None:
    commands = [c for c, _ in console_commands(DOC.read_text())]
    for needed in ("delegation serve", "delegation missions", "delegation status",
                   "delegation follow", "delegation cancel", "delegation signal",
                   "delegation bids", "delegation plan", "delegation completion"):
        assert any(c.startswith(needed) or f" {needed}" in c for c in commands), needed


#: The commands that run until stopped (started with ``&``): a process of their own.
LONG_RUNNING = ("engine", "sim", "serve")


def wrapper_script(relayed: list[str]) -> str:
    """``delegation`` as this checkout's: the long-running commands exec'd so that the script's
    ``kill`` reaches them, the one-shot ones forked by `cli_forks` (the CLI imported once)."""
    python = shlex.quote(sys.executable)
    return (f'#!/bin/sh\ncase "$1" in {"|".join(LONG_RUNNING)}) '
            f'exec {python} -m delegation "$@";; esac\n'
            f'exec {shlex.join(relayed)} "$@"\n')


def test_every_long_running_command_is_started_in_the_background() -> None:
    for command, _ in console_commands(DOC.read_text()):
        name = command.split()[1] if command.startswith("delegation ") else ""
        assert (name in LONG_RUNNING) == command.endswith("&"), command


def test_documented_commands_run(mosquitto: PrivateMosquitto, tmp_path: Path) -> None:
    with cli_forks.relay(tmp_path / "cli.sock") as relayed:
        _run_the_doc(mosquitto, tmp_path, relayed)


def _run_the_doc(mosquitto: PrivateMosquitto, tmp_path: Path, relayed: list[str]) -> None:
    wrapper = tmp_path / "delegation"
    wrapper.write_text(wrapper_script(relayed))
    wrapper.chmod(0o755)
    env = {k: v for k, v in os.environ.items() if not k.startswith("WARAPS_")}
    env.update(WARAPS_BROKER="127.0.0.1", WARAPS_PORT=str(mosquitto.settings().port),
               PYTHONPATH=str(ROOT / "src"), COLUMNS="100",
               PATH=f"{tmp_path}{os.pathsep}{os.environ.get('PATH', '')}",
               XDG_STATE_HOME=str(tmp_path / "state"))  # serve's store: not the user's
    result = subprocess.run(["bash", "-c", script(console_commands(DOC.read_text()))], cwd=ROOT,
                            env=env, capture_output=True, text=True, timeout=300,
                            stdin=subprocess.DEVNULL)
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-4000:]
    assert "succeeded" in result.stdout and "aborted" in result.stdout
