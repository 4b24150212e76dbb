"""Small input checks shared by the library (and ``sitl``); every error names the
field it is about (:class:`rota.errors.InputError`)."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from rota.errors import InputError

FloatArray = NDArray[np.float64]


def positive(value: object, name: str) -> float:
    """A positive, finite number (not a boolean, not a string)."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise InputError(name, f"must be a positive finite number, got {value!r}")
    x = float(value)
    if not math.isfinite(x) or x <= 0:
        raise InputError(name, f"must be a positive finite number, got {value!r}")
    return x


def vector3(value: object, name: str) -> FloatArray:
    """Three finite numbers (x, y, z); a bad component is named (``name[1]``)."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(name, f"must be 3 numbers (x, y, z), got {value!r}") from None
    if arr.shape != (3,):
        raise InputError(name, f"must be 3 numbers (x, y, z), got shape {arr.shape}")
    bad = ~np.isfinite(arr)
    if bad.any():
        raise InputError(f"{name}[{int(np.argmax(bad))}]", "must be finite (got NaN or inf)")
    return arr
