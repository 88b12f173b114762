"""TLS and username/password against a private mosquitto with a self-signed certificate."""

from __future__ import annotations

import queue
import shutil
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from delegation.runtime.broker import PrivateMosquitto, mosquitto_binary
from delegation.runtime.mqtt import MqttClient, MqttConnectError
from delegation.runtime.settings import BrokerSettings

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
    cert, key, passwords = d / "cert.pem", d / "key.pem", d / "passwords"
    subprocess.run(
        [
            "openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1",
            "-subj", "/CN=127.0.0.1", "-addext", "subjectAltName=IP:127.0.0.1",
            "-keyout", str(key), "-out", str(cert),
        ],
        check=True,
        capture_output=True,
    )  # fmt: skip
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
