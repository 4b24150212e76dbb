"""Who is acting on the vehicle: the Zenoh peer behind each input, as the log and
the flight record name it (``docs/security.md``, "Every actor on record").

Zenoh does not say which link a message came over. What it does say:

* the sender's **source info**, the Zenoh id its session declares on a put or a
  query (the ground station and the demo's planner declare theirs; a peer may leave
  it out, or claim another id);
* the **links** of this session, each with the identity Zenoh authenticated on it:
  the certificate's common name under mutual TLS, or the user name under
  user/password authentication (:attr:`zenoh.Link.auth_identifier`).

An :class:`Actor` holds both: the declared id, and the authenticated name of the
link to that id when the peer is connected directly. A declared id with no direct
link (a peer behind a router, or a made-up id) is recorded as declared, with the
links it may have come over. Which peer may send what at all is the access
control's job (the fleet's rules); this module only names who did.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from typing import Any

import zenoh

from companion.settings.config import short

log = logging.getLogger("rota.companion")

#: Least time between two look-ups of this session's links for an unknown id, s.
REFRESH_S = 0.5
@dataclass(frozen=True)
class Link:
    """A link of this session to another Zenoh peer (or router)."""

    zid: str
    name: str | None  #: authenticated identity: certificate common name or user name
    remote: str  #: the peer's endpoint, e.g. ``tls/127.0.0.1:59632``

    def __str__(self) -> str:
        who = f"{self.name!s} ({self.zid[:8]})" if self.name else f"zid {self.zid[:8]}"
        return f"{who} over {self.remote}"


@dataclass(frozen=True)
class Actor:
    """The peer behind one input."""

    zid: str | None  #: the Zenoh id the sender declared (None: it declared none)
    link: Link | None = None  #: this session's direct link to ``zid``, if there is one
    via: tuple[Link, ...] = ()  #: links it may have come over, when not direct

    @property
    def name(self) -> str | None:
        """The authenticated identity (certificate common name or user name)."""
        return None if self.link is None else self.link.name

    def __str__(self) -> str:
        if self.link is not None:
            if self.link.name:
                return f"{short(self.link.name)} (Zenoh peer {self.zid})"
            return f"Zenoh peer {self.zid} (unauthenticated link {self.link.remote})"
        declared = f"Zenoh peer {self.zid} (declared, not a direct link)" if self.zid \
            else "a Zenoh peer that declared no id"
        if not self.via:
            return declared
        shown = ", ".join(str(link) for link in self.via[:3])
        more = f" and {len(self.via) - 3} more" if len(self.via) > 3 else ""
        return f"{declared}, via {shown}{more}"

    def to_dict(self) -> dict[str, Any]:
        return {"zid": self.zid, "name": self.name,
                "link": None if self.link is None else self.link.remote,
                "via": [{"zid": k.zid, "name": k.name, "remote": k.remote} for k in self.via]}


def _link(link: zenoh.Link) -> Link:
    name = link.auth_identifier
    return Link(zid=str(link.zid), name=None if name is None else str(name), remote=str(link.dst))


class Peers:
    """The links of ``session``, kept current by Zenoh's link events; names the
    :class:`Actor` behind a source info. Thread-safe: Zenoh calls back on its own
    threads, and a lookup is a dictionary read."""

    def __init__(self, session: zenoh.Session) -> None:
        self._session = session
        self._lock = threading.Lock()
        self._links: dict[str, Link] = {}
        self._refreshed = 0.0
        self._listener = None
        try:
            self._listener = session.info.declare_link_events_listener(self._on_event,
                                                                       history=True)
        except Exception as exc:  # noqa: BLE001 - an older Zenoh: the links as they are now
            log.warning("Zenoh link events unavailable (%s): actors named from the links "
                        "at start only", exc)
            for link in session.info.links():
                self._links[str(link.zid)] = _link(link)

    def _on_event(self, event: Any) -> None:
        link = _link(event.link)
        gone = event.kind == zenoh.SampleKind.DELETE
        with self._lock:
            if gone:
                self._links.pop(link.zid, None)
            else:
                self._links[link.zid] = link
        log.info("Zenoh peer %s %s", link, "disconnected" if gone else "connected")

    def links(self) -> list[Link]:
        with self._lock:
            return list(self._links.values())

    def actor(self, info: zenoh.SourceInfo | None) -> Actor:
        """The actor behind an input with source info ``info`` (None: undeclared)."""
        zid = None if info is None else str(info.source_id.zid)
        with self._lock:
            direct = self._links.get(zid) if zid else None
        if zid and direct is None and time.monotonic() - self._refreshed > REFRESH_S:
            # a peer's first message can come before the event of its link: ask Zenoh
            # (at most every REFRESH_S, so made-up ids cannot make it ask often)
            self._refreshed = time.monotonic()
            fresh = {str(k.zid): _link(k) for k in self._session.info.links()}
            with self._lock:
                self._links.update(fresh)
                direct = self._links.get(zid)
        if direct is not None:
            return Actor(zid, direct)
        with self._lock:
            links = tuple(self._links.values())
        return Actor(zid, None, links)

    def close(self) -> None:
        if self._listener is not None:
            try:
                self._listener.undeclare()
            except Exception:  # noqa: BLE001, S110 - closing anyway
                pass
