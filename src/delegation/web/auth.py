"""Who is asking the page: a users file of ``TOKEN NAME`` lines (docs/ui.md, "Auth").

The name is the ``sender`` of the caller's commands, so the service decides what each may do
(owners, ``--operator``) as it does over MQTT. Without a users file every request acts as the
server's own sender.
"""

from __future__ import annotations

import hmac
import ipaddress
import logging
from collections.abc import Iterator, Mapping
from pathlib import Path
from urllib.parse import urlsplit

from delegation.errors import InputError, InputProblem

log = logging.getLogger(__name__)

COOKIE = "delegation-token"


def _stamp(path: Path) -> tuple[int, int, int] | None:
    try:
        st = path.stat()
    except OSError:
        return None
    return st.st_ino, st.st_size, st.st_mtime_ns


class Users(Mapping[str, str]):
    """token -> name of a users file, as it was last read; `current` reads it again when it
    changed on disk (revoking a token is editing the file: no restart)."""

    def __init__(self, path: Path, tokens: Mapping[str, str],
                 stamp: tuple[int, int, int] | None) -> None:
        self.path = path
        self._tokens = dict(tokens)
        self._stamp = stamp

    def __getitem__(self, token: str) -> str:
        return self._tokens[token]

    def __iter__(self) -> Iterator[str]:
        return iter(self._tokens)

    def __len__(self) -> int:
        return len(self._tokens)

    def current(self) -> Users:
        """These users, or the file's new ones when it changed (one ``stat`` when it did not).
        A file that no longer reads lets nobody in (logged) until it is fixed."""
        stamp = _stamp(self.path)
        if stamp == self._stamp:
            return self
        try:
            fresh = read_users(self.path)
        except InputError as exc:
            log.error("ui: users file %s: %s; every token refused until it is fixed",
                      self.path, exc.fail_reason)
            return Users(self.path, {}, stamp)
        log.info("ui: users file %s read again: %d tokens", self.path, len(fresh))
        return fresh


def read_users(path: str | Path) -> Users:
    """token -> name from a users file (``#`` comments and blank lines ignored)."""
    stamp = _stamp(Path(path))
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise InputError(InputProblem(
            str(path), "", f"cannot read the users file: {exc}")) from None
    users: dict[str, str] = {}
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.split()
        if len(parts) != 2:
            raise InputError(InputProblem(f"{path}:{number}", "", "expected 'TOKEN NAME'"))
        token, name = parts
        if len(token) < 8:
            raise InputError(InputProblem(
                f"{path}:{number}", "", "a token needs 8 characters or more"))
        if token in users:
            raise InputError(InputProblem(f"{path}:{number}", "", "the same token twice"))
        users[token] = name
    if not users:
        raise InputError(InputProblem(str(path), "", "no users (lines 'TOKEN NAME')"))
    return Users(Path(path), users, stamp)


def user_of(users: Mapping[str, str], token: str | None) -> str | None:
    """The name for a token (compared in constant time), or None."""
    if not token:
        return None
    found = None
    for known, name in users.items():
        if hmac.compare_digest(known.encode(), token.encode()):
            found = name
    return found


def bearer(header: str | None) -> str | None:
    """The token of an ``Authorization: Bearer TOKEN`` header."""
    if not header:
        return None
    scheme, _, value = header.partition(" ")
    return value.strip() or None if scheme.lower() == "bearer" else None


def host_name(netloc: str) -> str:
    """``host`` of ``host:port`` / ``[v6]:port`` (lower case, brackets removed)."""
    parsed = urlsplit(f"//{netloc}")
    return (parsed.hostname or "").lower()


def is_loopback_name(host: str) -> bool:
    """``localhost``, 127.0.0.0/8 or ::1."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def cross_site_refusal(method: str, host: str | None, origin: str | None,
                       loopback_only: bool) -> str | None:
    """Why a request must be refused as another site's, or None.

    A page bound to loopback without tokens trusts whoever can reach it, which includes every web
    site the operator's browser visits: a site may POST to ``http://127.0.0.1:8765/api/missions``
    (a "simple" request, no preflight), or rebind its own name to 127.0.0.1 and read the API.
    So a loopback page answers only requests addressed to a loopback name (``Host``), and every
    page refuses a POST whose ``Origin`` is not the page itself. Clients that send no ``Origin``
    (curl, scripts) are not browsers acting for another site.
    """
    if loopback_only and not is_loopback_name(host_name(host or "")):
        return f"this page answers requests for 127.0.0.1 or localhost only, not {host!r}"
    foreign = origin is not None and (
        origin == "null" or urlsplit(origin).netloc.lower() != (host or "").lower())
    if method != "GET" and foreign:
        return f"a request from another site ({origin}) is refused"
    return None
