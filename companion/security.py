"""Who can reach the service: its Zenoh configuration, and the check that it is
not exposed without authentication (``docs/security.md``).

The embedded default listens on loopback only. A Zenoh config file (the fleet's,
made by ``rota-companion fleet``) may listen on the network or connect to a
router; the service then starts only if every such endpoint is authenticated:
TLS with client certificates (mutual TLS) or Zenoh's user/password
authentication. The MAVLink link is held to the same rule: a UDP endpoint open
beyond loopback lets anyone on the network pose as the autopilot. With
``[zenoh] insecure = true`` the service starts anyway and says so on every
status message.
"""

from __future__ import annotations

import ipaddress
import json
from typing import Any
from urllib.parse import urlparse

import zenoh

from companion.config import Config, ConfigError


def zenoh_config(cfg: Config) -> zenoh.Config:
    """The Zenoh configuration: a file if given, else the embedded loopback default
    (peer mode, listening on the configured endpoints, no multicast scouting, so
    nothing leaves the machine unless configured to). Either way Zenoh drops a
    message larger than the inputs' byte caps before reassembling it."""
    if cfg.zenoh.config_file:
        try:
            z = zenoh.Config.from_file(cfg.zenoh.config_file)
        except Exception as exc:  # noqa: BLE001 - zenoh raises its own error type
            raise ConfigError(f"[zenoh] config_file: {cfg.zenoh.config_file}: {exc}") from None
    else:
        z = zenoh.Config()
        z.insert_json5("mode", json.dumps(cfg.zenoh.mode))
        z.insert_json5("scouting/multicast/enabled", "false")
        z.insert_json5("listen/endpoints", json.dumps(list(cfg.zenoh.listen)))
        z.insert_json5("connect/endpoints", json.dumps(list(cfg.zenoh.connect)))
    biggest = max(cfg.inputs.max_map_bytes, cfg.inputs.max_trajectory_bytes,
                  cfg.inputs.max_query_bytes)
    z.insert_json5("transport/link/rx/max_message_size", str(biggest + 65536))
    return z


def _get(z: zenoh.Config, key: str) -> Any:
    try:
        return json.loads(z.get_json(key))
    except Exception:  # noqa: BLE001 - absent
        return None


def _endpoints(value: Any) -> list[str]:
    """Endpoints of a listen/connect setting (a list, or per-mode lists)."""
    if isinstance(value, dict):
        return [e for v in value.values() for e in _endpoints(v)]
    return [str(e) for e in value] if isinstance(value, list) else []


def _loopback(host: str) -> bool:
    host = host.strip("[]")
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False  # a name: anything


def _host(endpoint: str) -> tuple[str, str]:
    """(protocol, host) of a Zenoh endpoint such as ``tcp/127.0.0.1:7447#iface=lo``."""
    proto, _, rest = endpoint.partition("/")
    address = rest.split("#")[0].split("?")[0]
    host = address.rsplit(":", 1)[0] if ":" in address else address
    return proto, host


def exposure(cfg: Config, z: zenoh.Config | None = None) -> list[str]:
    """Why the service would be reachable without authentication (empty: it is
    not): each Zenoh endpoint beyond loopback without mutual TLS or user/password
    authentication, and a MAVLink UDP endpoint beyond loopback."""
    z = z or zenoh_config(cfg)
    tls = _get(z, "transport/link/tls") or {}
    mtls = bool(tls.get("enable_mtls")) and bool(tls.get("root_ca_certificate"))
    usrpwd = _get(z, "transport/auth/usrpwd") or {}
    password = bool(usrpwd.get("dictionary_file")) or bool(usrpwd.get("user")
                                                           and usrpwd.get("password"))
    problems = []
    for what, key in (("listens on", "listen/endpoints"), ("connects to", "connect/endpoints")):
        for endpoint in _endpoints(_get(z, key)):
            proto, host = _host(endpoint)
            if proto in ("unixsock-stream", "unixpipe") or _loopback(host):
                continue
            if (proto == "tls" and mtls) or password:
                continue
            problems.append(f"Zenoh {what} {endpoint} without authentication (use the "
                            "fleet's mutual-TLS config, or user/password)")
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
