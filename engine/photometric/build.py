"""Build (once, cached) and load the native CPU photometric-loss extension.

Same conventions as the other native extensions (engine/native_build.py): compiled by
``torch.utils.cpp_extension.load`` at first use into ``$TORCH_EXTENSIONS_DIR`` (torch's default
cache when unset), in a directory keyed by a hash of the sources and flags, reused by later
processes and other checkouts of the same sources. The build targets x86-64-v3 (AVX2 + FMA).
``-ffp-contract=off``: the kernel writes its FMAs explicitly (the blur taps) and everything else
rounds as written, so its rounding does not depend on the compiler's contraction choices.
"""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

from sparsesplat.engine.errors import EngineError
from sparsesplat.engine.native_build import NativeExtension

SOURCE_DIR = Path(__file__).resolve().parent / "cpu"
"""Folder holding the C++ source."""
SOURCES = ("photometric.cpp",)
"""Translation units of the extension."""
EXTENSION_NAME = "sparsesplat_photometric_cpu"
"""Prefix of the built module's and its build directory's names (``native_build`` appends a
hash of the sources, headers and flags)."""
CFLAGS = [
    "-O3",
    "-mavx2",
    "-mfma",
    "-fopenmp",
    "-fno-math-errno",
    "-ffp-contract=off",
    "-std=c++17",
]
"""Compiler flags: the portable x86-64-v3 baseline plus OpenMP, FMAs only where written."""


class PhotometricBuildError(EngineError, RuntimeError):
    """The native photometric-loss extension could not be compiled or loaded."""


_EXTENSION = NativeExtension(
    EXTENSION_NAME,
    SOURCE_DIR,
    SOURCES,
    CFLAGS,
    on_failure=PhotometricBuildError,
    failure_hint="needs g++ with AVX2 support and ninja; set SPARSESPLAT_PHOTOMETRIC=torch to "
    "use the torch implementation instead",
    description="native photometric loss",
)


def load_extension() -> ModuleType:
    """Return the compiled extension, building it on first use; PhotometricBuildError on
    failure."""
    return _EXTENSION.load()
