"""Keep freed heap memory in the process instead of handing it back to the OS after each step.

A training iteration allocates and frees the same large tensors every step (the colour field's
(N, 64) activations are ~13 MB each at 50k Gaussians). glibc serves blocks that large with a
fresh ``mmap`` and unmaps them on free, so every step pays a page fault per 4 KB page and the
kernel's zeroing of it again: about 8 ms of a 0.22 s iteration at 50k Gaussians
(``make bench-iteration``). Raising the mmap threshold to its maximum (32 MB on 64-bit) and
disabling heap trimming lets the freed blocks be reused. The price is that the process keeps its
peak heap until it exits, which a training process reaches anyway.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_MMAP_THRESHOLD_MAX = 4 * 1024 * 1024 * ctypes.sizeof(ctypes.c_long)  # glibc's upper limit
_done = False


def keep_freed_memory() -> bool:
    """Apply the settings above once per process (glibc on Linux only; elsewhere a no-op).
    Returns whether they are in effect."""
    global _done
    if _done:
        return True
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc (e.g. musl has no mallopt)
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    ok = mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD_MAX) == 1
    ok = mallopt(_M_TRIM_THRESHOLD, 2**31 - 1) == 1 and ok
    _done = ok
    return ok
