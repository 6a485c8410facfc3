"""Held-out evaluation: PSNR, SSIM, LPIPS and AVGE of renders against ground truth.

Uses ``sparsesplat.engine.metrics`` when it provides the functions; falls back to a local PSNR
and the 3DGS SSIM otherwise, and reports LPIPS/AVGE as None when LPIPS cannot be computed
(e.g. weights absent), never failing the run for a missing metric.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import torch
from torch import Tensor

from sparsesplat.engine.losses import ssim as gs_ssim


def _psnr(pred: Tensor, gt: Tensor) -> float:
    mse = float(torch.mean((pred.double() - gt.double()) ** 2))
    return 99.0 if mse <= 1e-10 else -10.0 * math.log10(mse)


class Evaluator:
    """Scores (3, H, W) renders against (3, H, W) ground truth, metric backends resolved once."""

    def __init__(self, use_lpips: bool = True) -> None:
        """Resolve the metric implementations (LPIPS only if ``use_lpips``)."""
        self._psnr: Callable[[Tensor, Tensor], float] = _psnr
        self._ssim: Callable[[Tensor, Tensor], float] = lambda a, b: float(gs_ssim(a, b))
        self._lpips: Callable[[Tensor, Tensor], float] | None = None
        self.ssim_kind = "gs"
        """Which SSIM is reported: 'sk' (scikit-image, the paper's) or 'gs' (3DGS fallback)."""
        try:
            from sparsesplat.engine import metrics

            if hasattr(metrics, "psnr"):
                self._psnr = lambda a, b: float(metrics.psnr(_hwc(a), _hwc(b)))
            if hasattr(metrics, "ssim"):
                self._ssim = lambda a, b: float(metrics.ssim(_hwc(a), _hwc(b)))
                self.ssim_kind = "sk"
            if use_lpips:
                self._lpips = _make_lpips(metrics)
        except Exception:  # metrics module absent or broken: keep the fallbacks
            pass

    def score(self, pred: Tensor, gt: Tensor) -> dict[str, float | None]:
        """Metrics of one view (images clamped to [0, 1] first, as when saved)."""
        pred = pred.detach().clamp(0, 1).float().cpu()
        gt = gt.detach().float().cpu()
        lp = None
        if self._lpips is not None:
            try:
                lp = float(self._lpips(pred, gt))
            except Exception:
                self._lpips = None
        return {"psnr": self._psnr(pred, gt), "ssim": self._ssim(pred, gt), "lpips": lp}

    def mean(self, scores: Sequence[dict[str, float | None]]) -> dict[str, float | None]:
        """Scene means plus AVGE (geometric mean of MSE, sqrt(1 - SSIM), LPIPS)."""
        out: dict[str, float | None] = {}
        for key in ("psnr", "ssim", "lpips"):
            vals = [s[key] for s in scores if s[key] is not None]
            out[key] = sum(vals) / len(vals) if vals and len(vals) == len(scores) else None
        out["avge"] = avge(out["psnr"], out["ssim"], out["lpips"])
        return out


def avge(psnr: float | None, ssim: float | None, lpips: float | None) -> float | None:
    """AVGE (RegNeRF definition) from scene-mean PSNR, SSIM and LPIPS; None if any is None."""
    if psnr is None or ssim is None or lpips is None:
        return None
    mse = 10 ** (-psnr / 10)
    dssim = math.sqrt(max(1.0 - ssim, 0.0))
    return (mse * dssim * max(lpips, 0.0)) ** (1.0 / 3.0)


def _hwc(x: Tensor) -> Tensor:
    return x.permute(1, 2, 0).contiguous()


def _make_lpips(metrics: Any) -> Callable[[Tensor, Tensor], float] | None:
    """Find an LPIPS entry point in the metrics module (function or class); None if absent."""
    fn = getattr(metrics, "lpips", None)
    if callable(fn) and not isinstance(fn, type):
        return lambda a, b: float(fn(_hwc(a), _hwc(b)))
    cls = getattr(metrics, "LPIPS", None)
    if isinstance(cls, type):
        model = cls()
        return lambda a, b: float(model(_hwc(a), _hwc(b)))
    return None
