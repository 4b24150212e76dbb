"""Compiled kernels: where numba keeps its cache, and warming them up.

The re-timer's inner loops (path evaluation, check points and their rows, the
reachability passes and the interior-point solver) are compiled with numba
(:mod:`rota.kernels`). Compiling them takes seconds; numba keeps the machine code
on disk, so later processes only load it. The cache directory is, in order:

1. the ``cache_dir`` given to :func:`configure` or :func:`rota.warmup.warm_up`;
2. ``$ROTA_CACHE_DIR``;
3. ``$CACHE_DIRECTORY`` (set by systemd for a unit with ``CacheDirectory=``, the
   one writable place under a sandboxed unit);
4. ``~/.cache/rota``;

the first that can be created and written; failing all, a directory in the
system's temporary directory, and failing that no disk cache (the kernels are
then compiled in every process).

The kernels are imported on first use, so the directory can be chosen after
``import rota`` but before the first re-time (or :func:`rota.warmup.warm_up`).
"""

from __future__ import annotations

from types import SimpleNamespace

from rota.jitcache import _state, cache_enabled, configure, resolve_cache_dir

__all__ = ["cache_enabled", "configure", "kernels", "resolve_cache_dir"]


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
