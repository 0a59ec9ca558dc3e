"""Output arrays whose data starts on a cache line.

The one allocator of the arrays generated C writes when the caller passes none: a
generated ``run_tracks`` called on its own (:meth:`derive.build.FilterModule.run_tracks`)
and the slices of one result that :func:`derive.batch.run_tracks` hands to its threads.
A cache-line start lets a kernel's stores of whole lines and the threads' slices
(multiples of :data:`derive.batch.TRACK_MULTIPLE` tracks) share no line; the pages stay
untouched until the kernel writes them (the writer touches them first).
"""

from __future__ import annotations

import numpy as np

#: The alignment of the arrays :func:`aligned_empty` allocates, bytes (a cache line).
ALIGNMENT = 64


def aligned_empty(shape, dtype) -> np.ndarray:
    """An uninitialised C-contiguous array whose data starts on an :data:`ALIGNMENT`-byte
    boundary (its pages untouched until a thread writes them)."""
    dtype = np.dtype(dtype)
    count = int(np.prod(shape, dtype=np.int64))
    raw = np.empty(count * dtype.itemsize + ALIGNMENT, dtype=np.uint8)
    offset = -raw.ctypes.data % ALIGNMENT
    return raw[offset:offset + count * dtype.itemsize].view(dtype).reshape(shape)
