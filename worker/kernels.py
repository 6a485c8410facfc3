"""Workers build the native CPU kernels when they start, before they take work.

A fresh install compiles the kernels once (minutes on 2 cores). Done at the first job, that job
waited with no sign of why; done here, the training worker claims nothing until they are
ready, the render worker answers once they are, and ``<data_dir>/kernels.json`` says what is
happening to ``/healthz`` and ``/readyz`` meanwhile. A cached build only loads (well under a
second once torch is imported, which a worker does anyway).
"""

from __future__ import annotations

import logging

from sparsesplat.api.kernel_status import STATUS_FILE
from sparsesplat.api.settings import Settings

log = logging.getLogger(__name__)


def needs_cpu_kernels(settings: Settings) -> bool:
    """Whether this service renders or trains on the CPU (``auto`` without a CUDA GPU)."""
    device = settings.device.value
    if device == "cpu":
        return True
    if device != "auto":
        return False
    import torch

    return not torch.cuda.is_available()


def prepare_kernels(settings: Settings) -> None:
    """Build or load every native CPU kernel, recording progress in the data folder. A failed
    build is logged, not raised: the worker still serves, and work that needs the kernels fails
    with the build's error (what the job or render then reports)."""
    if not needs_cpu_kernels(settings):
        return
    from sparsesplat.engine.errors import EngineError
    from sparsesplat.engine.kernels import build_all

    try:
        variants = build_all(settings.data_dir / STATUS_FILE)
    except EngineError:
        log.exception("the native CPU kernels could not be built")
        return
    log.info("native CPU kernels ready", extra={"variants": variants})
