"""Numba policy for every kernel in :mod:`raytrace` (DESIGN.md).

``cache=True`` so CI and later runs skip compilation; fastmath without ``nnan``/``ninf``
because misses are ``inf`` and must stay so; ``prange`` only on outer pixel/ray loops.
"""

from __future__ import annotations

import numba

FASTMATH = {"nsz", "arcp", "contract", "afn", "reassoc"}

jit = numba.njit(cache=True, fastmath=FASTMATH, nogil=True)
"""Serial kernel decorator."""

pjit = numba.njit(cache=True, fastmath=FASTMATH, nogil=True, parallel=True)
"""Parallel kernel decorator (outer loop with ``numba.prange``)."""
