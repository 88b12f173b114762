"""Broker settings: where the broker is and how to log in (the ``WARAPS_*`` environment)."""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from delegation.errors import DelegationError

Protocol = Literal["auto", "5", "3.1.1"]
#: How units talk: an MQTT broker, or ROS 2 topics (`delegation.runtime.ros2`, docs/ros2.md).
Transport = Literal["mqtt", "ros2"]


def _env_flag(value: str | None) -> bool:
    return (value or "").strip().lower() in ("1", "true", "yes", "on")


class SettingsError(DelegationError):
    """Broker settings that cannot work (a missing key file, an unreadable password file)."""


def read_password_file(path: str) -> str:
    """The password in ``path``: its first line, without the line end (so that a secret never
    has to appear on a command line, where ``ps`` shows it)."""
    try:
        with open(path, encoding="utf-8") as f:
            return f.readline().rstrip("\r\n")
    except (OSError, UnicodeDecodeError) as exc:
        raise SettingsError(f"cannot read the password file {path!r}: {exc}") from None


class BrokerSettings(BaseModel):
    """Where the broker is and how to log in (WARA-PS example agents' ``WARAPS_*`` names).

    ``protocol="auto"`` connects with MQTT v5 and falls back to 3.1.1 only when the broker answers
    "unsupported protocol version" (amqtt 0.12 speaks 3.1.1 only); the choice is logged.
    """

    model_config = ConfigDict(frozen=True)

    host: str = "127.0.0.1"
    port: int = Field(default=1883, ge=1, le=65535)
    tls: bool = False
    username: str = ""
    password: str = Field(default="", repr=False)
    protocol: Protocol = "auto"
    keepalive: int = Field(default=30, ge=5)
    #: CA bundle to verify the broker's certificate with; None: the system's trusted CAs.
    ca_certs: str | None = None
    #: Client certificate and its key (PEM) for brokers that ask for one (``require_certificate``).
    certfile: str | None = None
    keyfile: str | None = None
    #: ``ros2``: the same JSON on ROS 2 topics (the domain from ``ROS_DOMAIN_ID``, DDS settings
    #: from ``FASTDDS_DEFAULT_PROFILES_FILE``); host, port, TLS and login are then unused.
    transport: Transport = "mqtt"

    @classmethod
    def from_env(cls, environ: Mapping[str, str] | None = None) -> BrokerSettings | None:
        """Settings from ``WARAPS_BROKER`` and friends; None when no broker is configured."""
        env = os.environ if environ is None else environ
        host = (env.get("WARAPS_BROKER") or "").strip()
        if not host:
            return None
        password = env.get("WARAPS_PASSWORD", "")
        if not password and env.get("WARAPS_PASSWORD_FILE"):
            password = read_password_file(env["WARAPS_PASSWORD_FILE"])
        return cls.from_values(
            host=host,
            port=env.get("WARAPS_PORT"),
            tls=_env_flag(env.get("WARAPS_TLS_CONNECTION")),
            username=env.get("WARAPS_USERNAME", ""),
            password=password,
            ca_certs=env.get("WARAPS_CA_FILE") or None,
            certfile=env.get("WARAPS_CERT_FILE") or None,
            keyfile=env.get("WARAPS_KEY_FILE") or None,
        )

    @classmethod
    def from_values(
        cls,
        host: str,
        port: int | str | None = None,
        tls: bool = False,
        username: str | None = "",
        password: str | None = "",
        protocol: Protocol = "auto",
        ca_certs: str | None = None,
        certfile: str | None = None,
        keyfile: str | None = None,
    ) -> BrokerSettings:
        """Settings from CLI-like values: an empty or zero port means the default for ``tls``.

        A CA file or a client certificate implies TLS; a certificate needs its key (and the
        files must be readable now, so a typo fails at start with the path named).
        """
        tls = tls or bool(ca_certs or certfile)
        if (certfile is None) != (keyfile is None):
            raise SettingsError("a client certificate needs both a certificate and a key file")
        for label, path in (("CA file", ca_certs), ("certificate", certfile), ("key", keyfile)):
            if path is not None and not os.access(path, os.R_OK):
                raise SettingsError(f"{label} {path!r} is not a readable file")
        port_value = int(port) if port not in (None, "", "0", 0) else (8883 if tls else 1883)
        return cls(
            host=host,
            port=port_value,
            tls=tls,
            username=username or "",
            password=password or "",
            protocol=protocol,
            ca_certs=ca_certs,
            certfile=certfile,
            keyfile=keyfile,
        )

    def describe(self) -> str:
        """host:port for logs (never the password)."""
        if self.transport == "ros2":
            return f"ROS 2 domain {os.environ.get('ROS_DOMAIN_ID') or 0}"
        scheme = "mqtts" if self.tls else "mqtt"
        return f"{scheme}://{self.host}:{self.port}"
