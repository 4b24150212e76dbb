"""Console-script entry points of the simulator CLIs (see :mod:`companion.entry`)."""

from companion.entry import run


def sim() -> int:
    return run("rota-sim", "sitl.cli")


def sitl() -> int:
    return run("rota-sitl", "sitl.experiment_cli")
