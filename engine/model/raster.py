"""How a model is rasterized: the settings (the ``raster`` section of a run's config) and the
rasterizer bound to them, shared by the trainer's renders and a loaded model's."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any, Literal, Protocol

from torch import Tensor

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.raster import RasterOutput, rasterize

RasterBackendName = Literal["auto", "cpu", "cuda", "reference"]
"""The rasterizer backends ``engine.raster.rasterize`` accepts."""


class Raster(Protocol):
    """``raster(means, log_scales, quats, opacity_logits, features, camera, background)``: the
    run's rasterizer with its near plane, dilation and backend bound (:func:`bind_raster`)."""

    def __call__(
        self,
        means: Tensor,
        log_scales: Tensor,
        quats: Tensor,
        opacity_logits: Tensor,
        features: Tensor,
        camera: Camera,
        background: Tensor | None,
        *,
        opacity_depth: bool = False,
    ) -> RasterOutput:
        """Render; ``opacity_depth`` as ``rasterize`` takes it (the fused soft-depth term)."""
        ...


@dataclass(frozen=True)
class RasterConfig:
    """``raster``: the rasterizer every render of the run (and of its stored model) uses."""

    backend: RasterBackendName = "auto"
    """Backend passed through to ``rasterize``: 'auto' (CUDA tensors → gsplat, CPU tensors →
    the native kernel), 'cpu', 'cuda' or 'reference' (dense float64)."""
    near: float | None = None
    """Cull Gaussians with view z below this. The reference rasterizer uses a fixed 0.2 scene
    units; None uses 0.2 x the scene's near bound instead, so the rule follows scene scale."""
    eps2d: float = 0.3
    """Screen-space dilation of the 2D covariance."""


FLAT_RASTER_NAMES = {"raster_backend": "backend", "raster_near": "near", "eps2d": "eps2d"}
"""The flat names earlier versions stored these fields under (``raster_backend`` ->
``raster.backend``, ...); ``engine.train.config.overrides.FLAT_NAMES`` takes its raster
entries from here."""


def stored_raster_config(config: dict[str, Any]) -> RasterConfig:
    """The raster settings of a config stored in a checkpoint: the nested form
    (``TrainConfig.to_dict``) or the flat one of earlier versions; absent fields keep their
    defaults. Read here, without the training package, so that a renderer needs none of it."""
    section = config.get("raster")
    if isinstance(section, dict):
        values = dict(section)
    else:
        values = {name: config[flat] for flat, name in FLAT_RASTER_NAMES.items() if flat in config}
    return RasterConfig(**values)


def bind_raster(near: float, eps2d: float, backend: str) -> Raster:
    """``rasterize`` with the run's near plane, dilation and backend bound (keyword
    ``opacity_depth`` still passes through, for the trainer's fused soft-depth term)."""
    return functools.partial(rasterize, near=near, eps2d=eps2d, backend=backend)
