"""TLS and username/password against a private mosquitto with a self-signed certificate."""

from __future__ import annotations

import argparse
import contextlib
import queue
import shutil
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from delegation.cli.connect import add_broker_args, broker_settings
from delegation.runtime.broker import PrivateMosquitto, mosquitto_binary
from delegation.runtime.mqtt import MqttClient, MqttConnectError
from delegation.runtime.settings import BrokerSettings, SettingsError
from pki import Pki, make_password_file, make_pki, self_signed

pytestmark = [
    pytest.mark.mqtt,
    pytest.mark.skipif(
        mosquitto_binary() is None
        or shutil.which("openssl") is None
        or shutil.which("mosquitto_passwd") is None,
        reason="needs mosquitto, mosquitto_passwd and openssl",
    ),
]


@pytest.fixture(scope="module")
def secure_broker(
    tmp_path_factory: pytest.TempPathFactory,
) -> Iterator[tuple[PrivateMosquitto, Path]]:
    d = tmp_path_factory.mktemp("tls")
    cert, key = self_signed(d)
    passwords = d / "passwords"
    subprocess.run(
        ["mosquitto_passwd", "-c", "-b", str(passwords), "agent", "s3cret"],
        check=True,
        capture_output=True,
    )
    broker = PrivateMosquitto(certfile=str(cert), keyfile=str(key), password_file=str(passwords))
    broker.start()
    try:
        yield broker, cert
    finally:
        broker.stop()


def test_tls_with_credentials(secure_broker: tuple[PrivateMosquitto, Path]) -> None:
    broker, cert = secure_broker
    env = {
        "WARAPS_BROKER": "127.0.0.1",
        "WARAPS_PORT": str(broker.port),
        "WARAPS_TLS_CONNECTION": "TRUE",
        "WARAPS_USERNAME": "agent",
        "WARAPS_PASSWORD": "s3cret",
    }
    settings = BrokerSettings.from_env(env)
    assert settings is not None
    client = MqttClient(settings.model_copy(update={"ca_certs": str(cert)}))
    client.subscribe("secure/#")
    client.connect()
    try:
        deadline = time.monotonic() + 10
        got = None
        while got is None and time.monotonic() < deadline:
            client.publish("secure/x", b"1", qos=1)
            try:
                got = client.messages.get(timeout=0.5)
            except queue.Empty:
                got = None
        assert got is not None and got.payload == b"1"
        assert client.protocol_version is not None and int(client.protocol_version) == 5
    finally:
        client.disconnect()


def test_wrong_password_is_refused(secure_broker: tuple[PrivateMosquitto, Path]) -> None:
    broker, cert = secure_broker
    settings = BrokerSettings(
        host="127.0.0.1", port=broker.port, tls=True, ca_certs=str(cert), username="agent",
        password="wrong",
    )  # fmt: skip
    with pytest.raises(MqttConnectError, match="cannot connect"):
        MqttClient(settings).connect(timeout=5)


def test_untrusted_certificate_is_refused(secure_broker: tuple[PrivateMosquitto, Path]) -> None:
    broker, _ = secure_broker
    settings = BrokerSettings(
        host="127.0.0.1", port=broker.port, tls=True, username="agent", password="s3cret"
    )
    with pytest.raises(MqttConnectError, match=r"(?i)certificate"):
        MqttClient(settings).connect(timeout=5)


# ---- a private CA, client certificates, a password file and an ACL (issue 11)


@pytest.fixture(scope="module")
def ca_broker(
    tmp_path_factory: pytest.TempPathFactory,
) -> Iterator[tuple[PrivateMosquitto, Pki, Path]]:
    """TLS with a private CA and required client certificates, passwords, and an ACL."""
    d = tmp_path_factory.mktemp("ca")
    pki = make_pki(d)
    passwords = make_password_file(d / "passwords", {"agent": "s3cret", "other": "pw2"})
    acl = d / "acl"
    acl.write_text("user agent\ntopic readwrite agent/#\n\nuser other\ntopic read agent/#\n")
    secret = d / "secret"
    secret.write_text("s3cret\n")
    broker = PrivateMosquitto(
        certfile=str(pki.server_cert), keyfile=str(pki.server_key), cafile=str(pki.ca),
        require_certificate=True, password_file=str(passwords), acl_file=str(acl),
    )  # fmt: skip
    broker.start()
    try:
        yield broker, pki, secret
    finally:
        broker.stop()


