"""The simulated vehicle in its own process, so that it does not share the GIL
with the service under test (as PX4 would not), with a small control pipe for
tests and the demo: read the true state, cut the link, and collect the record.

    with SimProcess(world="forest", seed=3, port=port) as sim:
        ...                        # MAVSDK: udpin://127.0.0.1:<port>
        sim.state()                # true / estimated position, mode, collisions
    report = sim.report            # collisions and the flight record
"""

from __future__ import annotations

import multiprocessing
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sitl.host_steal import HostSteal, StealMonitor


@dataclass
class SimReport:
    """What happened, in the world's ENU frame."""

    collisions: list[dict[str, Any]] = field(default_factory=list)
    time_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    true_position: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    estimated_position: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    velocity: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    mode: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=str))
    events: list[tuple[float, str]] = field(default_factory=list)
    home_enu: np.ndarray = field(default_factory=lambda: np.zeros(3))
    #: every offboard setpoint the vehicle received, as it received it: ``wall_time``
    #: (host monotonic s, the same clock as the service's), ``time_s`` (sim), and
    #: ``position`` (world ENU), ``velocity``, ``acceleration`` (ENU), ``mode``
    setpoints: dict[str, np.ndarray] = field(default_factory=dict)
    #: the host's steal counters while the vehicle flew (what a virtual machine's
    #: host took from its CPUs: :mod:`sitl.host_steal`)
    host_steal: HostSteal = field(default_factory=HostSteal)


def _child(conn: Any, options: dict[str, Any]) -> None:  # pragma: no cover - other process
    from companion.frames import ned_to_enu
    from sitl.estimation import EstimationErrorParams
    from sitl.vehicle import SimVehicle, VehicleParams, setpoint_arrays
    from sitl.world import World, get_world

    world = None
    if options.get("world_dict") is not None:
        world = World.from_dict(options["world_dict"])
    elif options.get("world") not in (None, "none"):
        world = get_world(options["world"], seed=options["seed"])
    start = getattr(world, "start", None)
    home = (float(start[0]), float(start[1]), 0.0) if start is not None else (0.0, 0.0, 0.0)
    params = VehicleParams(home_enu_m=home, **options.get("params", {}))
    est = (EstimationErrorParams(**options["estimation"]) if options.get("estimation")
           else None)  # None: the vehicle's default, PX4's EKF in SIH
    sim = SimVehicle(params, estimation=est, world=world, seed=options["noise_seed"],
                     port=options["port"], record_history=True, history_decimation=5)
    sim.start()
    conn.send(("ready", sim.local_port, home, sim.gcs_port))
    try:
        while True:
            if not conn.poll(0.05):
                continue
            cmd, *args = conn.recv()
            if cmd == "state":
                t, e = sim.true_state(), sim.estimated_state()
                conn.send({"time_s": t.time_s, "true_position": t.position_enu,
                           "estimated_position": e.position_enu,
                           "velocity": ned_to_enu(t.velocity_ned), "mode": sim.mode.name,
                           "armed": sim.armed, "collisions": len(sim.collisions),
                           "failsafe": sim.failsafe_active, "landed_state": sim.landed_state})
            elif cmd == "block":
                sim.link_blocked = bool(args[0])
                conn.send(True)
            elif cmd == "disarm":  # a kill switch / crash detector: disarms in the air
                conn.send(sim.disarm(force=True))
            elif cmd == "setpoints":  # the record so far (ENU), as in the report
                conn.send(_setpoints_enu(setpoint_arrays(sim.setpoint_log[args[0]:]), home))
            elif cmd == "stop":
                break
    finally:
        sim.stop()
        h = sim.history.arrays()
        conn.send(SimReport(
            collisions=[{"time_s": c.time_s, "position": c.position_enu,
                         "signed_distance_m": c.signed_distance_m} for c in sim.collisions],
            time_s=h["time_s"], true_position=ned_to_enu(h["true_position_ned"]) + home,
            estimated_position=ned_to_enu(h["estimated_position_ned"]) + home,
            velocity=ned_to_enu(h["velocity_ned"]), mode=h["mode"],
            events=list(sim.events), home_enu=np.asarray(home),
            setpoints=_setpoints_enu(setpoint_arrays(sim.setpoint_log), home)))


