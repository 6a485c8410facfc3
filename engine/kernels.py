"""The native CPU kernels as one set: which extensions exist and loading (building) them.

Every CPU run needs some of four extensions: the tile rasterizer and the EWA projection
(always), the hash grid and fused MLPs of the neural colour field, and the fused photometric
loss (training). They build once per source version and toolchain (see
:mod:`engine.native_build`); :func:`load_kernels` loads the ones a task needs, and
``sparsesplat build`` (:func:`build_all`) builds all of them ahead of the first job. An
extension that cannot be built on this CPU is not an error: its loader warns once, naming the
torch implementation that runs instead and the slowdown, and its variant reads
:data:`FALLBACK`.
"""

from __future__ import annotations

import importlib
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from sparsesplat.api.kernel_status import KernelState, KernelStatus, write_status


@dataclass(frozen=True)
class Kernel:
    """One native extension and when it is needed."""

    name: str
    """Short name (logs, the build command's table)."""
    module: str
    """Module with the loader function."""
    loader: str
    """Function of ``module`` that loads the extension, building it on first use; None where
    it cannot be built (after one warning)."""
    color: bool = False
    """Needed only with the neural colour field."""
    training: bool = False
    """Needed only for training."""

    def load(self) -> str:
        """Load (build on first use); returns the instruction-set variant it runs, or
        :data:`FALLBACK` where it cannot be built on this CPU."""
        module = getattr(importlib.import_module(self.module), self.loader)()
        return FALLBACK if module is None else str(module.variant())


FALLBACK = "torch"
"""The variant of an extension that cannot be built here: its torch implementation runs."""

KERNELS = (
    Kernel("rasterizer", "sparsesplat.engine.raster.build", "load_extension_or_none"),
    Kernel("projection", "sparsesplat.engine.raster.build", "load_projection_extension_or_none"),
    Kernel("hash grid", "sparsesplat.engine.color.build", "load_extension_or_none", color=True),
    Kernel(
        "photometric loss",
        "sparsesplat.engine.photometric.build",
        "load_extension_or_none",
        training=True,
    ),
)
"""Every native CPU extension of the engine."""


def load_kernels(
    color: bool = True,
    training: bool = True,
    on_each: Callable[[str, str, float], None] | None = None,
) -> dict[str, str]:
    """Load the kernels a CPU task needs (all by default), building those not built yet.
    ``on_each(name, variant, seconds)`` is called after each. Returns name -> variant."""
    variants = {}
    for kernel in KERNELS:
        if (kernel.color and not color) or (kernel.training and not training):
            continue
        started = time.monotonic()
        variants[kernel.name] = kernel.load()
        if on_each is not None:
            on_each(kernel.name, variants[kernel.name], time.monotonic() - started)
    return variants


def build_all(
    status_path: Path | None = None, on_each: Callable[[str, str, float], None] | None = None
) -> dict[str, str]:
    """Build (or load) every kernel, writing the progress to ``status_path`` when given
    (building, then ready with the variants, or failed with the error); the error is re-raised."""
    import os

    status = KernelStatus(state=KernelState.building, started_at=time.time(), pid=os.getpid())
    if status_path is not None:
        write_status(status_path, status)
    try:
        variants = load_kernels(on_each=on_each)
    except Exception as exc:
        if status_path is not None:
            write_status(
                status_path,
                status.model_copy(
                    update={
                        "state": KernelState.failed,
                        "finished_at": time.time(),
                        "message": str(exc),
                    }
                ),
            )
        raise
    if status_path is not None:
        write_status(
            status_path,
            status.model_copy(
                update={
                    "state": KernelState.ready,
                    "finished_at": time.time(),
                    "variants": variants,
                }
            ),
        )
    return variants
