"""Build (once, cached) and load the native CPU rasterizer extensions.

Two extensions: the tile rasterizer (``raster.cpp`` and the per-ISA kernels) and the fused EWA
projection (``project.cpp``). They are separate modules because each ``torch.utils.cpp_extension``
module has one pybind11 entry point, and the projection's build stays small and independent of
the tile kernels'. Both are built and cached by :mod:`engine.native_build` (compiled at first
use, reused by content key) from the shared baseline flags of the machine's architecture; the
AVX-512 tile kernels live in their own translation unit and are only called when the CPU reports
AVX-512 at run time, and the portable kernels (generic vectors, NEON on aarch64) are the only
ones on other CPUs (on x86 a third variant the tests select). The projection is built with
``-ffp-contract=off`` so that each ``a * b + c`` rounds twice, like the separate torch ops of
``projection.project`` it restates.
"""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

from sparsesplat.engine.errors import RasterError
from sparsesplat.engine.native_build import BASELINE_CFLAGS, NO_FP_CONTRACT, NativeExtension

SOURCE_DIR = Path(__file__).resolve().parent / "cpu"
"""Folder holding the C++ sources of both extensions."""

_EXTENSION = NativeExtension(
    "sparsesplat_raster_cpu",
    SOURCE_DIR,
    ("raster.cpp", "kernels_avx2.cpp", "kernels_avx512.cpp", "kernels_portable.cpp"),
    BASELINE_CFLAGS,
    on_failure=RasterError,
    failure_hint="",
    description="CPU rasterizer",
    fallback=(
        "rendering with the dense torch reference rasterizer instead (engine/raster/reference.py),"
        " far slower: it evaluates every Gaussian at every pixel where the native kernels take"
        " only those whose footprint reaches the pixel's tile, and for training keeps every"
        " (pixel, Gaussian) pair for the backward, so its memory grows with pixels x Gaussians:"
        " fit for small images and scenes only"
    ),
)

_PROJECTION = NativeExtension(
    "sparsesplat_projection_cpu",
    SOURCE_DIR,
    ("project.cpp",),
    [*BASELINE_CFLAGS, NO_FP_CONTRACT],
    on_failure=RasterError,
    failure_hint="",
    description="CPU projection",
    fallback=(
        "projecting with the torch implementation instead (engine/raster/projection.py), a few"
        " times slower: about a hundred small tensor operations each way where the kernel makes"
        " one pass"
    ),
)


def load_extension() -> ModuleType:
    """Return the compiled extension, building it on first use; RasterError on build failure."""
    return _EXTENSION.load()


def load_projection_extension() -> ModuleType:
    """Return the compiled projection extension (built on first use); RasterError on failure."""
    return _PROJECTION.load()


def load_extension_or_none() -> ModuleType | None:
    """The tile rasterizer, or None where it cannot be built (one warning says what runs
    instead, the first time)."""
    return _EXTENSION.load_or_none()


def load_projection_extension_or_none() -> ModuleType | None:
    """The projection extension, or None where it cannot be built (one warning, the first
    time)."""
    return _PROJECTION.load_or_none()
