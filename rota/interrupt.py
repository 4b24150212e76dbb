"""Ctrl-C during compiled code: held until the compiled call returns.

Why: numba's compiled functions run without the GIL (``nogil``). A SIGINT that
arrives meanwhile only sets CPython's "signal pending" flag; the Python-level
handler runs at the next bytecode the main thread executes. When the compiled
call returns, numba's wrapper re-takes the GIL and, while boxing the results,
calls back into Python (``numba.core.serialize._numba_unpickle``, which rebuilds
constants of the returned objects). The pending handler runs inside that frame
and raises ``KeyboardInterrupt`` there, and the wrapper does not check for it:
it either finishes boxing and returns a result with an exception set (CPython
turns that into ``SystemError: CPUDispatcher(...) returned a result with an
exception set``, which kills a Jupyter kernel) or boxes the NULL it got back into
the result and crashes (a segmentation fault, seen on long solves).

What: :class:`Guarded` wraps each kernel (:func:`rota.jit.kernels` hands out only
guarded kernels). In the main thread it makes sure SIGINT's Python handler is
:func:`_on_sigint`, which wraps whatever handler was there before (Python's
default, asyncio's, a user's). Outside compiled calls it calls that handler at
once, so nothing changes; inside one it only records the signal, and the
guard calls the previous handler as soon as the outermost compiled call has
returned, so ``KeyboardInterrupt`` is raised in Python code, between kernels
(a re-time checks between its rounds this way). A compiled call itself is not
cut short: Ctrl-C takes effect when the running kernel returns.

The guard costs a few microseconds a call (1-2 us; 5-8 us measured on this
machine at a load of 16 on 2 cores), against 10-70 us for the smallest kernel
call; no system call unless someone replaced the handler since the last call.
Other threads need none: Python runs signal handlers only in the main thread.
"""

from __future__ import annotations

import _signal
import signal
import threading
from collections.abc import Callable
from types import FrameType, ModuleType, SimpleNamespace
from typing import Any

_MAIN = threading.main_thread().ident
# signal.getsignal calls this C function and converts its answer to an enum, by
# trying and failing for a function (an exception each call: 37 us, measured)
_getsignal = _signal.getsignal
_SIGINT = signal.SIGINT.value
_state: dict[str, Any] = {"depth": 0, "pending": None, "previous": None}


def _on_sigint(signum: int, frame: FrameType | None) -> None:
    if _state["depth"]:
        _state["pending"] = (signum, frame)
        return
    _state["previous"](signum, frame)


def _install() -> bool:
    """Make :func:`_on_sigint` SIGINT's handler (wrapping the one in place);
    False when the handler is not a Python function (ignored, the OS default)."""
    current = _getsignal(signal.SIGINT)
    if current is _on_sigint:
        return True
    if not callable(current):
        return False
    try:
        signal.signal(signal.SIGINT, _on_sigint)
    except ValueError:  # not the main interpreter
        return False
    _state["previous"] = current
    return True


class Guarded:
    """A compiled function with SIGINT held while it runs (module docstring).
    Attributes other than the call (``signatures``...) are the function's."""

    __slots__ = ("fn",)

    def __init__(self, fn: Callable[..., Any]) -> None:
        self.fn = fn

    def __getattr__(self, name: str) -> Any:
        return getattr(self.fn, name)

    def __call__(self, *args: Any) -> Any:
        if threading.get_ident() != _MAIN or (_getsignal(_SIGINT) is not _on_sigint
                                              and not _install()):
            return self.fn(*args)
        _state["depth"] += 1
        try:
            return self.fn(*args)
        finally:
            _state["depth"] -= 1
            pending = _state["pending"]
            if pending is not None and not _state["depth"]:
                _state["pending"] = None
                _state["previous"](*pending)


def guarded(module: ModuleType) -> SimpleNamespace:
    """The functions ``module.__all__`` names, each :class:`Guarded`."""
    names = list(module.__all__)
    return SimpleNamespace(__all__=names, **{n: Guarded(getattr(module, n)) for n in names})
