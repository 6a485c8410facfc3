"""Held-out evaluation during training, with the paper's protocol from ``engine.metrics``.

Renders and ground truth are rounded to 8 bits first (the reference scores saved PNGs);
DTU views (those with a mask) use the masked PSNR and white-composited SSIM/LPIPS. LPIPS needs
the VGG weights in the models directory: when they are absent, LPIPS and AVGE are reported as
None (with one warning) rather than failing the run.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence

import numpy as np
import torch
from torch import Tensor

from sparsesplat.engine.metrics.image import composite_white, masked_psnr, psnr, quantize, ssim
from sparsesplat.engine.metrics.lpips import LPIPS
from sparsesplat.engine.weights import WeightsNotFound

log = logging.getLogger(__name__)

# PSNR of identical images is +inf; records keep a finite, recognisable ceiling instead so
# JSON/CSV stay valid numbers.
PSNR_CEILING = 99.0


class Evaluator:
    """Scores (3, H, W) renders against (H, W, 3) ground truth; the LPIPS net is loaded once."""

    def __init__(self, use_lpips: bool = True) -> None:
        """Load LPIPS-VGG if ``use_lpips`` and its weights are available."""
        self.lpips: LPIPS | None = None
        self._reference: dict[str, list[Tensor]] = {}
        if use_lpips:
            try:
                self.lpips = LPIPS()
            except WeightsNotFound as exc:
                log.warning("LPIPS disabled: %s", exc)

    def _lpips(self, render: np.ndarray, truth: np.ndarray, key: str | None) -> float:
        assert self.lpips is not None

        def to_nchw(a: np.ndarray) -> Tensor:
            return torch.from_numpy(a).float().permute(2, 0, 1)[None]

        with torch.no_grad():
            reference = self._reference.get(key) if key is not None else None
            if reference is None:
                reference = self.lpips.features_of(to_nchw(truth))
                if key is not None:
                    self._reference[key] = reference
            return float(self.lpips.distance_to_features(to_nchw(render), reference)[0])

    def score(
        self, pred: Tensor, gt: Tensor, mask: Tensor | None = None, key: str | None = None
    ) -> dict[str, float | None]:
        """Metrics of one view: ``pred`` (3, H, W), ``gt`` (H, W, 3), optional (H, W) mask.
        ``key`` names a fixed ground truth whose LPIPS features may be cached across calls."""
        render = quantize(pred.detach().clamp(0, 1).permute(1, 2, 0).float().cpu())
        truth = quantize(gt.detach().float().cpu())
        if mask is not None:
            m = mask.detach().cpu().float().numpy()
            value = masked_psnr(render, truth, m)
            render, truth = composite_white(render, m), composite_white(truth, m)
        else:
            value = psnr(render, truth)
        lp = self._lpips(render, truth, key) if self.lpips is not None else None
        return {"psnr": min(value, PSNR_CEILING), "ssim": ssim(render, truth), "lpips": lp}

    def mean(self, scores: Sequence[dict[str, float | None]]) -> dict[str, float | None]:
        """Scene means plus AVGE (geometric mean of MSE, sqrt(1 - SSIM), LPIPS)."""
        out: dict[str, float | None] = {}
        for key in ("psnr", "ssim", "lpips"):
            vals = [s[key] for s in scores if s[key] is not None]
            out[key] = sum(vals) / len(vals) if vals and len(vals) == len(scores) else None  # type: ignore[arg-type]
        out["avge"] = avge(out["psnr"], out["ssim"], out["lpips"])
        return out


def avge(psnr_db: float | None, ssim_value: float | None, lpips: float | None) -> float | None:
    """AVGE (RegNeRF definition) from scene-mean PSNR, SSIM and LPIPS; None if any is None."""
    if psnr_db is None or ssim_value is None or lpips is None:
        return None
    mse = 10 ** (-psnr_db / 10)
    dssim = math.sqrt(max(1.0 - ssim_value, 0.0))
    return (mse * dssim * max(lpips, 0.0)) ** (1.0 / 3.0)
