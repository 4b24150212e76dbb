"""Errors raised by the library for bad input. Solver trouble is never raised: it
is reported in the result (see :mod:`rota.result`)."""

from __future__ import annotations

from typing import Any

import numpy as np


def plain(value: Any) -> str:
    """``repr`` of a value as a user reads it in a message: numpy numbers and arrays
    as plain numbers and lists (``0.0``, not ``np.float64(0.0)``)."""
    if isinstance(value, np.generic | np.ndarray):
        value = value.tolist()
    elif isinstance(value, tuple | list):
        return ("[{}]" if isinstance(value, list) else "({})").format(
            ", ".join(plain(x) for x in value) + ("," if len(value) == 1
                                                  and isinstance(value, tuple) else ""))
    return repr(value)


class InputError(ValueError):
    """Bad input, naming the offending field (for example ``trajectory.knot_span``)."""

    def __init__(self, field: str, message: str) -> None:
        self.field = field
        self.message = message
        super().__init__(f"{field}: {message}")

    def within(self, parent: str) -> InputError:
        """The same error with ``parent.`` prefixed to the field path."""
        sep = "" if self.field.startswith("[") else "."
        return InputError(f"{parent}{sep}{self.field}", self.message)
