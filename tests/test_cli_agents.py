"""``delegation agents`` ends within its ``--wait`` even when the broker never answers."""

from __future__ import annotations

import os
import socket
import time

import pytest

import cli_forks


@pytest.mark.slow  # a fresh process waits out its bound
def test_agents_against_a_silent_broker_is_bounded_by_wait() -> None:
    # A loopback socket that completes TCP handshakes (the kernel's backlog) and never speaks
    # MQTT: the client waits for a CONNACK that never comes.
    with socket.socket() as silent:
        silent.bind(("127.0.0.1", 0))
        silent.listen(8)
        port = silent.getsockname()[1]
        started = time.monotonic()
        done = cli_forks.run(  # a process of its own, forked with the CLI imported
            ["agents", "--broker", "127.0.0.1", "--port", str(port), "--wait", "1"],
            dict(os.environ), timeout=30)
        took = time.monotonic() - started
    assert done.returncode == 1, done.stderr
    assert done.stderr.strip().startswith("error: cannot connect to mqtt://127.0.0.1"), done.stderr
    assert "Traceback" not in done.stderr
    # The bound is the point (the default connect timeout is 10 s): well under it, with slack
    # for interpreter start-up on a loaded machine.
    assert took < 8.0, f"agents --wait 1 took {took:.1f} s"
