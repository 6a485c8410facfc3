"""Per-image metrics as the DNGaussian evaluation computes them (PSNR, scikit-image SSIM,
AVGE, DTU masked PSNR). Images are (H, W, 3) float in [0, 1], tensors or arrays."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from sparsesplat.engine.errors import EngineError


class MetricError(EngineError, ValueError):
    """Metric inputs are malformed (shape mismatch, wrong channel count, empty mask)."""


def as_hwc(image: Any, name: str = "image") -> np.ndarray:
    """(H, W, 3) float64 array from a tensor/array in HWC (or CHW with 3 channels) layout."""
    arr = image.detach().cpu().numpy() if hasattr(image, "detach") else np.asarray(image)
    if arr.ndim == 3 and arr.shape[0] == 3 and arr.shape[2] != 3:
        arr = np.transpose(arr, (1, 2, 0))
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise MetricError(f"{name}: expected an (H, W, 3) image, got shape {arr.shape}")
    return arr.astype(np.float64)


def _pair(render: Any, gt: Any) -> tuple[np.ndarray, np.ndarray]:
    a, b = as_hwc(render, "render"), as_hwc(gt, "gt")
    if a.shape != b.shape:
        raise MetricError(f"render is {a.shape[:2]} but gt is {b.shape[:2]}")
    return a, b


def quantize(image: Any) -> np.ndarray:
    """Round to 8 bits and back, as the reference does by saving PNGs before scoring."""
    arr = image.detach().cpu().numpy() if hasattr(image, "detach") else np.asarray(image)
    return np.clip(arr * 255.0 + 0.5, 0, 255).astype(np.uint8).astype(np.float64) / 255.0


def mse(render: Any, gt: Any) -> float:
    """Mean squared error over all pixels and channels."""
    a, b = _pair(render, gt)
    return float(np.mean((a - b) ** 2))


def psnr_from_mse(value: float) -> float:
    """20 log10(1 / sqrt(mse)); +inf for identical images."""
    return math.inf if value <= 0 else -10.0 * math.log10(value)


def psnr(render: Any, gt: Any) -> float:
    """PSNR in dB for images in [0, 1] (+inf when identical)."""
    return psnr_from_mse(mse(render, gt))


def ssim(render: Any, gt: Any) -> float:
    """The paper's evaluation SSIM: scikit-image ``structural_similarity(channel_axis=2,
    data_range=1.0)`` on HWC float images (7x7 uniform window, K1 0.01, K2 0.03). Training
    uses 3DGS's Gaussian-window SSIM instead (``engine.losses.gaussian_window_ssim``)."""
    from skimage.metrics import structural_similarity

    a, b = _pair(render, gt)
    return float(structural_similarity(a, b, channel_axis=2, data_range=1.0))


def masked_psnr(render: Any, gt: Any, mask: Any) -> float:
    """DTU's masked PSNR: render and gt are composited on white with the mask
    (x * m + (1 - m)), and the MSE is taken only over pixels where the mask is exactly 1."""
    a, b = _pair(render, gt)
    m = mask.detach().cpu().numpy() if hasattr(mask, "detach") else np.asarray(mask)
    m = m.astype(np.float64)
    if m.ndim == 3:
        m = m[..., 0]
    if m.shape != a.shape[:2]:
        raise MetricError(f"mask is {m.shape} but images are {a.shape[:2]}")
    full = m == 1.0
    if not full.any():
        raise MetricError("mask has no pixel equal to 1; masked PSNR is undefined")
    m3 = m[..., None]
    a = a * m3 + (1.0 - m3)
    b = b * m3 + (1.0 - m3)
    return psnr_from_mse(float(np.mean((a[full] - b[full]) ** 2)))


def composite_white(image: Any, mask: Any) -> np.ndarray:
    """x * m + (1 - m): the DTU evaluation's composite for SSIM/LPIPS."""
    a = as_hwc(image)
    m = mask.detach().cpu().numpy() if hasattr(mask, "detach") else np.asarray(mask)
    m = m.astype(np.float64)
    m = m[..., :1] if m.ndim == 3 else m[..., None]
    return a * m + (1.0 - m)


def avge(psnr_value: float, ssim_value: float, lpips_value: float) -> float:
    """Geometric mean of MSE = 10^(-PSNR/10), sqrt(1 - SSIM) and LPIPS (RegNeRF definition,
    as the sparse-view literature and DNGaussian's metrics_count.py use it)."""
    mse_value = 0.0 if math.isinf(psnr_value) else 10.0 ** (-psnr_value / 10.0)
    dssim = math.sqrt(max(0.0, 1.0 - ssim_value))
    return float((mse_value * dssim * max(0.0, lpips_value)) ** (1.0 / 3.0))
