"""Build (once, cached) and load the native CPU rasterizer extension.

The extension is compiled by ``torch.utils.cpp_extension.load`` at first use into
``$TORCH_EXTENSIONS_DIR`` (torch's default cache when unset); later processes reuse the cached
build unless the sources or flags change. The whole build targets x86-64-v3 (AVX2 + FMA); the
AVX-512 tile kernels live in their own translation unit and are only called when the CPU reports
AVX-512 at run time.
"""

from __future__ import annotations

import logging
import os
import shutil
import sys
import threading
from pathlib import Path
from types import ModuleType

from sparsesplat.engine.errors import RasterError

log = logging.getLogger(__name__)

SOURCE_DIR = Path(__file__).resolve().parent / "cpu"
"""Folder holding the C++ sources."""
EXTENSION_NAME = "sparsesplat_raster_cpu"
"""Module name of the built extension (torch caches builds under this name)."""
CFLAGS = ["-O3", "-mavx2", "-mfma", "-mf16c", "-fopenmp", "-fno-math-errno", "-std=c++17"]
"""Compiler flags: the portable x86-64-v3 baseline plus OpenMP."""

_lock = threading.Lock()
_module: ModuleType | None = None


def _ensure_ninja_on_path() -> None:
    """torch's builder needs ``ninja``; the venv ships it next to the interpreter."""
    if shutil.which("ninja") is None:
        bindir = str(Path(sys.executable).parent)
        os.environ["PATH"] = bindir + os.pathsep + os.environ.get("PATH", "")


def load_extension() -> ModuleType:
    """Return the compiled extension, building it on first use; RasterError on build failure."""
    global _module
    if _module is not None:
        return _module
    with _lock:
        if _module is not None:
            return _module
        _ensure_ninja_on_path()
        from torch.utils import cpp_extension

        sources = [str(SOURCE_DIR / f) for f in ("raster.cpp", "kernels_avx2.cpp")]
        sources.append(str(SOURCE_DIR / "kernels_avx512.cpp"))
        try:
            mod = cpp_extension.load(
                name=EXTENSION_NAME,
                sources=sources,
                extra_cflags=CFLAGS,
                extra_ldflags=["-fopenmp"],
                extra_include_paths=[str(SOURCE_DIR)],
                verbose=False,
            )
        except Exception as exc:  # the builder raises RuntimeError/CalledProcessError/OSError
            tail = str(exc)[-4000:]
            raise RasterError(
                f"building the CPU rasterizer from {SOURCE_DIR} failed "
                f"(needs g++ with AVX2 support and ninja): {tail}"
            ) from exc
        log.info("CPU rasterizer loaded: %s kernels", mod.variant())
        _module = mod
        return mod
