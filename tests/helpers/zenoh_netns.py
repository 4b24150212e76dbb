"""A network of two computers in network namespaces made here (nothing leaves
this machine): the vehicle (10.77.0.1, and its loopback) and a stranger on the
same link (10.77.0.2) with no credentials. Run by ``tests/e2e/test_zenoh_exposure.py``
as ``unshare -n python tests/helpers/zenoh_netns.py vehicle CONFIG_JSON5 WINDOW_S``; prints
one JSON line: whether the stranger reached the vehicle's ``config`` queryable,
and after how long.

``stranger`` is the other role, run inside the second namespace by the first:
a Zenoh peer with Zenoh's defaults (multicast and gossip scouting on) listening
on the link, asking ``rota/sim/config`` until it gets an answer or time is up.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import zenoh

VEHICLE, STRANGER = "10.77.0.1", "10.77.0.2"


def sh(*cmd: str) -> None:
    subprocess.run(cmd, check=True, capture_output=True)


def stranger(window_s: float) -> None:
    s = zenoh.open(zenoh.Config.from_json5(json.dumps(
        {"mode": "peer", "listen": {"endpoints": [f"tcp/{STRANGER}:7447"]}})))
    t0 = time.monotonic()
    reached = None
    while time.monotonic() - t0 < window_s:
        if any(r.ok is not None for r in s.get("rota/sim/config", timeout=0.5)):
            reached = round(time.monotonic() - t0, 2)
            break
        time.sleep(0.1)
    print(json.dumps({"reached_after_s": reached}), flush=True)
    s.close()


def vehicle(config: str, window_s: float) -> None:
    # this namespace: loopback (with multicast, as a real computer's) and one end of a link
    sh("ip", "link", "set", "lo", "up", "multicast", "on")
    other = subprocess.Popen(["unshare", "-n", "sleep", str(window_s + 30)])
    try:
        sh("ip", "link", "add", "veh0", "type", "veth", "peer", "name", "str0")
        sh("ip", "link", "set", "str0", "netns", str(other.pid))
        sh("ip", "addr", "add", f"{VEHICLE}/24", "dev", "veh0")
        sh("ip", "link", "set", "veh0", "up", "multicast", "on")
        inside = ("nsenter", "-t", str(other.pid), "-n")
        sh(*inside, "ip", "link", "set", "lo", "up")
        sh(*inside, "ip", "addr", "add", f"{STRANGER}/24", "dev", "str0")
        sh(*inside, "ip", "link", "set", "str0", "up", "multicast", "on")
        for ns in ((), inside):
            sh(*ns, "ip", "route", "add", "224.0.0.0/4", "dev", "veh0" if not ns else "str0")
        s = zenoh.open(zenoh.Config.from_json5(config))
        q = s.declare_queryable("rota/sim/config", lambda q: q.reply(q.key_expr, b"{}"))
        done = subprocess.run([*inside, sys.executable, __file__, "stranger", str(window_s)],
                              capture_output=True, text=True, timeout=window_s + 30,
                              env=os.environ)
        print(done.stdout.strip().splitlines()[-1] if done.stdout.strip() else
              json.dumps({"error": done.stderr[-500:]}), flush=True)
        q.undeclare()
        s.close()
    finally:
        other.kill()
        other.wait()


if __name__ == "__main__":
    if sys.argv[1] == "stranger":
        stranger(float(sys.argv[2]))
    else:
        vehicle(sys.argv[2], float(sys.argv[3]))
