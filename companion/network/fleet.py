"""``rota-companion fleet DIR``: the certificates and Zenoh configurations of a
fleet, for mutual TLS and Zenoh's access control (``docs/security.md``).

Made with the ``openssl`` command (nothing here does cryptography itself):

* ``ca/``: the fleet's certificate authority (keep ``ca.key`` offline);
* ``<vehicle>/``: each vehicle's certificate and ``zenoh.json5``: it listens on
  loopback (for a planner on the same computer) and on mutual TLS (for the
  network), with access control: ground stations may command and configure it,
  its planner may send trajectories and maps, both may read status and
  telemetry; everyone else gets nothing;
* ``<ground station>/``: certificate and ``zenoh-<vehicle>.json5`` per vehicle (a
  Zenoh client of that vehicle; a fleet behind a Zenoh router needs one config);
* ``planner-<vehicle>/``: certificate and ``zenoh.json5`` for a planner on another
  computer (a client of that vehicle).

Access-control subjects are the certificates' common names (the directory names).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from companion.protocol import KEY_PREFIX

LOOPBACK_PORT = 7447
TLS_PORT = 7448
#: Seek no one: no multicast scouting, no connecting to addresses other peers gossip.
NO_SCOUTING = {"multicast": {"enabled": False}, "gossip": {"enabled": False}}


class FleetError(RuntimeError):
    """The fleet could not be made; the message says why."""


class FleetNameError(FleetError, ValueError):
    """A member's name (or a vehicle's host) is not allowed; the message says which."""


#: A member's name: its directory, its certificate's common name, a Zenoh key part.
NAME = re.compile(r"[A-Za-z0-9_-]{1,32}")
#: Where a vehicle is reached: a host name or an IP address (it goes into Zenoh
#: endpoints, where ``#``, ``?`` or ``/`` would change their meaning).
HOST = re.compile(r"[A-Za-z0-9.-]{1,253}|\[[0-9A-Fa-f:.]{2,45}\]")
#: Directory names the fleet uses itself.
RESERVED = ("ca",)
PLANNER = "planner-"


@dataclass(frozen=True)
class Fleet:
    """What to make: vehicle ids, ground-station names, and where vehicles are
    reached on the network (``hosts[vehicle]``: a name or an IP address)."""

    vehicles: tuple[str, ...]
    ground_stations: tuple[str, ...] = ("gs",)
    hosts: dict[str, str] = field(default_factory=dict)
    key_prefix: str = KEY_PREFIX
    days: int = 825
    loopback_port: int = LOOPBACK_PORT
    tls_port: int = TLS_PORT

    def host(self, vehicle: str) -> str:
        return self.hosts.get(vehicle, f"{vehicle}.local")


def check_names(fleet: Fleet, root: Path | None = None) -> None:
    """Refuse names that would collide or escape: each a safe name
    (``[A-Za-z0-9_-]``, 1-32 characters), not ``ca``, not a planner's
    (``planner-...``), used once across vehicles and ground stations, and not
    already another kind of member in the fleet at ``root``; hosts only of the
    vehicles, each a plain host name or address. Raises :class:`FleetNameError`."""
    if not fleet.vehicles:
        raise FleetNameError("no vehicles given")
    seen: dict[str, str] = {}
    for kind, names in (("vehicle", fleet.vehicles), ("ground station", fleet.ground_stations)):
        for name in names:
            if not NAME.fullmatch(name):
                raise FleetNameError(f"{kind} name {name[:40]!r}: use 1-32 letters, digits, "
                                     "'_' or '-'")
            if name.lower() in RESERVED or name.startswith(PLANNER):
                raise FleetNameError(f"{kind} name {name!r} is reserved (the fleet's own "
                                     f"'ca' directory and planner names '{PLANNER}<vehicle>')")
            if name in seen:
                raise FleetNameError(
                    f"{kind} name {name!r} is given twice" if seen[name] == kind else
                    f"{name!r} is both a {seen[name]} and a {kind} (the ground stations are "
                    "'gs' unless --ground-stations says otherwise): each member needs its "
                    "own name, or its certificate gives it the other's rights")
            seen[name] = kind
            was = _member_kind(root / name) if root is not None else None
            if was is not None and was != kind:
                raise FleetNameError(f"{kind} name {name!r} is already a {was} of this fleet: "
                                     "its certificate would give one the other's rights")
    for vehicle, host in fleet.hosts.items():
        if vehicle not in fleet.vehicles:
            raise FleetNameError(f"--host {vehicle}={host[:40]}: {vehicle!r} is not one of "
                                 "the vehicles")
        if not HOST.fullmatch(host):
            raise FleetNameError(f"--host {vehicle}={host[:40]!r}: not a host name or IP "
                                 "address")


def _member_kind(directory: Path) -> str | None:
    """What an existing member directory of a fleet is (None: none there)."""
    if (directory / "zenoh.json5").is_file():
        return "vehicle" if "of vehicle " in (directory / "zenoh.json5").read_text()[:200] \
            else "planner"
    if any(directory.glob("zenoh-*.json5")):
        return "ground station"
    return None


def _openssl(*args: str, cwd: Path) -> None:
    exe = shutil.which("openssl")
    if exe is None:
        raise FleetError("the openssl command is needed (Debian/Ubuntu: apt install openssl)")
    done = subprocess.run([exe, *args], cwd=cwd, capture_output=True, text=True)
    if done.returncode:
        raise FleetError(f"openssl {args[0]} failed: {done.stderr.strip()[:300]}")


def _private(path: Path) -> None:
    os.chmod(path, 0o600)


def make_ca(ca_dir: Path, days: int) -> None:
    ca_dir.mkdir(parents=True, exist_ok=True)
    if (ca_dir / "ca.pem").exists():
        return  # an existing fleet gains members; its CA stays
    _openssl("req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes",
             "-keyout", "ca.key", "-out", "ca.pem", "-days", str(days),
             "-subj", "/CN=rota-fleet-ca", "-addext", "basicConstraints=critical,CA:TRUE",
             "-addext", "keyUsage=critical,keyCertSign,cRLSign", cwd=ca_dir)
    _private(ca_dir / "ca.key")


def make_member(ca_dir: Path, out: Path, name: str, days: int,
                names: Sequence[str] = (), ips: Sequence[str] = ()) -> None:
    """A certificate and key for ``name`` (its common name), signed by the CA."""
    out.mkdir(parents=True, exist_ok=True)
    alt = [f"DNS:{n}" for n in (name, *names)] + [f"IP:{ip}" for ip in ips]
    (out / "ext.cnf").write_text(
        f"subjectAltName={','.join(alt)}\nbasicConstraints=CA:FALSE\n"
        "keyUsage=critical,digitalSignature\nextendedKeyUsage=serverAuth,clientAuth\n")
    _openssl("req", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes",
             "-keyout", "key.pem", "-out", "req.csr", "-subj", f"/CN={name}", cwd=out)
    _openssl("x509", "-req", "-in", "req.csr", "-CA", str(ca_dir / "ca.pem"),
             "-CAkey", str(ca_dir / "ca.key"), "-CAcreateserial", "-out", "cert.pem",
             "-days", str(days), "-extfile", "ext.cnf", cwd=out)
    for tmp in ("req.csr", "ext.cnf"):
        (out / tmp).unlink()
    _private(out / "key.pem")
    shutil.copy(ca_dir / "ca.pem", out / "ca.pem")


def _tls(directory: str) -> dict[str, Any]:
    """Zenoh's TLS link settings for a member whose files are in ``directory``."""
    return {"root_ca_certificate": f"{directory}/ca.pem", "enable_mtls": True,
            "listen_private_key": f"{directory}/key.pem",
            "listen_certificate": f"{directory}/cert.pem",
            "connect_private_key": f"{directory}/key.pem",
            "connect_certificate": f"{directory}/cert.pem"}


