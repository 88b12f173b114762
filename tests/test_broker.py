"""The brokers we start ourselves: loopback only, free port, clean start and stop."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

from delegation.runtime.broker import (
    BrokerError,
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