def _setpoints_enu(sp: dict[str, np.ndarray], home: Any) -> dict[str, np.ndarray]:
    from companion.frames import ned_to_enu

    return {"wall_time": sp["wall_time"], "time_s": sp["time_s"],
            "position": ned_to_enu(sp["position_ned"]) + np.asarray(home),
            "velocity": ned_to_enu(sp["velocity_ned"]),
            "acceleration": ned_to_enu(sp["acceleration_ned"]), "mode": sp["mode"],
            "sent_s": sp["sent_s"], "yaw_ned_deg": np.degrees(sp["yaw_ned_rad"])}


class SimProcess:
    """A :class:`sitl.vehicle.SimVehicle` running in a child process.

    Args:
        world: a world name of :func:`sitl.world.get_world`, or None.
        world_dict: a world as :meth:`sitl.world.World.to_dict` (instead of a name).
        seed: world and noise seed.
        noise_seed: the vehicle's noise (estimation error, wander) alone, if not ``seed``:
            flights of one world that are to differ as PX4's runs do.
        port: the companion's UDP port (MAVSDK ``udpin://127.0.0.1:<port>``).
        params: overrides of :class:`sitl.vehicle.VehicleParams` fields.
        estimation: an estimation-error model as :class:`sitl.estimation.EstimationErrorParams`
            fields (over the dataclass defaults: the paper's speed-dependent model alone);
            None or empty: the vehicle's default, PX4's EKF in SIH with hover wander.
    """

    def __init__(self, *, port: int, world: str | None = None,
                 world_dict: dict[str, Any] | None = None, seed: int = 0,
                 params: dict[str, Any] | None = None,
                 estimation: dict[str, Any] | None = None,
                 noise_seed: int | None = None) -> None:
        self.options = {"port": port, "world": world, "world_dict": world_dict, "seed": seed,
                        "noise_seed": seed if noise_seed is None else noise_seed,
                        "params": params or {}, "estimation": estimation or {}}
        self.report: SimReport | None = None
        self.home_enu = np.zeros(3)
        self.local_port: int | None = None
        self.gcs_port: int | None = None  # the vehicle's GCS-like link (sitl.observer)
        self._ctx = multiprocessing.get_context("spawn")
        self._conn: Any = None
        self._proc: Any = None
        self.steal_monitor = StealMonitor()

    def __enter__(self) -> SimProcess:
        self.steal_monitor.start()
        parent, child = self._ctx.Pipe()
        self._proc = self._ctx.Process(target=_child, args=(child, self.options), daemon=True)
        self._proc.start()
        self._conn = parent
        if not parent.poll(60):
            self._proc.kill()
            raise RuntimeError("simulated vehicle did not start")
        _, self.local_port, home, self.gcs_port = parent.recv()
        self.home_enu = np.asarray(home, dtype=float)
        return self

    def _ask(self, *message: Any) -> Any:
        self._conn.send(message)
        if not self._conn.poll(10):
            raise RuntimeError("simulated vehicle does not answer")
        return self._conn.recv()

    def state(self) -> dict[str, Any]:
        """True and estimated position (world ENU), velocity, mode, collisions so far."""
        return self._ask("state")

    def block_link(self, blocked: bool = True) -> None:
        """Drop all MAVLink traffic in both directions (a link loss)."""
        self._ask("block", blocked)

    def force_disarm(self) -> int:
        """Disarm now, in the air too (a kill switch); returns the MAV_RESULT."""
        return self._ask("disarm")

    def setpoints(self, start: int = 0) -> dict[str, np.ndarray]:
        """The offboard setpoints received so far (from index ``start``), as
        :attr:`SimReport.setpoints`."""
        return self._ask("setpoints", start)

    def __exit__(self, *exc: object) -> None:
        try:
            self._conn.send(("stop",))
            while self._conn.poll(20):
                item = self._conn.recv()
                if isinstance(item, SimReport):
                    self.report = item
                    break
        finally:
            self.steal_monitor.stop()
            if self.report is not None:
                self.report.host_steal = self.steal_monitor.samples()
            self._proc.join(5)
            if self._proc.is_alive():
                self._proc.kill()