def access_control(prefix: str, vehicle: str, ground_stations: Sequence[str],
                   planner: str) -> dict[str, Any]:
    """The vehicle's Zenoh access control: deny by default; the rules below.

    Only the vehicle speaks for the vehicle: its outputs (``status``,
    ``telemetry``, ``retimed``, the ``alive`` token) and its queryables may only
    leave it (egress); no member may put, declare or answer on them towards it
    (ingress), so no forgery reaches a ground station through the vehicle."""
    k = f"{prefix}/{vehicle}"
    out = [f"{k}/status", f"{k}/telemetry", f"{k}/retimed"]
    alive = [f"{k}/alive", f"{prefix}/*/alive"]
    asked = [f"{k}/cmd/*", f"{k}/config", f"{k}/estimator"]
    rules = [
        {"id": "read", "permission": "allow", "flows": ["ingress"],
         "messages": ["declare_subscriber"], "key_exprs": out},
        {"id": "outputs", "permission": "allow", "flows": ["egress"], "messages": ["put"],
         "key_exprs": out},
        {"id": "alive", "permission": "allow", "flows": ["ingress"],
         "messages": ["declare_liveliness_subscriber", "liveliness_query"], "key_exprs": alive},
        {"id": "alive-out", "permission": "allow", "flows": ["egress"],
         "messages": ["liveliness_token", "reply"], "key_exprs": [f"{k}/alive"]},
        {"id": "plan", "permission": "allow", "flows": ["ingress"], "messages": ["put"],
         "key_exprs": [f"{k}/trajectory", f"{k}/map"]},
        {"id": "command", "permission": "allow", "flows": ["ingress"], "messages": ["query"],
         "key_exprs": asked},
        {"id": "answer", "permission": "allow", "flows": ["egress"],
         "messages": ["reply", "declare_queryable"], "key_exprs": asked},
    ]
    subjects = [{"id": "ground-stations", "cert_common_names": list(ground_stations)},
                {"id": "planner", "cert_common_names": [planner]},
                # a planner on the vehicle's own computer: the plain loopback listener
                {"id": "local", "interfaces": ["lo"], "link_protocols": ["tcp"]}]
    seen = ["read", "outputs", "alive", "alive-out"]
    policies = [{"rules": [*seen, "command", "answer", "plan"], "subjects": ["ground-stations"]},
                {"rules": [*seen, "plan"], "subjects": ["planner", "local"]}]
    return {"enabled": True, "default_permission": "deny", "rules": rules,
            "subjects": subjects, "policies": policies}


