"""Roll masks: the free rolls of a candidate as one 64-bit word, bit k for roll k (angle 2 pi k / rolls)."""

from __future__ import annotations

from typing import cast

import numpy as np
from numba import njit

#: roll masks are one 64-bit word per candidate
MAX_ROLLS = 64


def full_mask(rolls: int) -> np.uint64:
    """The word with bits 0..rolls-1 set (1 <= rolls <= MAX_ROLLS)."""
    return np.uint64((1 << rolls) - 1) if rolls < 64 else np.uint64(0xFFFFFFFFFFFFFFFF)


@njit(cache=True, inline="always", error_model="numpy")
def popcount(v: np.uint64) -> np.uint64:
    """The number of set bits of the uint64 `v` (SWAR: no loop, no table)."""
    v = v - ((v >> np.uint64(1)) & np.uint64(0x5555555555555555))
    v = (v & np.uint64(0x3333333333333333)) + ((v >> np.uint64(2)) & np.uint64(0x3333333333333333))
    v = (v + (v >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return (v * np.uint64(0x0101010101010101)) >> np.uint64(56)


def any_free(free: np.ndarray) -> np.ndarray:
    """Per row of the (n, R) bool roll masks, whether any roll is free: (n,) bool. Rows of whole 8-byte words are
    OR-ed as integers, several times faster than ndarray.any(axis=1) on millions of rows."""
    n, rolls = free.shape
    if rolls % 8 or not free.flags.c_contiguous:
        return cast(np.ndarray, free.any(axis=1))  # numpy's stubs give `any` with an axis a bool or an array
    words = free.view(np.uint64).reshape(n, rolls // 8)
    acc = words[:, 0].copy()
    for c in range(1, rolls // 8):
        acc |= words[:, c]
    nonzero: np.ndarray = acc != 0
    return nonzero
