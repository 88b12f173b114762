"""The brokers we start ourselves: loopback only, free port, clean start and stop."""

from __future__ import annotations

import logging
import socket
import sys
import time
from pathlib import Path

import pytest

from delegation.runtime.broker import (
    BrokerError,
    BrokerProcess,
    EmbeddedBroker,
    PrivateMosquitto,
    free_port,
    mosquitto_binary,
)
from delegation.runtime.mqtt import MqttClient


def _listening_addresses(port: int) -> set[str]:
    """Local addresses with a TCP listener on ``port`` (from /proc/net/tcp)."""
    found = set()
    with open("/proc/net/tcp") as f:
        for line in f.readlines()[1:]:
            local, state = line.split()[1], line.split()[3]
            addr_hex, port_hex = local.split(":")
            if int(port_hex, 16) == port and state == "0A":  # LISTEN
                found.add(socket.inet_ntoa(bytes.fromhex(addr_hex)[::-1]))
    return found


@pytest.mark.mqtt
def test_embedded_broker_binds_loopback_and_accepts_clients() -> None:
    with EmbeddedBroker() as broker:
        assert broker.port > 0
        assert _listening_addresses(broker.port) == {"127.0.0.1"}
        client = MqttClient(broker.settings())
        client.connect()
        assert client.connected.is_set()
        client.disconnect()
    with pytest.raises(OSError), socket.create_connection(("127.0.0.1", broker.port), timeout=1):
        pass


def test_embedded_broker_refuses_other_interfaces() -> None:
    with pytest.raises(BrokerError, match="loopback"):
        EmbeddedBroker(host="0.0.0.0")


@pytest.mark.mqtt
@pytest.mark.skipif(mosquitto_binary() is None, reason="no mosquitto binary")
def test_private_mosquitto_starts_and_stops() -> None:
    broker = PrivateMosquitto().start()
    try:
        assert broker.running
        assert _listening_addresses(broker.port) == {"127.0.0.1"}
        client = MqttClient(broker.settings())
        client.connect()
        assert client.protocol_version is not None and int(client.protocol_version) == 5
        client.disconnect()
    finally:
        broker.stop()
    assert not broker.running
    broker.stop()  # idempotent


def test_free_port_is_bindable() -> None:
    port = free_port()
    with socket.socket() as s:
        s.bind(("127.0.0.1", port))


def test_stable_free_port_is_outside_the_ephemeral_range() -> None:
    text = Path("/proc/sys/net/ipv4/ip_local_port_range").read_text()
    lo, hi = (int(x) for x in text.split())
    port = free_port(stable=True)
    assert not lo <= port <= hi
    with socket.socket() as s:
        s.bind(("127.0.0.1", port))


@pytest.mark.mqtt
def test_broker_process_carries_messages_and_stops() -> None:
    """The demo's embedded broker in its own process: loopback only, messages go through, and
    stop ends the child."""
    import threading

    from delegation.runtime.broker import BrokerProcess

    broker = BrokerProcess().start()
    try:
        assert broker.running
        assert _listening_addresses(broker.port) == {"127.0.0.1"}
        got = threading.Event()
        sub = MqttClient(broker.settings(), sink=lambda msg: got.set())
        sub.connect()
        sub.subscribe("t/x", 1)
        pub = MqttClient(broker.settings())
        pub.connect()
        # The SUBSCRIBE is not acknowledged before subscribe() returns, and the two clients'
        # packets reach the broker on two connections: publish until one arrives (bounded).
        deadline = time.monotonic() + 10.0
        while not got.is_set():
            assert time.monotonic() < deadline, "nothing went through the broker in 10 s"
            pub.publish("t/x", b"hello", qos=1)
            got.wait(0.2)
        pub.disconnect()
        sub.disconnect()
    finally:
        broker.stop()
    assert not broker.running
    broker.stop()  # idempotent


def test_broker_process_refuses_other_interfaces() -> None:
    from delegation.runtime.broker import BrokerProcess

    with pytest.raises(BrokerError, match="loopback"):
        BrokerProcess(host="0.0.0.0")


@pytest.mark.slow  # broker and parent processes
@pytest.mark.mqtt
def test_broker_process_exits_when_its_parent_is_killed() -> None:
    """A parent killed with -9 cannot stop its broker: the child sees its stdin close and exits
    (waited on with a pidfd, not polled)."""
    import os
    import select
    import signal
    import subprocess
    import sys

    parent = subprocess.Popen(
        [sys.executable, "-c",
         "import sys, threading\n"
         "from delegation.runtime.broker import BrokerProcess\n"
         "b = BrokerProcess().start()\n"
         "print(b._proc.pid, flush=True)\n"
         "threading.Event().wait()\n"],
        stdout=subprocess.PIPE,
    )
    try:
        assert parent.stdout is not None
        ready, _, _ = select.select([parent.stdout], [], [], 20)
        assert ready, "the parent did not start its broker"
        child = int(parent.stdout.readline())
        fd = os.pidfd_open(child)
        try:
            parent.send_signal(signal.SIGKILL)
            parent.wait(10)
            readable, _, _ = select.select([fd], [], [], 15)
            assert readable, f"broker process {child} still running 15 s after its parent died"
        finally:
            os.close(fd)
    finally:
        if parent.poll() is None:
            parent.kill()
            parent.wait(10)
        if parent.stdout:
            parent.stdout.close()


class _ChattyChild(BrokerProcess):
    """A child that says its port, then writes 256 kB of errors (4x a pipe's buffer) and exits:
    it can exit only if somebody reads what it writes."""

    def _command(self) -> list[str]:
        script = ("import sys\nprint('port 1', flush=True)\n"
                  "for k in range(4096): sys.stderr.write(f'error {k}: ' + 'x' * 53 + '\\n')\n"
                  "sys.stderr.flush()\nprint('more on stdout', flush=True)\n")
        return [sys.executable, "-c", script]


def test_broker_process_output_is_drained_to_the_log(caplog: pytest.LogCaptureFixture) -> None:
    """Issue 23: the child's stderr was piped and never read; after ~64 kB it blocked."""
    caplog.set_level(logging.INFO, logger="delegation.runtime.broker")
    child = _ChattyChild().start()
    proc = child._proc
    assert proc is not None
    try:
        assert proc.wait(timeout=20.0) == 0  # never blocked on a full pipe
    finally:
        child.stop()
    said = [r.getMessage() for r in caplog.records if r.name == "delegation.runtime.broker"]
    assert any("error 4095: " in m for m in said), said[-3:]
    assert any("more on stdout" in m for m in said)
