"""Who may use the ground-station web page (``rota-gs web``).

* **A token per session**, made from :mod:`secrets` at start and given out of
  band: printed on the terminal (in the page's address, after ``#``, so it never
  reaches a server log or a ``Referer``) and written to a file only the owner can
  read. Every ``/api/`` request, reading included, carries it as
  ``Authorization: Bearer TOKEN``; the page keeps it in the tab's session storage,
  which belongs to the page's own origin (scheme, host and port).
* **Every request** (the page and its assets too) must name a host the page
  answers to, with its port, in ``Host`` (against DNS rebinding); an ``Origin``,
  when sent, must be the page's own; a browser's ``Sec-Fetch-Site`` must say the
  request comes from the page itself (only opening the page may come from
  elsewhere).
* **Off this machine's loopback only over TLS**: a token sent in clear over a
  network is anyone's who listens, so another bind is refused unless the page is
  served over HTTPS (``--tls-cert``, ``--tls-key``).
"""

from __future__ import annotations

import hmac
import ipaddress
import os
import secrets
import socket
import ssl
from dataclasses import dataclass
from pathlib import Path

from rota.errors import InputError

#: Host names (with the address literals) that mean this machine's loopback.
LOOPBACK_NAMES = frozenset({"localhost", "127.0.0.1", "::1"})
#: The browser's ``Sec-Fetch-Site`` values of a request the page itself made or a
#: user typed (``none``).
OWN_SITES = frozenset({"same-origin", "none"})


def is_loopback(host: str) -> bool:
    """``host`` (a name or an address) is this machine's loopback only."""
    host = host.strip("[]").lower()
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def is_wildcard(host: str) -> bool:
    return host.strip("[]") in ("", "0.0.0.0", "::")  # noqa: S104 - a check, not a bind


def new_token() -> str:
    """32 random bytes, URL-safe (43 characters)."""
    return secrets.token_urlsafe(32)


@dataclass(frozen=True)
class Access:
    """What a request must show: ``Host`` one of ``hosts`` with ``port``, its
    ``Origin`` (if any) the page's own, and for ``/api/`` the ``token``."""

    token: str
    port: int
    hosts: frozenset[str]
    tls: bool = False

    @property
    def scheme(self) -> str:
        return "https" if self.tls else "http"

    def host_ok(self, header: str | None) -> bool:
        """``Host`` names a host the page answers to, with the page's port (a
        browser leaves out only the scheme's default port)."""
        if not header:
            return False
        name, port = _split_host(header.strip().lower())
        if port is None:
            port = 443 if self.tls else 80
        return name in self.hosts and port == self.port

    def origin_ok(self, origin: str | None, host_header: str) -> bool:
        """No ``Origin`` (a typed address, a same-origin read), or the page's own."""
        if origin is None:
            return True
        return origin.strip().lower() == f"{self.scheme}://{host_header.strip().lower()}"

    def token_ok(self, authorization: str | None) -> bool:
        """``Authorization: Bearer TOKEN`` with this session's token (compared in
        constant time)."""
        if not authorization:
            return False
        kind, _, given = authorization.strip().partition(" ")
        return kind.lower() == "bearer" and hmac.compare_digest(given.strip().encode(),
                                                                self.token.encode())


def _split_host(value: str) -> tuple[str, int | None]:
    """``name:port``, ``[v6]:port``, ``name`` -> (name without brackets, port)."""
    if value.startswith("["):
        name, _, rest = value[1:].partition("]")
        port = rest[1:] if rest.startswith(":") else ""
    elif value.count(":") == 1:
        name, _, port = value.partition(":")
    else:
        name, port = value, ""
    if not port:
        return name, None
    return (name, int(port)) if port.isdigit() else ("", -1)


def check_bind(host: str, tls: bool) -> None:
    """Refuse to serve beyond this machine's loopback without TLS (one line)."""
    if not is_loopback(host) and not tls:
        raise InputError("--host", f"{host or '(all addresses)'} is reachable from the network "
                         "and the page's token would cross it in clear: serve over TLS "
                         "(--tls-cert FILE --tls-key FILE), or keep the default 127.0.0.1 and "
                         "reach it through an SSH tunnel (ssh -L 8470:127.0.0.1:8470 HOST)")


def access_for(host: str, port: int, token: str, tls: bool = False,
               names: tuple[str, ...] = ()) -> Access:
    """The host names a page bound to ``host`` answers to: the bound name; the
    loopback names when it listens there; this machine's names and addresses when
    it listens on all addresses; and ``names`` (how others reach it)."""
    hosts = {host.strip("[]").lower(), *(n.strip("[]").lower() for n in names)}
    if is_loopback(host) or is_wildcard(host):
        hosts |= LOOPBACK_NAMES
    if is_wildcard(host):
        hosts |= _own_names()
    hosts.discard("")
    return Access(token, port, frozenset(hosts), tls)


def _own_names() -> set[str]:
    names = {socket.gethostname().lower(), socket.getfqdn().lower()}
    for name in list(names):
        try:
            names |= {str(info[4][0]).lower() for info in socket.getaddrinfo(name, None)}
        except OSError:
            pass
    return names


def tls_context(cert: str, key: str) -> ssl.SSLContext:
    """A server TLS context (TLS 1.2 or newer) from PEM files."""
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    ctx.minimum_version = ssl.TLSVersion.TLSv1_2
    try:
        ctx.load_cert_chain(cert, key)
    except (OSError, ssl.SSLError) as exc:
        raise InputError("--tls-cert/--tls-key", f"{cert}, {key}: {exc}") from None
    return ctx


def default_token_file(port: int) -> Path:
    """``$XDG_RUNTIME_DIR/rota-gs/web-PORT.token`` (the owner's own runtime
    directory), else ``~/.local/state/rota-gs/web-PORT.token``."""
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    if runtime and Path(runtime).is_dir() and Path(runtime).stat().st_uid == os.getuid():
        base = Path(runtime)
    else:
        base = Path(os.environ.get("XDG_STATE_HOME") or Path.home() / ".local" / "state")
    return base / "rota-gs" / f"web-{port}.token"


def write_token(path: Path, token: str) -> None:
    """Write the token to ``path``, readable by its owner only (0600; a directory
    of ours made for it is 0700)."""
    if not path.parent.exists():
        path.parent.mkdir(mode=0o700, parents=True)
        os.chmod(path.parent, 0o700)
    flags = os.O_WRONLY | os.O_CREAT | os.O_TRUNC | getattr(os, "O_NOFOLLOW", 0)
    fd = os.open(path, flags, 0o600)
    try:
        os.fchmod(fd, 0o600)
        os.write(fd, (token + "\n").encode())
    finally:
        os.close(fd)
