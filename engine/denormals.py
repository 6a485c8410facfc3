"""Flush float32 denormals to zero on every compute thread while a model trains.

Adam's first moment decays by 0.9 per step on the hash-table rows that stop receiving gradient
(Gaussians pruned, moved or dropped for a step), so after a few hundred steps millions of
entries sit in the denormal range (below 1.2e-38) for the ~150 steps before they underflow to
zero. x86 CPUs handle each denormal operand with a microcode assist of a hundred cycles or more:
measured on a flower run at 47.7k Gaussians (iteration 2000 of 3000), 1.7M of the table's 12.2M
first-moment entries were denormal and Adam took 46 ms of a 0.29 s iteration at two threads;
with denormals flushed, 12 ms (one thread: 56 -> 22 ms; docs/experiments/2026-11-26-denormals.md).

Flushing changes only values below 1.2e-38 (their effect on a parameter is below float32's
resolution of any value they are added to). The MXCSR register holding the mode is per thread
and ``torch.set_flush_denormal`` sets the calling thread's only, while Adam and the kernels run
on the OpenMP team; the colour extension sets it on every team thread. Without that extension
(not built on this machine) the calling thread's mode is set, which covers one-thread runs.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import torch


def _set(on: bool) -> bool:
    """Set the mode on all compute threads (or the calling one); return the previous mode."""
    from sparsesplat.engine.color.build import load_extension_or_none

    # The build is tried once per process (one warning where it fails).
    module = load_extension_or_none()
    if module is not None:
        return bool(module.set_flush_denormal_all(on))
    torch.set_flush_denormal(on)  # the native extension could not be built: this thread only
    return False  # torch cannot read the mode back; off is the process default


@contextmanager
def flush_denormals() -> Iterator[None]:
    """Flush denormals to zero on every compute thread inside the block; restore the previous
    mode after. Enter it after setting the thread count (threads started later inherit the mode
    of the thread that starts them)."""
    before = _set(True)
    try:
        yield
    finally:
        _set(before)
