"""How every command that joins a broker reads where and as whom: ``--broker``/``--port``/TLS/login
flags over the ``WARAPS_*`` environment, like the WARA-PS example agents."""

from __future__ import annotations

import argparse
import os
from typing import TYPE_CHECKING

from delegation.cli.options import UsageError, env_flag, env_port, port_number, positive_float

if TYPE_CHECKING:
    from delegation.runtime.client import ServiceClient
    from delegation.runtime.settings import BrokerSettings


def add_broker_args(parser: argparse.ArgumentParser) -> None:
    """``--broker/--port/--tls/--ca-file/--cert-file/--key-file/--username/--password-file``,
    defaulting to ``WARAPS_*``; a password never has to be given on the command line."""
    g = parser.add_argument_group("broker (defaults from WARAPS_* environment variables)")
    g.add_argument(
        "--transport", choices=("mqtt", "ros2"), default=None,
        help="mqtt: a broker (the default); ros2: ROS 2 topics /<name>/<prefix>/<suffix> in the "
        "domain ROS_DOMAIN_ID, needs the [ros2] extra (docs/ros2.md) [WARAPS_TRANSPORT]",
    )
    g.add_argument(
        "--broker", default=None, metavar="HOST",
        help="MQTT broker host [WARAPS_BROKER, else 127.0.0.1]",
    )
    g.add_argument("--port", default=None, type=port_number,
                   help="broker port [WARAPS_PORT, 1883 or 8883 with TLS]")
    g.add_argument(
        "--tls", action="store_true", default=None, help="connect with TLS [WARAPS_TLS_CONNECTION]"
    )
    g.add_argument(
        "--ca-file",
        default=None,
        metavar="PEM",
        help="CA to verify the broker with (implies --tls) [WARAPS_CA_FILE]",
    )
    g.add_argument(
        "--cert-file",
        default=None,
        metavar="PEM",
        help="client certificate (implies --tls) [WARAPS_CERT_FILE]",
    )
    g.add_argument(
        "--key-file", default=None, metavar="PEM", help="client certificate's key [WARAPS_KEY_FILE]"
    )
    g.add_argument("--username", default=None, help="[WARAPS_USERNAME]")
    g.add_argument(
        "--password-file",
        default=None,
        metavar="FILE",
        help="file whose first line is the password [WARAPS_PASSWORD_FILE; or the "
        "password itself in WARAPS_PASSWORD]",
    )
    g.add_argument("--password", default=None, help=argparse.SUPPRESS)  # visible in ps: avoid
    g.add_argument("--prefix", default="waraps", help="first topic level (default: waraps)")


def add_service_args(parser: argparse.ArgumentParser) -> None:
    """``--service`` and ``--wait``: the running delegation service a command talks to (with the
    broker flags, `service_client`)."""
    parser.add_argument("--service", default="delegator0", help="the service's unit name")
    parser.add_argument("--wait", type=positive_float, default=10.0,
                        help="seconds to wait for the service's heartbeat (default 10)")


def service_client(args: argparse.Namespace) -> ServiceClient:
    """A client of the service `add_service_args` named, on the broker of `client_settings`
    (not started)."""
    from delegation.runtime.client import ServiceClient

    return ServiceClient(client_settings(args), prefix=args.prefix, service=args.service,
                         service_timeout=args.wait)


def broker_settings(args: argparse.Namespace) -> BrokerSettings | None:
    """Flags over environment; None when neither names a broker host (``demo`` then starts its
    own). Bad ``WARAPS_*`` values are a `UsageError` naming the variable. On ROS 2 there is no
    broker to start: the settings are returned."""
    if transport(args) == "ros2":
        return client_settings(args)
    host = args.broker or (os.environ.get("WARAPS_BROKER") or "").strip()
    if not host:
        return None
    return client_settings(args)


def client_settings(args: argparse.Namespace) -> BrokerSettings:
    """The one rule for every command that joins a broker: ``--broker``, else ``WARAPS_BROKER``,
    else 127.0.0.1 (like ``mosquitto_sub``); port, TLS (CA file, client certificate and key) and
    login (the password from a file, never needed on the command line) from flags over
    ``WARAPS_*``."""
    from delegation.runtime.settings import BrokerSettings, read_password_file

    env = os.environ
    host = args.broker or (env.get("WARAPS_BROKER") or "").strip() or "127.0.0.1"
    tls = args.tls if args.tls is not None else bool(env_flag(env, "WARAPS_TLS_CONNECTION"))
    port = args.port or env_port(env) or None
    username = args.username if args.username is not None else env.get("WARAPS_USERNAME", "")
    if getattr(args, "password_file", None):
        password = read_password_file(args.password_file)
    elif getattr(args, "password", None) is not None:
        password = args.password
    elif env.get("WARAPS_PASSWORD"):
        password = env["WARAPS_PASSWORD"]
    elif env.get("WARAPS_PASSWORD_FILE"):
        password = read_password_file(env["WARAPS_PASSWORD_FILE"])
    else:
        password = ""

    def pick(flag: str, variable: str) -> str | None:
        value = getattr(args, flag, None)
        return str(value) if value else (env.get(variable) or None)

    settings = BrokerSettings.from_values(
        host=host,
        port=port,
        tls=bool(tls),
        username=username,
        password=password,
        ca_certs=pick("ca_file", "WARAPS_CA_FILE"),
        certfile=pick("cert_file", "WARAPS_CERT_FILE"),
        keyfile=pick("key_file", "WARAPS_KEY_FILE"),
    )
    if transport(args) == "mqtt":
        return settings
    require_ros2()
    return settings.model_copy(update={"transport": "ros2"})


def require_ros2() -> None:
    """A `UsageError` (one line: how to install it; exit 2) where the ``[ros2]`` extra is
    missing."""
    from delegation.runtime.transport import ROS2_INSTALL, ros2_missing

    missing = ros2_missing()
    if missing is not None:
        raise UsageError(f"{ROS2_INSTALL} [{missing}]")


def transport(args: argparse.Namespace) -> str:
    """``--transport``, else ``WARAPS_TRANSPORT``, else ``mqtt``; a `UsageError` for others."""
    value = getattr(args, "transport", None) or (os.environ.get("WARAPS_TRANSPORT") or "").strip()
    value = value.lower() or "mqtt"
    if value not in ("mqtt", "ros2"):
        raise UsageError(f"WARAPS_TRANSPORT: {value!r} is not mqtt or ros2")
    return value
