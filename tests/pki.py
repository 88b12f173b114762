"""Test helpers: a private CA, server and client certificates (openssl) and a mosquitto password
file (mosquitto_passwd), all in a test's tmp directory."""

from __future__ import annotations

import shutil
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from delegation.runtime.broker import PrivateMosquitto
from delegation.runtime.settings import BrokerSettings

HAVE_TOOLS = all(shutil.which(t) for t in ("openssl", "mosquitto_passwd"))


def _run(*args: str) -> None:
    subprocess.run(list(args), check=True, capture_output=True, timeout=60)


@dataclass(frozen=True)
class Pki:
    ca: Path
    server_cert: Path
    server_key: Path
    client_cert: Path
    client_key: Path


def make_pki(d: Path) -> Pki:
    """A CA, a server certificate for 127.0.0.1 and a client certificate, both signed by it."""
    ca, ca_key = d / "ca.crt", d / "ca.key"
    _run(
        "openssl",
        "req",
        "-x509",
        "-newkey",
        "rsa:2048",
        "-nodes",
        "-days",
        "1",
        "-subj",
        "/CN=delegation test CA",
        "-keyout",
        str(ca_key),
        "-out",
        str(ca),
    )
    ext = d / "san.ext"
    ext.write_text("subjectAltName=IP:127.0.0.1\n")

    def signed(name: str, cn: str, extfile: Path | None) -> tuple[Path, Path]:
        key, csr, crt = d / f"{name}.key", d / f"{name}.csr", d / f"{name}.crt"
        _run(
            "openssl",
            "req",
            "-newkey",
            "rsa:2048",
            "-nodes",
            "-subj",
            f"/CN={cn}",
            "-keyout",
            str(key),
            "-out",
            str(csr),
        )
        extra = ["-extfile", str(extfile)] if extfile else []
        _run(
            "openssl",
            "x509",
            "-req",
            "-in",
            str(csr),
            "-CA",
            str(ca),
            "-CAkey",
            str(ca_key),
            "-CAcreateserial",
            "-days",
            "1",
            "-out",
            str(crt),
            *extra,
        )
        return crt, key

    server_cert, server_key = signed("server", "127.0.0.1", ext)
    client_cert, client_key = signed("client", "agent", None)
    return Pki(ca, server_cert, server_key, client_cert, client_key)


def make_password_file(path: Path, users: dict[str, str]) -> Path:
    """A mosquitto password file (PBKDF2-SHA512, written by mosquitto_passwd)."""
    first = True
    for user, password in users.items():
        args = ["mosquitto_passwd", "-b", str(path), user, password]
        if first:
            args.insert(1, "-c")
            first = False
        _run(*args)
    return path


def self_signed(d: Path) -> tuple[Path, Path]:
    """A self-signed certificate for 127.0.0.1 and its key (``cert.pem``, ``key.pem`` in ``d``)."""
    cert, key = d / "cert.pem", d / "key.pem"
    _run("openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1",
         "-subj", "/CN=127.0.0.1", "-addext", "subjectAltName=IP:127.0.0.1",
         "-keyout", str(key), "-out", str(cert))
    return cert, key


@contextmanager
def tls_mosquitto(d: Path) -> Iterator[BrokerSettings]:
    """A private mosquitto on TLS only (a self-signed certificate): client settings trusting it."""
    cert, key = self_signed(d)
    with PrivateMosquitto(certfile=str(cert), keyfile=str(key)) as broker:
        yield broker.settings().model_copy(update={"ca_certs": str(cert)})
