"""Build (once, cached) and load the native CPU rasterizer extension.

The extension is compiled by ``torch.utils.cpp_extension.load`` at first use into
``$TORCH_EXTENSIONS_DIR`` (torch's default cache when unset); later processes reuse the cached
build unless the sources or flags change. The whole build targets x86-64-v3 (AVX2 + FMA); the
AVX-512 tile kernels live in their own translation unit and are only called when the CPU reports
AVX-512 at run time.
"""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

from sparsesplat.engine.errors import RasterError
from sparsesplat.engine.native_build import NativeExtension

SOURCE_DIR = Path(__file__).resolve().parent / "cpu"
"""Folder holding the C++ sources."""
EXTENSION_NAME = "sparsesplat_raster_cpu"
"""Module name of the built extension (torch caches builds under this name)."""
CFLAGS = ["-O3", "-mavx2", "-mfma", "-mf16c", "-fopenmp", "-fno-math-errno", "-std=c++17"]
"""Compiler flags: the portable x86-64-v3 baseline plus OpenMP."""

_EXTENSION = NativeExtension(
    EXTENSION_NAME,
    SOURCE_DIR,
    ("raster.cpp", "kernels_avx2.cpp", "kernels_avx512.cpp"),
    CFLAGS,
    on_failure=RasterError,
    failure_hint="needs g++ with AVX2 support and ninja",
    description="CPU rasterizer",
)


def load_extension() -> ModuleType:
    """Return the compiled extension, building it on first use; RasterError on build failure."""
    return _EXTENSION.load()
