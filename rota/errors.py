"""Errors raised by the library for bad input. Solver trouble is never raised: it
is reported in the result (see :mod:`rota.result`)."""

from __future__ import annotations


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
