"""Who can reach the service: its Zenoh configuration, and the check that it is
not exposed without authentication (``docs/security.md``).

The embedded default listens on loopback only and seeks no one (multicast and
gossip scouting off). A Zenoh config file (the fleet's, made by
``rota-companion fleet``) may listen on the network or connect to a router; the
service then starts only if every way in is authenticated, read as Zenoh will
use the file (its defaults for what the file leaves unset, and each endpoint's
own ``#`` settings over the file's TLS section):

* no scouting that connects to whoever answers (multicast, gossip);
* every listener beyond loopback: TLS with client certificates (mutual TLS), or
  Zenoh's user/password authentication (a ``dictionary_file``);
* every connection beyond loopback: mutual TLS (the peer's certificate checked
  against the fleet's authority and its name), not user/password, which proves
  who we are to the peer but not who the peer is;
* reachable beyond loopback at all: access control on, denying by default.

The MAVLink link is held to the same rule: a UDP endpoint open beyond loopback
lets anyone on the network pose as the autopilot. With ``[zenoh] insecure =
true`` the service starts anyway and says so on every status message.
"""

from __future__ import annotations

import ipaddress
import json
from dataclasses import dataclass
from typing import Any
from urllib.parse import urlparse

import zenoh

from companion.settings.config import Config, ConfigError

#: What Zenoh 1.x does where a config file says nothing (zenoh-config's defaults;
#: reading such a file back gives ``null``). ``tests/e2e/test_zenoh_exposure.py``
#: checks the multicast one against the installed Zenoh.
SCOUTING_DEFAULT_ENABLED = {"multicast": True, "gossip": True}
AUTOCONNECT_DEFAULT = {"router": (), "peer": ("router", "peer", "client"),
                       "client": ("router", "peer", "client")}
#: Connections that stay on this computer (file-system permissions guard them).
LOCAL_PROTOCOLS = ("unixsock-stream", "unixpipe")
#: Protocols that use the TLS settings (``transport/link/tls``).
TLS_PROTOCOLS = ("tls", "quic")
_CA_KEYS = ("root_ca_certificate_file", "root_ca_certificate_raw", "root_ca_certificate_base64")


def zenoh_config(cfg: Config) -> zenoh.Config:
    """The Zenoh configuration: a file if given, else the embedded loopback default
    (peer mode, listening on the configured endpoints, no multicast nor gossip
    scouting, so nothing leaves the machine unless configured to). Either way
    Zenoh drops a message larger than the inputs' byte caps before reassembling it,
    and shares no memory with other processes."""
    if cfg.zenoh.config_file:
        try:
            z = zenoh.Config.from_file(cfg.zenoh.config_file)
        except Exception as exc:  # noqa: BLE001 - zenoh raises its own error type
            raise ConfigError(f"[zenoh] config_file: {cfg.zenoh.config_file}: {exc}") from None
    else:
        z = zenoh.Config()
        z.insert_json5("mode", json.dumps(cfg.zenoh.mode))
        z.insert_json5("scouting/multicast/enabled", "false")
        z.insert_json5("scouting/gossip/enabled", "false")
        z.insert_json5("listen/endpoints", json.dumps(list(cfg.zenoh.listen)))
        z.insert_json5("connect/endpoints", json.dumps(list(cfg.zenoh.connect)))
    biggest = max(cfg.inputs.max_map_bytes, cfg.inputs.max_trajectory_bytes,
                  cfg.inputs.max_query_bytes)
    z.insert_json5("transport/link/rx/max_message_size", str(biggest + 65536))
    # No shared memory with local peers: a peer's large message would be mapped into
    # the service (its 16 MB pool stayed resident after one map, measured), and
    # another process's segment is not the service's to map; loopback TCP it is
    z.insert_json5("transport/shared_memory/enabled", "false")
    return z


def _get(z: zenoh.Config, key: str) -> Any:
    try:
        return json.loads(z.get_json(key))
    except Exception:  # noqa: BLE001 - absent
        return None


def _for_mode(value: Any, mode: str) -> Any:
    """A setting that may be given per mode (``{"peer": ..., "router": ...}``)."""
    return value.get(mode) if isinstance(value, dict) else value


