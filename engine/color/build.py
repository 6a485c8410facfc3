"""Build (once, cached) and load the native CPU colour-field extension (hash grid, SH encoding).

Same conventions as the rasterizer's loader (engine/raster/build.py): compiled by
``torch.utils.cpp_extension.load`` at first use into ``$TORCH_EXTENSIONS_DIR`` (torch's default
cache when unset) and reused by later processes unless sources or flags change; the whole build
targets x86-64-v3 (AVX2 + FMA) and the AVX-512 level kernels live in their own translation unit,
called only when the CPU reports AVX-512 at run time. ``-ffp-contract=off`` keeps ``x * scale +
0.5`` two roundings, as in the torch reference, so both pick the same grid cell at boundaries.
"""

from __future__ import annotations

import logging
import os
import shutil
import sys
import threading
from pathlib import Path
from types import ModuleType

from sparsesplat.engine.errors import EngineError

log = logging.getLogger(__name__)

SOURCE_DIR = Path(__file__).resolve().parent / "cpu"
"""Folder holding the C++ sources."""
SOURCES = ("hashgrid.cpp", "sh.cpp", "kernels_avx2.cpp", "kernels_avx512.cpp")
"""Translation units of the extension (headers: common.h, kernels.h)."""
EXTENSION_NAME = "sparsesplat_hashgrid_cpu"
"""Module name of the built extension (torch caches builds under this name)."""
CFLAGS = [
    "-O3",
    "-mavx2",
    "-mfma",
    "-mf16c",
    "-fopenmp",
    "-fno-math-errno",
    "-ffp-contract=off",
    "-std=c++17",
]
"""Compiler flags: the portable x86-64-v3 baseline plus OpenMP, without FMA contraction."""


class HashGridBuildError(EngineError, RuntimeError):
    """The native hash-grid extension could not be compiled or loaded."""


_lock = threading.Lock()
_module: ModuleType | None = None


def _ensure_ninja_on_path() -> None:
    """torch's builder needs ``ninja``; the venv ships it next to the interpreter."""
    if shutil.which("ninja") is None:
        bindir = str(Path(sys.executable).parent)
        os.environ["PATH"] = bindir + os.pathsep + os.environ.get("PATH", "")


def load_extension() -> ModuleType:
    """Return the compiled extension, building it on first use; HashGridBuildError on failure."""
    global _module
    if _module is not None:
        return _module
    with _lock:
        if _module is not None:
            return _module
        _ensure_ninja_on_path()
        from torch.utils import cpp_extension

        try:
            mod = cpp_extension.load(
                name=EXTENSION_NAME,
                sources=[str(SOURCE_DIR / f) for f in SOURCES],
                extra_cflags=CFLAGS,
                extra_ldflags=["-fopenmp"],
                extra_include_paths=[str(SOURCE_DIR)],
                verbose=False,
            )
        except Exception as exc:  # the builder raises RuntimeError/CalledProcessError/OSError
            tail = str(exc)[-4000:]
            raise HashGridBuildError(
                f"building the native hash grid from {SOURCE_DIR} failed (needs g++ with AVX2 "
                f"support and ninja; set SPARSESPLAT_HASHGRID=torch to use the torch "
                f"implementation instead): {tail}"
            ) from exc
        log.info("native hash grid loaded: %s kernels", mod.variant())
        _module = mod
        return mod
