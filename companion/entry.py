"""The console scripts' entry points: each CLI's ``main`` behind a light shim.

The shim imports nothing heavy before its ``try``, so Ctrl-C at any moment,
also while numpy, numba or zenoh are still being imported, ends with one line
("PROG: interrupted") and exit status 130 instead of a traceback. Once ``main``
has returned, SIGINT is ignored, so the exit status is the command's own.
"""

from __future__ import annotations

import signal
import sys
from importlib import import_module

INTERRUPTED = 130


def package_version() -> str:
    """rota-companion's version as installed ("unknown" when run from a source tree),
    for every CLI's ``--version`` (the library's own CLI has its copy: ``rota`` cannot
    import the service)."""
    from importlib.metadata import PackageNotFoundError, version  # (not before the shim)

    try:
        return version("rota-companion")
    except PackageNotFoundError:  # pragma: no cover - a source tree
        return "unknown"


def run(prog: str, module: str) -> int:
    """Import ``module`` and return its ``main()``; 130 with one line on Ctrl-C.

    While importing, SIGINT is also recorded: an import may turn the
    KeyboardInterrupt into another error (numpy's C extensions raise ImportError
    "PyCapsule_Import could not import module ..."). ``main`` runs with Python's
    default handler back in place (asyncio and the CLIs rely on it)."""
    seen: list[int] = []

    def on_sigint(signum: int, frame: object) -> None:
        seen.append(signum)
        raise KeyboardInterrupt

    # Ctrl-C inside a callback the interpreter calls (importlib's module-lock weakref
    # callback) cannot propagate: Python would print "Exception ignored in ..." and go
    # on; ``seen`` has it, so the hook keeps quiet about it.
    hook = sys.unraisablehook

    def quiet(unraisable: object) -> None:
        if not isinstance(getattr(unraisable, "exc_value", None), KeyboardInterrupt):
            hook(unraisable)

    signal.signal(signal.SIGINT, on_sigint)
    sys.unraisablehook = quiet
    try:
        main = import_module(module).main
        signal.signal(signal.SIGINT, signal.default_int_handler)
        sys.unraisablehook = hook
        if seen:  # an import swallowed it
            raise KeyboardInterrupt
        code = main()
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    except BaseException as exc:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        sys.unraisablehook = hook
        if not (seen or isinstance(exc, KeyboardInterrupt)):
            raise
        print(f"{prog}: interrupted", file=sys.stderr, flush=True)
        return INTERRUPTED
    return code


def rota() -> int:
    return run("rota", "rota.cli")


def companion() -> int:
    return run("rota-companion", "companion.cli")


def gs() -> int:
    return run("rota-gs", "companion.gs.cli")