def _params(text: str) -> dict[str, str]:
    """Zenoh's ``key=value;key=value`` endpoint parameters."""
    out = {}
    for part in text.split(";"):
        key, _, value = part.partition("=")
        if key.strip():
            out[key.strip()] = value.strip()
    return out


def _loopback(host: str) -> bool:
    host = host.strip("[]")
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False  # a name: anything


@dataclass(frozen=True)
class Endpoint:
    """A Zenoh endpoint, ``proto/address?metadata#config``: only the ``#`` part
    configures the link (a TLS setting there overrides the file's TLS section;
    in the ``?`` part Zenoh ignores it)."""

    text: str
    protocol: str
    host: str
    config: dict[str, str]

    @classmethod
    def parse(cls, text: str) -> Endpoint:
        locator, _, config = text.partition("#")
        proto, _, rest = locator.partition("/")
        address = rest.split("?")[0]
        host = address.rsplit(":", 1)[0] if ":" in address else address
        return cls(text, proto.lower(), host, _params(config))

    @property
    def local(self) -> bool:
        return self.protocol in LOCAL_PROTOCOLS or _loopback(self.host)


def _endpoints(z: zenoh.Config, key: str, mode: str) -> list[Endpoint]:
    """The endpoints Zenoh will use in ``mode`` (its per-mode defaults included:
    a peer whose file names no listener listens on ``tcp/[::]:0``)."""
    value = _for_mode(_get(z, key), mode)
    return [Endpoint.parse(str(e)) for e in value] if isinstance(value, list) else []


def _kinds(value: Any, mode: str) -> tuple[str, ...]:
    """An autoconnect setting (``"router|peer"``, a list, or per mode) as kinds."""
    value = _for_mode(value, mode)
    if value is None:
        return AUTOCONNECT_DEFAULT.get(mode, ())
    if isinstance(value, str):
        value = value.split("|")
    return tuple(str(v).strip() for v in value if str(v).strip()) \
        if isinstance(value, list) else ()


def _scouting(z: zenoh.Config, mode: str) -> list[str]:
    """Scouting that connects the service to whoever answers."""
    problems = []
    for kind, how in (("multicast", "to whoever answers its scouts on the network"),
                      ("gossip", "to the addresses its peers tell it of")):
        enabled = _get(z, f"scouting/{kind}/enabled")
        if enabled is None:
            enabled = SCOUTING_DEFAULT_ENABLED[kind]
        kinds = _kinds(_get(z, f"scouting/{kind}/autoconnect"), mode)
        if enabled and kinds:
            unset = " (Zenoh's default where the file says nothing)" \
                if _get(z, f"scouting/{kind}/enabled") is None else ""
            problems.append(f"Zenoh {kind} scouting is on{unset}: the service connects "
                            f"{how} ({'|'.join(kinds)}), with no credentials asked (set "
                            f"scouting/{kind}/enabled to false, as the fleet's config does)")
    return problems


@dataclass(frozen=True)
class _Auth:
    """The file's authentication settings, as an endpoint's link sees them."""

    tls: dict[str, str]  # the TLS section in an endpoint's own keys
    dictionary: bool  # user/password: a listener asks every peer for one

    @classmethod
    def read(cls, z: zenoh.Config) -> _Auth:
        t = _get(z, "transport/link/tls") or {}
        tls = {}
        if t.get("enable_mtls") is not None:
            tls["enable_mtls"] = str(bool(t["enable_mtls"])).lower()
        if t.get("root_ca_certificate"):
            tls["root_ca_certificate_file"] = str(t["root_ca_certificate"])
        if t.get("root_ca_certificate_base64"):
            tls["root_ca_certificate_base64"] = "(given)"
        if t.get("verify_name_on_connect") is not None:
            tls["verify_name_on_connect"] = str(bool(t["verify_name_on_connect"])).lower()
        usrpwd = _get(z, "transport/auth/usrpwd") or {}
        return cls(tls, bool(usrpwd.get("dictionary_file")))

    def link(self, e: Endpoint) -> dict[str, str]:
        """The TLS settings of ``e``'s link: its own over the file's."""
        return self.tls | {k: v for k, v in e.config.items() if k in (
            "enable_mtls", "verify_name_on_connect", *_CA_KEYS)}


