"""Where numba keeps the compiled kernels: the cache directory, chosen once per
process (the rules are in :mod:`rota.jit`). Imports nothing of ``rota``: the kernels'
decorator (:mod:`rota.kernels._njit`) and the loader (:mod:`rota.jit`) both read it."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

_state: dict[str, object] = {"dir": None, "kernels": None}


def _writable(path: Path) -> bool:
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path):
            pass
        return True
    except OSError:
        return False


def resolve_cache_dir(cache_dir: str | os.PathLike[str] | None = None) -> Path | None:
    """The cache directory by the rules of this module (created), or None."""
    candidates = [cache_dir, os.environ.get("ROTA_CACHE_DIR")]
    systemd = os.environ.get("CACHE_DIRECTORY")  # may list several, ':'-separated
    if systemd:
        candidates.append(systemd.split(":")[0])
    candidates += [Path.home() / ".cache" / "rota",
                   Path(tempfile.gettempdir()) / f"rota-cache-{os.getuid()}"]
    for c in candidates:
        if c and _writable(Path(c)):
            return Path(c)
    return None


def configure(cache_dir: str | os.PathLike[str] | None = None) -> Path | None:
    """Choose numba's cache directory (see the module docstring); returns it.

    Takes effect only before the kernels are first loaded in this process;
    afterwards it returns the directory in use.
    """
    if _state["kernels"] is not None:
        return _state["dir"]  # type: ignore[return-value]
    path = resolve_cache_dir(cache_dir)
    import numba

    if path is not None:
        numba.config.CACHE_DIR = str(path)
        os.environ["NUMBA_CACHE_DIR"] = str(path)
    _state["dir"] = path
    return path


def cache_enabled() -> bool:
    return _state["dir"] is not None