def _round_trip(client: MqttClient, topic: str, timeout: float = 5.0) -> bool:
    """True once a message published on ``topic`` comes back to the same client."""
    client.subscribe(topic)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        client.publish(topic, b"1", qos=1)
        try:
            if client.messages.get(timeout=0.5).topic == topic:
                return True
        except queue.Empty:
            continue
    return False


def test_ca_file_client_certificate_and_password_file_from_env(
    ca_broker: tuple[PrivateMosquitto, Pki, Path],
) -> None:
    broker, pki, secret = ca_broker
    env = {
        "WARAPS_BROKER": "127.0.0.1",
        "WARAPS_PORT": str(broker.port),
        "WARAPS_CA_FILE": str(pki.ca),
        "WARAPS_CERT_FILE": str(pki.client_cert),
        "WARAPS_KEY_FILE": str(pki.client_key),
        "WARAPS_USERNAME": "agent",
        "WARAPS_PASSWORD_FILE": str(secret),
    }
    settings = BrokerSettings.from_env(env)
    assert settings is not None and settings.tls and settings.password == "s3cret"
    client = MqttClient(settings)
    client.connect()
    try:
        assert _round_trip(client, "agent/x")
    finally:
        client.disconnect()


def test_acl_refuses_a_topic_outside_the_users_grant(
    ca_broker: tuple[PrivateMosquitto, Pki, Path],
) -> None:
    broker, pki, _ = ca_broker
    base = BrokerSettings.from_values(
        "127.0.0.1", broker.port, ca_certs=str(pki.ca), certfile=str(pki.client_cert),
        keyfile=str(pki.client_key), username="other", password="pw2",
    )  # fmt: skip
    watcher = MqttClient(base.model_copy(update={"username": "agent", "password": "s3cret"}))
    other = MqttClient(base)
    watcher.subscribe("agent/#")
    watcher.connect()
    other.connect()
    try:
        assert _round_trip(watcher, "agent/probe")  # the watcher's subscription is active
        other.publish("agent/forged", b"x", qos=1)  # read-only for "other": dropped by the ACL
        watcher.publish("agent/after", b"y", qos=1)
        seen: list[str] = []
        deadline = time.monotonic() + 5
        while "agent/after" not in seen and time.monotonic() < deadline:
            with contextlib.suppress(queue.Empty):
                seen.append(watcher.messages.get(timeout=0.5).topic)
        assert "agent/after" in seen and "agent/forged" not in seen
    finally:
        other.disconnect()
        watcher.disconnect()


def test_no_client_certificate_is_refused(ca_broker: tuple[PrivateMosquitto, Pki, Path]) -> None:
    broker, pki, _ = ca_broker
    settings = BrokerSettings.from_values(
        "127.0.0.1", broker.port, ca_certs=str(pki.ca), username="agent", password="s3cret"
    )
    with pytest.raises(MqttConnectError, match="cannot connect"):
        MqttClient(settings).connect(timeout=2)  # refused: no CONNACK ever comes


def test_cli_helper_reads_ca_cert_key_and_password_file(
    ca_broker: tuple[PrivateMosquitto, Pki, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    _, pki, secret = ca_broker
    for var in ("WARAPS_BROKER", "WARAPS_PASSWORD", "WARAPS_PASSWORD_FILE", "WARAPS_CA_FILE"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("WARAPS_CERT_FILE", str(pki.client_cert))
    monkeypatch.setenv("WARAPS_KEY_FILE", str(pki.client_key))
    parser = argparse.ArgumentParser()
    add_broker_args(parser)
    args = parser.parse_args(
        [
            "--broker",
            "127.0.0.1",
            "--ca-file",
            str(pki.ca),
            "--username",
            "agent",
            "--password-file",
            str(secret),
        ]
    )
    settings = broker_settings(args)
    assert settings is not None
    assert (settings.tls, settings.ca_certs, settings.certfile, settings.password) == (
        True,
        str(pki.ca),
        str(pki.client_cert),
        "s3cret",
    )
    assert settings.port == 8883 and "s3cret" not in repr(settings)
    assert "--password " not in parser.format_help()
    with pytest.raises(SettingsError, match="not a readable file"):
        BrokerSettings.from_values("h", ca_certs=str(pki.ca) + ".missing")
