"""Build (once, cached) and load the native CPU photometric-loss extension.

Built and cached by :mod:`engine.native_build` (compiled at first use, reused by content key)
from the shared baseline flags. ``-ffp-contract=off``: the kernel writes its FMAs explicitly
(the blur taps) and everything else rounds as written, so its rounding does not depend on the
compiler's contraction choices.
"""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

from sparsesplat.engine.errors import EngineError
from sparsesplat.engine.native_build import BASELINE_CFLAGS, NO_FP_CONTRACT, NativeExtension


class PhotometricBuildError(EngineError, RuntimeError):
    """The native photometric-loss extension could not be compiled or loaded."""


_EXTENSION = NativeExtension(
    "sparsesplat_photometric_cpu",
    Path(__file__).resolve().parent / "cpu",
    ("photometric.cpp", "depth_norm.cpp", "warp.cpp"),
    [*BASELINE_CFLAGS, NO_FP_CONTRACT],
    on_failure=PhotometricBuildError,
    failure_hint="set SPARSESPLAT_PHOTOMETRIC=torch to use the torch implementation instead",
    description="native photometric loss",
    fallback=(
        "the photometric, patch-normalized depth and warp-consistency losses run their torch"
        " implementations instead (as with SPARSESPLAT_PHOTOMETRIC=torch), slower per training"
        " iteration: dozens of full-image tensor operations where the kernels make one pass"
    ),
)


def load_extension() -> ModuleType:
    """Return the compiled extension, building it on first use; PhotometricBuildError on
    failure."""
    return _EXTENSION.load()


def load_extension_or_none() -> ModuleType | None:
    """The extension, or None where it cannot be built (one warning says the torch
    implementations run instead, the first time; the build is not tried again)."""
    return _EXTENSION.load_or_none()
