"""Build (once, cached) and load the native CPU colour-field extension (hash grid, SH encoding,
the fused MLPs, the threads' flush-denormal mode).

Built and cached by :mod:`engine.native_build` (compiled at first use, reused by content key)
from the shared baseline flags; the AVX-512 kernels are a translation unit of their own, called
only when the CPU reports AVX-512 at run time. On other CPUs (aarch64) the ``*_portable.cpp``
units build the same kernels without intrinsics (on x86 they are empty). ``-ffp-contract=off``
keeps ``x * scale + 0.5`` two roundings, as in the torch reference, so both pick the same grid
cell at boundaries (the MLP kernels write their fused multiply-adds explicitly).
"""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

from sparsesplat.engine.errors import EngineError
from sparsesplat.engine.native_build import BASELINE_CFLAGS, NO_FP_CONTRACT, NativeExtension


class HashGridBuildError(EngineError, RuntimeError):
    """The native hash-grid extension could not be compiled or loaded."""


_EXTENSION = NativeExtension(
    "sparsesplat_hashgrid_cpu",
    Path(__file__).resolve().parent / "cpu",
    (
        "hashgrid.cpp",
        "sh.cpp",
        "fpmode.cpp",
        "mlp.cpp",
        "kernels_avx2.cpp",
        "kernels_avx512.cpp",
        "kernels_portable.cpp",
        "mlp_avx2.cpp",
        "mlp_avx512.cpp",
        "mlp_portable.cpp",
    ),
    [*BASELINE_CFLAGS, NO_FP_CONTRACT],
    on_failure=HashGridBuildError,
    failure_hint="set SPARSESPLAT_HASHGRID=torch to use the torch implementation instead",
    description="native hash grid",
    fallback=(
        "the neural colour field (hash grid, SH encoding, MLPs) runs its torch implementation"
        " instead (as with SPARSESPLAT_HASHGRID=torch), slower per training iteration and"
        " render: per-level gathers and scatters and separate layer ops where the kernels make"
        " one fused pass, and flush-to-zero set on the calling thread only"
    ),
)


def load_extension() -> ModuleType:
    """Return the compiled extension, building it on first use; HashGridBuildError on failure."""
    return _EXTENSION.load()


def load_extension_or_none() -> ModuleType | None:
    """The extension, or None where it cannot be built (one warning says the torch
    implementation runs instead, the first time; the build is not tried again)."""
    return _EXTENSION.load_or_none()


def release_cached_memory() -> int:
    """Unmap the table-gradient block the hash grid keeps for its next backward and return its
    bytes (0 when none is kept or the extension was never loaded in this process): called when
    a training run ends, so a long-lived process does not hold ~50 MB for a backward that may
    never come."""
    module = _EXTENSION.loaded
    return int(module.release_cached_memory()) if module is not None else 0
