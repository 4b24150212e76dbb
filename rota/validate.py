"""Small input checks shared by the library (and ``sitl``); every error names the
field it is about (:class:`rota.errors.InputError`)."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from rota.errors import InputError, plain

FloatArray = NDArray[np.float64]


def positive(value: object, name: str) -> float:
    """A positive, finite number (not a boolean, not a string)."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise InputError(name, f"must be a positive finite number, got {plain(value)}")
    x = float(value)
    if not math.isfinite(x) or x <= 0:
        raise InputError(name, f"must be a positive finite number, got {plain(value)}")
    return x


def vector3(value: object, name: str) -> FloatArray:
    """Three finite numbers (x, y, z); a bad component is named (``name[1]``)."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(name, f"must be 3 numbers (x, y, z), got {plain(value)}") from None
    if arr.shape != (3,):
        raise InputError(name, f"must be 3 numbers (x, y, z), got shape {arr.shape}")
    bad = ~np.isfinite(arr)
    if bad.any():
        raise InputError(f"{name}[{int(np.argmax(bad))}]", "must be finite (got NaN or inf)")
    return arr


class KeepsReadOnly:
    """Mixin for the library's frozen objects: arrays that were read-only are
    read-only again after pickling (numpy unpickles every array writable).

    The compiled kernels are compiled per array type, and read-only is part of
    it: a map or trajectory sent to a worker process would otherwise reach them
    as a type no warm-up compiled, and its first re-time would compile for
    seconds (seen: the flight service's first re-time after a map timed out).
    """

    def __getstate__(self) -> dict[str, object]:
        state = dict(self.__dict__)
        state["__read_only__"] = [(k, j) for k, v in state.items()
                                  for j, a in _arrays(v) if not a.flags.writeable]
        return state

    def __setstate__(self, state: dict[str, object]) -> None:
        state = dict(state)
        for key, j in state.pop("__read_only__", ()):  # type: ignore[union-attr]
            value = state[key]
            (value if j is None else value[j]).setflags(write=False)  # type: ignore[index]
        self.__dict__.update(state)


def _arrays(value: object) -> list[tuple[int | None, np.ndarray]]:
    """The arrays in an attribute: itself, or the items of a tuple (cached pieces)."""
    if isinstance(value, np.ndarray):
        return [(None, value)]
    if isinstance(value, tuple):
        return [(j, a) for j, a in enumerate(value) if isinstance(a, np.ndarray)]
    return []
