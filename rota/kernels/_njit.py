"""The one decorator of the kernels: numba's ``njit`` with the on-disk cache when
:mod:`rota.jitcache` found a writable directory."""

import numba

from rota.jitcache import cache_enabled


def njit(fn):
    return numba.njit(cache=cache_enabled(), nogil=True, error_model="numpy")(fn)