def _endpoint(e: Endpoint, listening: bool, auth: _Auth) -> str | None:
    """Why ``e`` lets an unauthenticated peer in (None: it does not)."""
    what = f"Zenoh {'listens on' if listening else 'connects to'} {e.text}"
    if e.local:
        return None
    if e.protocol in TLS_PROTOCOLS:
        link = auth.link(e)
        mtls = link.get("enable_mtls", "false").lower() == "true"
        ca = [k for k in _CA_KEYS if link.get(k)]
        if mtls and ca:
            own = [k for k in _CA_KEYS if e.config.get(k)]
            if own and e.config.get(own[0]) != auth.tls.get(own[0]):
                return (f"{what} trusting another certificate authority than the file's "
                        f"({own[0]}): the access control's common names would be vouched "
                        "for by two authorities")
            if not listening and link.get("verify_name_on_connect", "true").lower() != "true":
                return (f"{what} without checking the peer's name (verify_name_on_connect "
                        "false): any certificate of any public authority passes")
            return None
        if listening and auth.dictionary:
            return None
        why = "its own #enable_mtls=false" if e.config.get("enable_mtls", "").lower() \
            == "false" else ("no root certificate authority" if mtls else "enable_mtls off")
        return (f"{what} without authentication: TLS without client certificates ({why}); "
                "use the fleet's mutual-TLS config")
    if listening and auth.dictionary:
        return None
    hint = "user/password proves this vehicle to the peer, not the peer to it: use " \
        "mutual TLS" if auth.dictionary or not listening else "use the fleet's mutual-TLS " \
        "config, or user/password"
    return f"{what} without authentication ({hint})"


def _access_control(z: zenoh.Config) -> list[str]:
    acl = _get(z, "access_control") or {}
    if acl.get("enabled") and str(acl.get("default_permission", "deny")).lower() == "deny":
        return []
    return ["Zenoh is reachable beyond loopback without access control denying by default "
            "(access_control enabled, default_permission \"deny\"): every holder of a "
            "certificate or password of the fleet could command the vehicle (the fleet's "
            "config has the rules)"]


def zenoh_exposure(z: zenoh.Config) -> list[str]:
    """Why a Zenoh configuration lets an unauthenticated peer in, or lets any
    authenticated one act (empty: neither), read as Zenoh will use it."""
    mode = str(_get(z, "mode") or "peer")
    auth = _Auth.read(z)
    problems = _scouting(z, mode)
    remote = False
    for key, listening in (("listen/endpoints", True), ("connect/endpoints", False)):
        for e in _endpoints(z, key, mode):
            remote = remote or not e.local
            why = _endpoint(e, listening, auth)
            if why:
                problems.append(why)
    if remote:
        problems += _access_control(z)
    return problems


def exposure(cfg: Config, z: zenoh.Config | None = None) -> list[str]:
    """Why the service would be reachable without authentication (empty: it is
    not): its Zenoh configuration (:func:`zenoh_exposure`) and a MAVLink UDP or
    TCP endpoint beyond loopback."""
    problems = zenoh_exposure(z or zenoh_config(cfg))
    url = urlparse(cfg.mavlink.url)
    if url.scheme in ("udp", "udpin", "udpout", "tcp", "tcpin", "tcpout") and url.hostname \
            and not _loopback(url.hostname):
        problems.append(f"MAVLink on {cfg.mavlink.url}: anyone on that network can pose as "
                        "the autopilot (use a serial link, or loopback to a local router)")
    return problems


def check_exposure(cfg: Config, z: zenoh.Config | None = None) -> list[str]:
    """Refuse an exposed configuration unless ``[zenoh] insecure = true``; returns
    the problems that ``insecure`` lets through (to warn about on every status)."""
    problems = exposure(cfg, z)
    if problems and not cfg.zenoh.insecure:
        raise ConfigError("refusing to start exposed: " + "; ".join(problems)
                          + " ([zenoh] insecure = true overrides this, and is announced "
                          "on every status)")
    return problems
