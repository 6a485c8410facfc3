"""Build (once, cached) and load the native CPU colour-field extension (hash grid, SH encoding).

Same conventions as the rasterizer's loader (engine/raster/build.py): compiled by
``torch.utils.cpp_extension.load`` at first use into ``$TORCH_EXTENSIONS_DIR`` (torch's default
cache when unset) in a directory keyed by a hash of the sources and flags, reused by later
processes and other checkouts of the same sources; the whole build targets x86-64-v3 (AVX2 +
FMA) and the AVX-512 level kernels live in their own translation unit, called only when the CPU
reports AVX-512 at run time. ``-ffp-contract=off`` keeps ``x * scale + 0.5`` two roundings, as
in the torch reference, so both pick the same grid cell at boundaries.
"""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

from sparsesplat.engine.errors import EngineError
from sparsesplat.engine.native_build import NativeExtension

SOURCE_DIR = Path(__file__).resolve().parent / "cpu"
"""Folder holding the C++ sources."""
SOURCES = ("hashgrid.cpp", "sh.cpp", "kernels_avx2.cpp", "kernels_avx512.cpp")
"""Translation units of the extension (headers: common.h, kernels.h)."""
EXTENSION_NAME = "sparsesplat_hashgrid_cpu"
"""Prefix of the built module's and its build directory's names (``native_build`` appends a
hash of the sources, headers and flags)."""
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


_EXTENSION = NativeExtension(
    EXTENSION_NAME,
    SOURCE_DIR,
    SOURCES,
    CFLAGS,
    on_failure=HashGridBuildError,
    failure_hint="needs g++ with AVX2 support and ninja; set SPARSESPLAT_HASHGRID=torch to use "
    "the torch implementation instead",
    description="native hash grid",
)


def load_extension() -> ModuleType:
    """Return the compiled extension, building it on first use; HashGridBuildError on failure."""
    return _EXTENSION.load()
