"""Elementwise cos, sin, arccos and arctan2 that give the same bits on every x86-64 machine.

numpy picks its loops for the CPU at run time: on a CPU with AVX-512 its float64 arccos (and some others) come
from Intel's SVML, elsewhere from the C library, and the two differ in the last bits. A friction margin or a
quality term computed on one machine then differs from the same run on another, so the export's bytes (CONTRACT.md:
the same input, parameters and seed give a byte-identical export) and the golden files depended on the worker's
CPU. These functions run compiled loops that call the C library's functions on every CPU, as the other kernels do.
On a CPU without AVX-512 they give exactly numpy's values (tests/graspgen/test_libm.py).

Each takes array-likes (any shape; arctan2 broadcasts its two) and returns a float64 array of that shape. The loop
is one `njit(cache=True)` kernel, compiled on first use and loaded from numba's cache after that (numba's
`vectorize` would build its four ufuncs at import, 0.6 s for every process).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from numba import njit

__all__ = ["arccos", "arctan2", "cos", "sin"]


_ACOS, _COS, _SIN, _ATAN2 = 0, 1, 2, 3


@njit(cache=True)
def _apply(op: int, a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """out[i] = op(a[i]) (op(a[i], b[i]) for atan2): one kernel, so one cache entry to load."""
    for i in range(out.size):
        if op == _ACOS:
            out[i] = math.acos(a[i])
        elif op == _COS:
            out[i] = math.cos(a[i])
        elif op == _SIN:
            out[i] = math.sin(a[i])
        else:
            out[i] = math.atan2(a[i], b[i])


def _unary(op: int, x: npt.ArrayLike) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    out = np.empty(a.shape, dtype=np.float64)
    flat = np.ascontiguousarray(a).reshape(-1)
    _apply(op, flat, flat, out.reshape(-1))
    return out


def arccos(x: npt.ArrayLike) -> np.ndarray:
    return _unary(_ACOS, x)


def cos(x: npt.ArrayLike) -> np.ndarray:
    return _unary(_COS, x)


def sin(x: npt.ArrayLike) -> np.ndarray:
    return _unary(_SIN, x)


def arctan2(y: npt.ArrayLike, x: npt.ArrayLike) -> np.ndarray:
    b, a = np.broadcast_arrays(np.asarray(y, dtype=np.float64), np.asarray(x, dtype=np.float64))
    out = np.empty(a.shape, dtype=np.float64)
    _apply(_ATAN2, np.ascontiguousarray(b).reshape(-1), np.ascontiguousarray(a).reshape(-1), out.reshape(-1))
    return out
