"""Novel-view metrics exactly as the DNGaussian evaluation computes them."""

from __future__ import annotations

from sparsesplat.engine.metrics.evaluate import Evaluator, SceneScores
from sparsesplat.engine.metrics.image import (
    MetricError,
    avge,
    masked_psnr,
    mse,
    psnr,
    quantize,
    ssim,
)
from sparsesplat.engine.metrics.lpips import LPIPS, lpips_distance

__all__ = [
    "LPIPS",
    "Evaluator",
    "MetricError",
    "SceneScores",
    "avge",
    "lpips_distance",
    "masked_psnr",
    "mse",
    "psnr",
    "quantize",
    "ssim",
]
