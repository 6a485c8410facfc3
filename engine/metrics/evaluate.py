"""Score novel views the way the paper does.

Renders and ground truth are first rounded to 8 bits (the reference writes PNGs and re-reads
them). LLFF/Blender: PSNR, SSIM and LPIPS on the full images. DTU (views with a mask):
PSNR over pixels where the mask is exactly 1 after compositing both images on white; SSIM and
LPIPS on the white-composited full images. Scene values are means over the test views; AVGE
is computed from the scene means (as ``metrics_count.py`` does)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sparsesplat.engine.metrics.image import (
    avge,
    composite_white,
    masked_psnr,
    psnr,
    quantize,
    ssim,
)
from sparsesplat.engine.metrics.lpips import LPIPS


@dataclass
class SceneScores:
    """Paper metrics for one scene."""

    psnr: float
    """Mean PSNR over the test views (masked PSNR for DTU)."""
    ssim: float
    """Mean scikit-image SSIM."""
    lpips: float
    """Mean LPIPS-VGG (DNGaussian's [0, 1] input convention)."""
    avge: float
    """Geometric mean of MSE(psnr), sqrt(1 - ssim), lpips, from the means above."""
    per_view: list[dict[str, float]] = field(default_factory=list)
    """Per test view: psnr, ssim, lpips."""

    def as_dict(self) -> dict[str, Any]:
        """Plain dict for JSON reports."""
        return {
            "psnr": self.psnr,
            "ssim": self.ssim,
            "lpips": self.lpips,
            "avge": self.avge,
            "per_view": self.per_view,
        }


class Evaluator:
    """Scores lists of (render, gt, mask) triples; holds one LPIPS network."""

    def __init__(
        self,
        models_dir: Path | None = None,
        quantize_8bit: bool = True,
        lpips: LPIPS | None = None,
    ) -> None:
        """``quantize_8bit``: round both images to 8 bits first, as the reference does;
        ``lpips``: an already built network to share (else one is loaded)."""
        self.lpips = lpips if lpips is not None else LPIPS(models_dir)
        self.quantize_8bit = quantize_8bit

    def score_view(self, render: Any, gt: Any, mask: Any | None = None) -> dict[str, float]:
        """PSNR, SSIM, LPIPS of one view (DTU convention when ``mask`` is given)."""
        if self.quantize_8bit:
            render, gt = quantize(render), quantize(gt)
        if mask is not None:
            value = masked_psnr(render, gt, mask)
            render, gt = composite_white(render, mask), composite_white(gt, mask)
        else:
            value = psnr(render, gt)
        return {"psnr": value, "ssim": ssim(render, gt), "lpips": self.lpips.distance(render, gt)}

    def score(self, items: Sequence[tuple[Any, Any, Any | None]]) -> SceneScores:
        """Scene scores for (render, gt, mask-or-None) triples, one per test view."""
        rows = [self.score_view(r, g, m) for r, g, m in items]
        if not rows:
            raise ValueError("no views to evaluate")
        n = len(rows)
        mean = {k: sum(row[k] for row in rows) / n for k in ("psnr", "ssim", "lpips")}
        return SceneScores(
            mean["psnr"],
            mean["ssim"],
            mean["lpips"],
            avge(mean["psnr"], mean["ssim"], mean["lpips"]),
            rows,
        )
