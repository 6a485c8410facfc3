"""Autograd wrappers and backend choice of the native per-pixel losses (engine/photometric/cpu/):
the photometric loss, the patch-normalized depth loss and the warp-consistency L1.

The loss is a scalar, so the native forward computes the gradient with respect to the
prediction in the same call and saves it; the backward only scales it by the upstream scalar.
``engine.losses.photometric_loss`` calls this for float32 CPU images; the environment variable
``SPARSESPLAT_PHOTOMETRIC=torch`` forces its torch implementation (the reference), ``native``
makes unsuited inputs an error instead of a silent fallback.
"""

from __future__ import annotations

import os
from typing import Any

import torch
from torch import Tensor
from torch.autograd.function import once_differentiable

from sparsesplat.engine.photometric.build import load_extension, load_extension_or_none

BACKENDS = ("auto", "native", "torch")
"""Accepted values of $SPARSESPLAT_PHOTOMETRIC ('auto' when unset: native where suited)."""
BACKEND_ENV = "SPARSESPLAT_PHOTOMETRIC"
"""Environment variable choosing the photometric loss implementation."""


def backend() -> str:
    """The requested backend from the environment; ValueError naming the variable if invalid."""
    value = os.environ.get(BACKEND_ENV, "auto").strip().lower() or "auto"
    if value not in BACKENDS:
        raise ValueError(f"${BACKEND_ENV}: expected one of {BACKENDS}, got {value!r}")
    return value


def _native_if_built(choice: str, suited: bool) -> bool:
    """Suited inputs run natively, unless ``auto`` finds the extension cannot be built on this
    machine: then the torch implementation (one warning, the first time). ``native`` insists
    (a failed build raises)."""
    return suited and (choice == "native" or load_extension_or_none() is not None)


def _suited(pred: Tensor, others: tuple[Tensor, ...]) -> bool:
    """float32 CPU (C, H, W) images of one shape, none but ``pred`` asking for a gradient (the
    kernel differentiates with respect to the prediction only)."""
    if pred.dim() != 3 or pred.numel() == 0:
        return False
    return all(
        t.device.type == "cpu" and t.dtype == torch.float32 and t.shape == pred.shape
        for t in (pred, *others)
    ) and not any(t.requires_grad for t in others)


def uses_native(pred: Tensor, *others: Tensor) -> bool:
    """Whether the photometric loss of ``pred`` against ``others`` (the target and its SSIM
    statistics) runs natively: float32 CPU images of one shape, unless the environment forces
    the torch implementation. With ``SPARSESPLAT_PHOTOMETRIC=native`` unsuited inputs raise."""
    choice = backend()
    if choice == "torch":
        return False
    suited = _suited(pred, others)
    if choice == "native" and not suited:
        described = ", ".join(f"{tuple(t.shape)} {t.dtype} on {t.device}" for t in (pred, *others))
        raise ValueError(
            f"${BACKEND_ENV}=native needs float32 CPU (C, H, W) images of one shape and a "
            f"target without gradient; got {described}"
        )
    return _native_if_built(choice, suited)


class _NativeLoss(torch.autograd.Function):
    """A scalar loss whose native kernel returns (value, d value / d first input) in one call;
    the backward only scales the saved gradient by the upstream scalar."""

    @staticmethod
    def forward(ctx: Any, kernel: str, x: Tensor, *args: Any) -> Tensor:
        # x: the only input with a gradient; args: the kernel's other arguments, in its order.
        need_grad = bool(ctx.needs_input_grad[1])
        loss, grad = getattr(load_extension(), kernel)(x, *args, need_grad)
        if need_grad:
            ctx.save_for_backward(grad)
        ctx.n_args = len(args)
        return loss

    @staticmethod
    @once_differentiable
    def backward(ctx: Any, upstream: Tensor) -> tuple[Tensor | None, ...]:
        (grad,) = ctx.saved_tensors
        return (None, grad * upstream, *([None] * ctx.n_args))


def photometric_native(
    pred: Tensor,
    target: Tensor,
    image: Tensor,
    mu: Tensor,
    var: Tensor,
    weights: Tensor,
    lambda_dssim: float,
    c1: float,
    c2: float,
) -> Tensor:
    """``mean|pred - target| + lambda_dssim * (1 - SSIM(pred, image))`` for float32 CPU (C, H, W)
    images, differentiable with respect to ``pred``. ``mu`` and ``var``: ``image``'s blurred
    mean and variance under the separable window ``weights`` (odd length); ``c1``, ``c2``: SSIM's
    stabilizing constants."""
    return _NativeLoss.apply(
        "forward",
        pred.contiguous(),
        target.detach().contiguous(),
        image.detach().contiguous(),
        mu.detach().reshape(pred.shape).contiguous(),
        var.detach().reshape(pred.shape).contiguous(),
        weights.detach().to(torch.float32).contiguous(),
        float(lambda_dssim),
        float(c1),
        float(c2),
    )


