"""Where ROTA's velocity-to-uncertainty model comes from: the single seam between
the configuration (now) and the in-flight estimator (which implements the same
protocol). The service asks for the model at every re-time."""

from __future__ import annotations

from typing import Any, Protocol

from rota.chance import UncertaintyModel


class UncertaintySource(Protocol):
    def model(self) -> UncertaintyModel:
        """The model to use for the next re-time."""

    def describe(self) -> dict[str, Any]:
        """JSON-ready description for the status channel."""


class ConfiguredUncertainty:
    """The model from the configuration file, fixed."""

    def __init__(self, model: UncertaintyModel) -> None:
        self._model = model

    def model(self) -> UncertaintyModel:
        return self._model

    def describe(self) -> dict[str, Any]:
        return {"source": "config", "m": self._model.m, "b": self._model.b,
                "per_axis": self._model.per_axis}


def origin(desc: dict[str, Any]) -> str:
    """Where the model in use came from, in words, from its ``describe()``."""
    if desc.get("source") == "estimator" and desc.get("in_use") == "estimate":
        return (f"learned in flight ({desc.get('evidence_s', 0):g} s of evidence, "
                f"{desc.get('samples', 0)} samples)")
    if desc.get("source") == "estimator":
        return "configured ([uncertainty]; the estimator's own is not yet trusted)"
    return "configured ([uncertainty])"