def _write(path: Path, title: str, config: dict[str, Any]) -> None:
    path.write_text(f"// {title}\n// Made by `rota-companion fleet`; see docs/security.md.\n"
                    + json.dumps(config, indent=2) + "\n")


def vehicle_config(fleet: Fleet, vehicle: str, directory: str) -> dict[str, Any]:
    return {
        "mode": "peer",
        "listen": {"endpoints": [f"tcp/127.0.0.1:{fleet.loopback_port}",
                                 f"tls/0.0.0.0:{fleet.tls_port}"]},
        "scouting": NO_SCOUTING,
        "transport": {"link": {"tls": _tls(directory)}},
        "access_control": access_control(fleet.key_prefix, vehicle, fleet.ground_stations,
                                          f"planner-{vehicle}"),
    }


def client_config(endpoints: Sequence[str], directory: str) -> dict[str, Any]:
    return {"mode": "client", "connect": {"endpoints": list(endpoints)},
            "scouting": NO_SCOUTING,
            "transport": {"link": {"tls": _tls(directory)}}}


def make_fleet(fleet: Fleet, out: str | Path, install_dir: str | None = None) -> list[Path]:
    """Make (or extend) the fleet in ``out``; returns the Zenoh configs written.
    ``install_dir``: where each member's directory will live on its computer
    (default: where it is made), as the configs name their files."""
    root = Path(out).resolve()
    check_names(fleet, root)
    ca = root / "ca"
    make_ca(ca, fleet.days)
    written = []

    def where(name: str) -> str:
        return f"{install_dir.rstrip('/')}/{name}" if install_dir else str(root / name)

    for v in fleet.vehicles:
        host = fleet.host(v)
        is_ip = host.replace(".", "").isdigit() or host.startswith("[")
        make_member(ca, root / v, v, fleet.days, names=() if is_ip else (host,),
                    ips=("127.0.0.1", *((host.strip("[]"),) if is_ip else ())))
        _write(root / v / "zenoh.json5", f"Zenoh configuration of vehicle {v}",
               vehicle_config(fleet, v, where(v)))
        written.append(root / v / "zenoh.json5")
        planner = f"planner-{v}"
        make_member(ca, root / planner, planner, fleet.days)
        _write(root / planner / "zenoh.json5", f"Zenoh configuration of {v}'s planner",
               client_config([f"tls/{host}:{fleet.tls_port}"], where(planner)))
        written.append(root / planner / "zenoh.json5")
    for gs in fleet.ground_stations:
        make_member(ca, root / gs, gs, fleet.days)
        for v in fleet.vehicles:
            path = root / gs / f"zenoh-{v}.json5"
            _write(path, f"Zenoh configuration of ground station {gs} for vehicle {v}",
                   client_config([f"tls/{fleet.host(v)}:{fleet.tls_port}"], where(gs)))
            written.append(path)
    return written
