"""Console-script entry points of the simulator CLIs (see :mod:`companion.entry`)."""

import sys

from companion.entry import run

#: rota-sitl's flight commands (sitl/flights_cli.py); the rest are experiments. (Here, not
#: imported from there: nothing is imported before the shim's Ctrl-C guard.)
FLIGHTS = ("demo", "bench-stream", "soak", "fuzz", "parity", "startup")


def sim() -> int:
    return run("rota-sim", "sitl.cli")


def sitl() -> int:
    """``rota-sitl``: the flights (light to start: the demo speaks at once) or the
    experiments, by the first command word."""
    first = next((a for a in sys.argv[1:] if not a.startswith("-")), None)
    return run("rota-sitl", "sitl.flights_cli" if first in FLIGHTS else "sitl.experiment_cli")
