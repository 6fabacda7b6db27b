"""Elementwise cos, sin, arccos and arctan2 that give the same bits on every x86-64 machine.

numpy picks its loops for the CPU at run time: on a CPU with AVX-512 its float64 arccos (and some others) come
from Intel's SVML, elsewhere from the C library, and the two differ in the last bits. A friction margin or a
quality term computed on one machine then differs from the same run on another, so the export's bytes (CONTRACT.md:
the same input, parameters and seed give a byte-identical export) and the golden files depended on the worker's
CPU. These ufuncs are numba's, which call the C library's functions on every CPU, as the compiled kernels do.
On a CPU without AVX-512 they give exactly numpy's values (tests/graspgen/test_libm.py).
"""

from __future__ import annotations

import math

from numba import vectorize

__all__ = ["arccos", "arctan2", "cos", "sin"]


@vectorize(["float64(float64)"], cache=True)
def arccos(x):
    return math.acos(x)


@vectorize(["float64(float64)"], cache=True)
def cos(x):
    return math.cos(x)


@vectorize(["float64(float64)"], cache=True)
def sin(x):
    return math.sin(x)


@vectorize(["float64(float64, float64)"], cache=True)
def arctan2(y, x):
    return math.atan2(y, x)
