"""engine/malloc.py: with the setting on, a training step's large buffers are reused, not
page-faulted in again. Measured in fresh subprocesses (the setting is process-wide)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from tests.conftest import REPO

# Three 13 MB blocks (the size of a 50k x 64 activation) touched and freed, ten times: the
# page faults per round. Freed together they leave a heap top above glibc's default trim
# threshold, which is given back to the kernel and faulted in again next round.
_PROBE = """
import ctypes, resource, sys
from sparsesplat.engine.malloc import keep_freed_memory
if sys.argv[1] == "keep" and not keep_freed_memory():
    print("unsupported"); raise SystemExit
libc = ctypes.CDLL(None)
libc.malloc.restype = ctypes.c_void_p
libc.malloc.argtypes = [ctypes.c_size_t]
libc.free.argtypes = [ctypes.c_void_p]
libc.memset.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_size_t]
size = 13 << 20
def step():
    blocks = [libc.malloc(size) for _ in range(3)]
    for b in blocks:
        libc.memset(b, 1, size)
    for b in reversed(blocks):
        libc.free(b)
for _ in range(3):
    step()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(10):
    step()
print((resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before) / 10)
"""


def _faults_per_step(mode: str) -> str:
    out = subprocess.run(
        [sys.executable, "-c", _PROBE, mode], cwd=REPO, capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0, out.stderr
    return out.stdout.strip()


def test_freed_blocks_are_reused_without_page_faults() -> None:
    kept = _faults_per_step("keep")
    if kept == "unsupported":
        pytest.skip("not glibc: keep_freed_memory() is a no-op here")
    # 3 x 13 MB is ~10k pages: glibc's defaults fault most of them in again every step.
    assert float(_faults_per_step("default")) > 1000, "the probe no longer shows the problem"
    assert float(kept) < 50
