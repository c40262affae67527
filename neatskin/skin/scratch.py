"""Scratch memory for the skin's vectorised arithmetic: uninitialised arrays carved from one block per thread, kept
from call to call.

Why: a fresh temporary of a few hundred kB comes from mmap, and its page faults cost as much as the arithmetic over a
dry-run press's few hundred states (skin/modelgrad.py: 5.4 -> 2.5 us a row for 256 presses; skin/kernelpinch.py's
interpolation, docs/skin.md). The rule for a caller: every `arrays` call carves from the block's start, so one call
gives all the temporaries a computation needs at once, they are dead by the next call in the thread, and nothing a
function returns is such a view (copy out, or write into the caller's own array).
"""

from __future__ import annotations

import math
import threading

import numpy as np

BLOCK_MAX = 1 << 21  # float64 elements (16 MB) kept at most; larger requests get their own arrays
_BLOCKS = threading.local()


def arrays(*shapes: tuple[int, ...]) -> list[np.ndarray]:
    """Uninitialised float64 arrays of these shapes, views of this thread's block (larger requests get their own)."""
    sizes = [math.prod(shape) for shape in shapes]
    total = sum(sizes)
    if total > BLOCK_MAX:
        return [np.empty(shape) for shape in shapes]
    block = getattr(_BLOCKS, "block", None)
    if block is None or block.size < total:
        block = np.empty(max(total, 1 << 16))
        _BLOCKS.block = block
    offsets = np.cumsum([0, *sizes])
    return [block[lo:hi].reshape(shape) for lo, hi, shape in zip(offsets[:-1], offsets[1:], shapes)]


def buffers(count: int, shape: tuple[int, ...]) -> list[np.ndarray]:
    """`count` uninitialised arrays of `shape`, as `arrays`."""
    return arrays(*([shape] * count))
