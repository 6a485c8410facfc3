"""Losses: photometric (L1, 3DGS SSIM), Global-Local Depth Normalization, depth smoothness,
and DNGaussian's shape / scale / opacity regularizers.

Images are (C, H, W) tensors here. Depth maps are (1, H, W) or (H, W).
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor
from torch.nn import functional as F

from sparsesplat.engine.photometric import native as photometric_native

_STD_FLOOR = 1e-8
"""Floor on the normalization epsilon so constant depth (zero std) gives 0, never 0/0."""


SSIM_C1 = 0.01**2
"""SSIM's stabilizer of the means' term (3DGS's (0.01 * data range)² for [0, 1] images)."""
SSIM_C2 = 0.03**2
"""SSIM's stabilizer of the (co)variances' term."""


def l1_loss(pred: Tensor, target: Tensor) -> Tensor:
    """Mean absolute error."""
    return (pred - target).abs().mean()


def _gaussian_1d(size: int, sigma: float, like: Tensor) -> Tensor:
    coords = torch.arange(size, dtype=like.dtype, device=like.device) - (size - 1) / 2
    g = torch.exp(-(coords**2) / (2 * sigma**2))
    return g / g.sum()


def _blur(stack: Tensor, window: int, sigma: float) -> Tensor:
    """Zero-padded Gaussian blur of every channel of ``stack`` (1, C, H, W). The 2D window is
    the outer product of two 1D windows, and zero padding factors the same way, so two 1D
    passes equal the 11x11 convolution (22 instead of 121 multiply-adds per pixel)."""
    c, pad = stack.shape[1], window // 2
    g = _gaussian_1d(window, sigma, stack)
    vertical = g.view(1, 1, window, 1).expand(c, 1, window, 1)
    horizontal = g.view(1, 1, 1, window).expand(c, 1, 1, window)
    out = F.conv2d(stack, vertical, padding=(pad, 0), groups=c)
    return F.conv2d(out, horizontal, padding=(0, pad), groups=c)


class SSIMTarget:
    """The target-only SSIM statistics (local mean and second moment) of one image, computed
    once: training images never change, so the trainer keeps one per view and each SSIM call
    blurs only the prediction's three maps."""

    def __init__(self, target: Tensor, window: int = 11, sigma: float = 1.5) -> None:
        y = target.detach().unsqueeze(0)
        c = y.shape[1]
        blurred = _blur(torch.cat([y, y * y], dim=1), window, sigma)
        self.image = target.detach()
        self.mu = blurred[:, :c]
        self.var = blurred[:, c:] - self.mu**2
        self.window, self.sigma = window, sigma


def gaussian_window_ssim(
    pred: Tensor,
    target: Tensor | SSIMTarget,
    window: int = 11,
    sigma: float = 1.5,
) -> Tensor:
    """3DGS's training SSIM: 11x11 Gaussian window (sigma 1.5), zero padding, C1=0.01²,
    C2=0.03², mean over all pixels and channels; differentiable. Not the paper's evaluation
    SSIM (scikit-image's 7x7 uniform window on 8-bit images: ``engine.metrics.image.ssim``).
    Inputs (C, H, W) in [0, 1]; ``target`` may be a precomputed :class:`SSIMTarget` (its
    window and sigma then apply)."""
    t = target if isinstance(target, SSIMTarget) else SSIMTarget(target, window, sigma)
    c = pred.shape[0]
    x = pred.unsqueeze(0)
    blurred = _blur(torch.cat([x, x * x, x * t.image.unsqueeze(0)], dim=1), t.window, t.sigma)
    mu_x = blurred[:, :c]
    sxx = blurred[:, c : 2 * c] - mu_x**2
    sxy = blurred[:, 2 * c :] - mu_x * t.mu
    c1, c2 = SSIM_C1, SSIM_C2
    num = (2 * mu_x * t.mu + c1) * (2 * sxy + c2)
    den = (mu_x**2 + t.mu**2 + c1) * (sxx + t.var + c2)
    return (num / den).mean()


def photometric_loss(
    pred: Tensor, target: Tensor, lambda_dssim: float, ssim_target: SSIMTarget | None = None
) -> Tensor:
    """DNGaussian's colour loss: L1 + lambda * (1 - SSIM) (L1 is NOT scaled by 1 - lambda).
    ``ssim_target``: ``target``'s precomputed SSIM statistics, if the caller keeps them.
    float32 CPU images take the fused native kernel (engine/photometric; value and gradient in
    one pass), unless $SPARSESPLAT_PHOTOMETRIC=torch; the code below is its reference."""
    if lambda_dssim == 0:
        return l1_loss(pred, target)
    t = ssim_target or SSIMTarget(target)
    if photometric_native.uses_native(pred, target, t.image, t.mu[0], t.var[0]):
        window = _gaussian_1d(t.window, t.sigma, pred)
        return photometric_native.photometric_native(
            pred, target, t.image, t.mu, t.var, window, lambda_dssim, SSIM_C1, SSIM_C2
        )
    l1 = l1_loss(pred, target)
    return l1 + lambda_dssim * (1.0 - gaussian_window_ssim(pred, t))


def patchify(depth: Tensor, patch: int) -> Tensor:
    """(1, H, W) or (H, W) → (P, patch²) non-overlapping tiles from the top-left corner, row by
    row; the last H mod p rows and W mod p columns are dropped (the layout of ``unfold`` with
    stride = kernel, made by one reshaped copy instead of im2col)."""
    h, w = depth.shape[-2], depth.shape[-1]
    rows, cols = h // patch, w // patch
    d = depth.reshape(h, w)[: rows * patch, : cols * patch]
    tiles = d.reshape(rows, patch, cols, patch).permute(0, 2, 1, 3)
    return tiles.reshape(rows * cols, patch * patch)


def _std(centred: Tensor, dim: int | None = None) -> Tensor:
    """Sample standard deviation of already-centred values (over ``dim``, or all of them).
    The variance is floored at 1e-30 before the square root so a constant patch has a finite
    (zero) gradient, where ``Tensor.std`` gives 0/0; the floor moves the value by 1e-15 at
    most, far below the normalization's epsilon floor."""
    n = centred.numel() if dim is None else centred.shape[dim]
    if n < 2:
        return centred.new_zeros(()) if dim is None else centred.new_zeros(centred.shape[0], 1)
    sq = centred.square()
    total = sq.sum() if dim is None else sq.sum(dim=dim, keepdim=True)
    return (total / (n - 1)).clamp_min(1e-30).sqrt()


def _normalize(patches: Tensor, scale: Tensor | None) -> Tensor:
    """Subtract each patch's mean, divide by its own std (local) or ``scale`` (global), plus an
    epsilon of 1% of the std of all patch values (floored so constant maps give zeros)."""
    centred = patches - patches.mean(dim=1, keepdim=True)
    if scale is None:
        scale = _std(centred, dim=1)
    every = patches - patches.mean()
    eps = torch.clamp_min(0.01 * _std(every), _STD_FLOOR)
    return centred / (scale + eps)


def margin_mse(residual: Tensor, margin: float) -> Tensor:
    """Error-tolerant L2: mean of r² over the elements with |r| > margin. The reference returns
    NaN when nothing exceeds the margin; we return a graph-connected zero instead."""
    keep = residual.abs() > margin
    count = int(keep.sum())
    if count == 0:
        return (residual * 0.0).sum()
    # A masked sum instead of residual[keep]: boolean indexing (nonzero + gather, and a
    # scatter in the backward) cost more than the loss itself on a full-resolution map.
    return torch.where(keep, residual.square(), 0.0).sum() / count


class DepthTarget:
    """The prior-only parts of the depth losses of one training view, computed once: the
    prior's normalized patches per (patch size, mode) and the smoothness weights of its guide.
    The prior never changes during a run, so only the rendered depth is normalized per call."""

    def __init__(self, prior: Tensor, guide: Tensor | None = None) -> None:
        """``prior`` (H, W) or (1, H, W); ``guide``: the smoothness guide (see
        :func:`edge_aware_smoothness`), or None when the run uses no smoothness."""
        self.prior = prior.detach().reshape(prior.shape[-2], prior.shape[-1])
        self._global_scale = _std(self.prior - self.prior.mean())
        self._patches: dict[tuple[int, str], Tensor] = {}
        self.smooth_weights: tuple[Tensor, Tensor] | None = None
        """Per neighbour direction, exp(-|dM|) over its sum (None without a guide)."""
        if guide is not None:
            g = guide.detach().reshape(self.prior.shape)
            self.smooth_weights = _smooth_weights(g)

    def normalized(self, patch: int, mode: str) -> Tensor:
        """The prior's normalized patches for ``patch`` and ``mode`` (cached)."""
        key = (patch, mode)
        if key not in self._patches:
            scale = self._global_scale if mode == "global" else None
            self._patches[key] = _normalize(patchify(self.prior, patch), scale)
        return self._patches[key]


def depth_norm_loss(
    depth: Tensor, target: Tensor | DepthTarget, patch: int, margin: float, mode: str = "local"
) -> Tensor:
    """Patch-normalized depth loss between rendered ``depth`` and prior ``target`` (same size,
    "larger = farther"). ``mode`` 'local' divides each patch by its own std, 'global' by the
    detached std of the whole map (Global-Local Depth Normalization). ``target`` may be a
    :class:`DepthTarget` holding the prior's normalized patches."""
    if mode not in ("local", "global"):
        raise ValueError(f"depth_norm_loss: mode must be 'local' or 'global', got {mode!r}")
    tgt = target if isinstance(target, DepthTarget) else DepthTarget(target)
    h, w = depth.shape[-2], depth.shape[-1]
    patch = max(1, min(patch, h, w))
    prior = tgt.normalized(patch, mode)
    if photometric_native.depth_norm_suited(depth, prior):
        # One native pass for value and gradient (engine/photometric/cpu/depth_norm.cpp).
        return photometric_native.depth_norm_native(
            depth.reshape(h, w), prior, patch, margin, mode == "global", _STD_FLOOR
        )
    pd = patchify(depth, patch)
    if mode == "local":
        nd = _normalize(pd, None)
    else:
        flat = depth.detach().reshape(-1)
        nd = _normalize(pd, _std(flat - flat.mean()))
    return margin_mse(nd - prior, margin)


def global_local_depth_loss(
    depth: Tensor,
    target: Tensor | DepthTarget,
    patch_range: tuple[int, int],
    margin: float,
    generator: torch.Generator,
    global_weight: float = 1.0,
    local_weight: float = 0.1,
) -> Tensor:
    """R = global_weight * GN(p1) + local_weight * LN(p2), p1 and p2 drawn independently and
    uniformly from the inclusive ``patch_range``."""
    lo, hi = patch_range
    p1 = int(torch.randint(lo, hi + 1, (1,), generator=generator))
    p2 = int(torch.randint(lo, hi + 1, (1,), generator=generator))
    tgt = target if isinstance(target, DepthTarget) else DepthTarget(target)
    return global_weight * depth_norm_loss(
        depth, tgt, p1, margin, "global"
    ) + local_weight * depth_norm_loss(depth, tgt, p2, margin, "local")


def _smooth_weights(guide: Tensor) -> tuple[Tensor, Tensor]:
    """exp(-|dM|) along y and x, each divided by its sum (clamped away from 0)."""
    out = []
    for dim in (0, 1):
        wg = torch.exp(-torch.diff(guide, dim=dim).abs())
        out.append(wg / wg.sum().clamp_min(1e-12))
    return out[0], out[1]


def edge_aware_smoothness(
    depth: Tensor, guide: Tensor | None = None, weights: tuple[Tensor, Tensor] | None = None
) -> Tensor:
    """Sum |dD| exp(-|dM|) / sum exp(-|dM|) over x and y neighbours, with weights from the
    guide (the prior depth, pre-scaled to the reference's [0, 257] range by the caller), or
    from ``weights`` precomputed by :class:`DepthTarget` for that guide."""
    d = depth.reshape(depth.shape[-2], depth.shape[-1])
    if weights is None:
        if guide is None:
            raise ValueError("edge_aware_smoothness: give a guide or its weights")
        weights = _smooth_weights(guide.reshape(d.shape))
    return _Smoothness.apply(d, weights[0], weights[1])


class _Smoothness(torch.autograd.Function):
    """sum |d[i+1] - d[i]| w_y + sum |d[:, j+1] - d[:, j]| w_x with a hand-written backward:
    the gradient of each difference is sign x weight, added to one neighbour and taken from the
    other (autograd's diff/abs/mul chain allocates five full-size maps per direction)."""

    @staticmethod
    def forward(ctx: Any, d: Tensor, wy: Tensor, wx: Tensor) -> Tensor:
        dy = d[1:] - d[:-1]
        dx = d[:, 1:] - d[:, :-1]
        total = (dy.abs() * wy).sum() + (dx.abs() * wx).sum()
        ctx.save_for_backward(dy.sign_().mul_(wy), dx.sign_().mul_(wx))
        return total

    @staticmethod
    def backward(ctx: Any, grad: Tensor) -> tuple[Tensor, None, None]:
        gy, gx = ctx.saved_tensors
        h, w = gy.shape[0] + 1, gx.shape[1] + 1
        out = gy.new_zeros(h, w)
        out[1:] += gy
        out[:-1] -= gy
        out[:, 1:] += gx
        out[:, :-1] -= gx
        return out * grad, None, None


def shape_regularizer(scales: Tensor) -> Tensor:
    """mean(max(s) / min(s)): discourages needle-like Gaussians."""
    if scales.shape[0] == 0:
        return scales.sum()
    return (scales.max(dim=1).values / scales.min(dim=1).values.clamp_min(1e-12)).mean()


def scale_regularizer(scales: Tensor) -> Tensor:
    """mean(max(s)²): discourages very large Gaussians."""
    if scales.shape[0] == 0:
        return scales.sum()
    return scales.max(dim=1).values.square().mean()


def opacity_regularizer(opacity: Tensor, threshold: float = 0.2) -> Tensor:
    """1 - mean(a² | a > t) + mean((1 - a)² | a < t), empty selections contributing 0 (the
    reference's second term pushes low opacities up, kept as is; see method notes §6)."""
    # Masked sums over the whole vector instead of boolean indexing: the same means without the
    # gather and the scatter-back (index_put) in the backward.
    hi, lo = opacity > threshold, opacity < threshold
    n_hi, n_lo = int(hi.sum()), int(lo.sum())
    zero = opacity.sum() * 0.0
    term_hi = 1.0 - torch.where(hi, opacity.square(), 0.0).sum() / n_hi if n_hi else zero
    term_lo = torch.where(lo, (1.0 - opacity).square(), 0.0).sum() / n_lo if n_lo else zero
    return term_hi + term_lo