def depth_norm_suited(depth: Tensor, target: Tensor) -> bool:
    """Whether the patch-normalized depth loss of ``depth`` against the prior's normalized
    patches ``target`` runs natively: float32 CPU tensors, a target without gradient, unless
    $SPARSESPLAT_PHOTOMETRIC says torch (``native`` makes unsuited inputs an error)."""
    choice = backend()
    if choice == "torch":
        return False
    suited = (
        depth.device.type == "cpu"
        and target.device.type == "cpu"
        and depth.dtype == torch.float32
        and target.dtype == torch.float32
        and not target.requires_grad
    )
    if choice == "native" and not suited:
        raise ValueError(
            f"${BACKEND_ENV}=native needs float32 CPU depth and target without gradient; got "
            f"{depth.dtype} on {depth.device} and {target.dtype} on {target.device}"
        )
    return _native_if_built(choice, suited)


def depth_norm_native(
    depth: Tensor, target: Tensor, patch: int, margin: float, global_mode: bool, std_floor: float
) -> Tensor:
    """``engine.losses.depth_norm_loss`` of a float32 CPU (H, W) ``depth`` against ``target``,
    the prior's normalized (P, patch²) patches, differentiable with respect to ``depth``;
    ``patch`` already clamped to 1..min(H, W)."""
    return _NativeLoss.apply(
        "depth_norm_forward", depth.contiguous(), target.detach().contiguous(), int(patch),
        float(margin), bool(global_mode), float(std_floor),
    )  # fmt: skip


class _WarpL1(torch.autograd.Function):
    """The warp-consistency L1 (cpu/warp.cpp): the forward returns the mean and the per-pixel
    gradient numerators of its sum with respect to depth and alpha; the backward scales them by
    upstream / count."""

    @staticmethod
    def forward(ctx: Any, depth: Tensor, alpha: Tensor | None, *args: Any) -> Tensor:
        need_grad = bool(ctx.needs_input_grad[0] or ctx.needs_input_grad[1])
        loss, count, gd, ga = load_extension().warp_l1_forward(depth, alpha, *args, need_grad)
        ctx.count = int(count)
        if need_grad:
            ctx.save_for_backward(gd, ga if alpha is not None else None)
        ctx.n_args = len(args)
        return loss

    @staticmethod
    @once_differentiable
    def backward(ctx: Any, upstream: Tensor) -> tuple[Tensor | None, ...]:
        gd, ga = ctx.saved_tensors
        scale = upstream / max(ctx.count, 1)
        return (gd * scale, None if ga is None else ga * scale, *([None] * ctx.n_args))


def warp_l1_suited(*maps: Tensor | None) -> bool:
    """Whether the warp-consistency L1 of these maps (depth, alpha, photos, the source's
    depth; None for an absent one) runs natively: float32 CPU tensors, unless
    $SPARSESPLAT_PHOTOMETRIC says torch (``native`` makes unsuited inputs an error)."""
    choice = backend()
    if choice == "torch":
        return False
    given = [m for m in maps if m is not None]
    suited = all(m.device.type == "cpu" and m.dtype == torch.float32 for m in given)
    if choice == "native" and not suited:
        described = ", ".join(f"{m.dtype} on {m.device}" for m in given)
        raise ValueError(f"${BACKEND_ENV}=native needs float32 CPU maps; got {described}")
    return _native_if_built(choice, suited)


def warp_l1_native(
    depth: Tensor,
    alpha: Tensor | None,
    reference_image: Tensor,
    source_image: Tensor,
    source_depth: Tensor | None,
    reference_intrinsics: tuple[float, float, float, float],
    source_intrinsics: tuple[float, float, float, float],
    rotation: Tensor,
    translation: Tensor,
    min_alpha: float,
    occlusion_tolerance: float,
) -> Tensor:
    """``engine.train.regularizers.consistency.warp_consistency_loss`` in one native pass:
    ``depth`` and ``alpha`` (H, W) (differentiable), the (3, H, W) and (3, Hs, Ws) photos, the
    source's seen depth (Hs, Ws) or None, each camera's (fx, fy, cx, cy), and the
    reference-to-source ``rotation`` (3, 3) and ``translation`` (3,)."""
    return _WarpL1.apply(
        depth.contiguous(),
        None if alpha is None else alpha.contiguous(),
        reference_image.detach().contiguous(),
        source_image.detach().contiguous(),
        None if source_depth is None else source_depth.detach().contiguous(),
        [float(k) for k in reference_intrinsics],
        [float(k) for k in source_intrinsics],
        [float(r) for r in rotation.reshape(-1).tolist()],
        [float(t) for t in translation.reshape(-1).tolist()],
        float(min_alpha),
        float(occlusion_tolerance),
    )
