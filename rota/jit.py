"""Compiled kernels: where numba keeps its cache, and warming them up.

The re-timer's inner loops (path evaluation, check points and their rows, the
reachability passes and the interior-point solver) are compiled with numba
(:mod:`rota.kernels`). Compiling them takes seconds; numba keeps the machine code
on disk, so later processes only load it. The cache directory is, in order:

1. the ``cache_dir`` given to :func:`configure` or :func:`warm_up`;
2. ``$ROTA_CACHE_DIR``;
3. ``$CACHE_DIRECTORY`` (set by systemd for a unit with ``CacheDirectory=``, the
   one writable place under a sandboxed unit);
4. ``~/.cache/rota``;

the first that can be created and written; failing all, a directory in the
system's temporary directory, and failing that no disk cache (the kernels are
then compiled in every process).

The kernels are imported on first use, so the directory can be chosen after
``import rota`` but before the first re-time (or :func:`warm_up`).
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

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


def kernels() -> SimpleNamespace:
    """The compiled kernels (:mod:`rota.kernels`), loaded on first use, each with
    Ctrl-C held while it runs (:mod:`rota.interrupt`)."""
    found = _state["kernels"]
    if found is None:
        if _state["dir"] is None:
            configure()
        import rota.kernels as mod  # noqa: PLC0415 - deliberately lazy
        from rota.interrupt import guarded  # noqa: PLC0415

        found = _state["kernels"] = guarded(mod)
    return found  # type: ignore[return-value]


def warm_up(cache_dir: str | os.PathLike[str] | None = None) -> float:
    """Load (or compile) every kernel and run each once on a tiny problem.

    Call it before the first re-time that matters (the flight service calls it
    before it reports ready). ``cache_dir``: where numba keeps compiled code (see
    the module docstring). Returns the seconds it took: about the import and
    load time with a warm cache, the full compile time with a cold one.
    """
    start = time.perf_counter()
    configure(cache_dir)
    kernels()
    from rota.warmup import exercise  # noqa: PLC0415

    exercise()
    return time.perf_counter() - start
