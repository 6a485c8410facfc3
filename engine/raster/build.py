"""Build (once, cached) and load the native CPU rasterizer extensions.

Two extensions: the tile rasterizer (``raster.cpp`` and the per-ISA kernels) and the fused EWA
projection (``project.cpp``). They are separate modules because each ``torch.utils.cpp_extension``
module has one pybind11 entry point, and the projection's build stays small and independent of
the tile kernels'. Each is compiled by ``torch.utils.cpp_extension.load`` at first use into
``$TORCH_EXTENSIONS_DIR`` (torch's default cache when unset), in a directory keyed by a hash of
the sources and flags (``engine/native_build.py``): later processes and other checkouts of the
same sources reuse it, and a changed source or flag builds afresh. The whole build targets
x86-64-v3 (AVX2 + FMA); the AVX-512 tile kernels live in their own translation unit and are only
called when the CPU reports AVX-512 at run time. The projection is built with
``-ffp-contract=off`` so that each ``a * b + c`` rounds twice, like the separate torch ops of
``projection.project`` it restates.
"""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

from sparsesplat.engine.errors import RasterError
from sparsesplat.engine.native_build import NativeExtension

SOURCE_DIR = Path(__file__).resolve().parent / "cpu"
"""Folder holding the C++ sources."""
EXTENSION_NAME = "sparsesplat_raster_cpu"
"""Prefix of the built module's and its build directory's names (``native_build`` appends a
hash of the sources, headers and flags)."""
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


PROJECTION_EXTENSION_NAME = "sparsesplat_projection_cpu"
"""Prefix of the projection module's and build directory's names (hash appended likewise)."""
PROJECTION_CFLAGS = [*CFLAGS, "-ffp-contract=off"]
"""The rasterizer's flags without FMA contraction (float32 rounding as in the torch version)."""

_PROJECTION = NativeExtension(
    PROJECTION_EXTENSION_NAME,
    SOURCE_DIR,
    ("project.cpp",),
    PROJECTION_CFLAGS,
    on_failure=RasterError,
    failure_hint="needs g++ with AVX2 support and ninja",
    description="CPU projection",
)


def load_extension() -> ModuleType:
    """Return the compiled extension, building it on first use; RasterError on build failure."""
    return _EXTENSION.load()


def load_projection_extension() -> ModuleType:
    """Return the compiled projection extension (built on first use); RasterError on failure."""
    return _PROJECTION.load()
