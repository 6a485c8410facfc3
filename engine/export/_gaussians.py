"""Shared input checks for the exporters: shapes, dtypes and dropping non-finite Gaussians."""

from __future__ import annotations

import logging
from dataclasses import dataclass

import torch
from torch import Tensor

from sparsesplat.engine.export.errors import ExportError
from sparsesplat.engine.export.sh_eval import degree_from_coeffs

log = logging.getLogger(__name__)


@dataclass
class GaussianArrays:
    """The exportable parameters of N Gaussians, float32 on the CPU, all rows finite."""

    means: Tensor
    """(N, 3) centres in world units."""
    log_scales: Tensor
    """(N, 3) log of the per-axis standard deviations."""
    quats: Tensor
    """(N, 4) rotations, wxyz, as stored (not necessarily unit length)."""
    opacity_logits: Tensor
    """(N,) pre-sigmoid opacities."""
    sh: Tensor
    """(N, K, 3) SH coefficients, K = (degree + 1)^2."""
    dropped: int
    """How many input Gaussians were removed because some parameter was not finite."""

    @property
    def degree(self) -> int:
        """SH degree of ``sh``."""
        return degree_from_coeffs(self.sh.shape[1])


def check_gaussians(
    means: Tensor,
    log_scales: Tensor,
    quats: Tensor,
    opacity_logits: Tensor,
    sh: Tensor,
    *,
    what: str,
) -> GaussianArrays:
    """Validate shapes and drop non-finite rows (logged); ``what`` names the target in messages.

    ``opacity_logits`` may be (N,) or (N, 1). Raises :class:`ExportError` on a shape mismatch
    or an SH tensor that is not (N, (d+1)^2, 3) for d in 0..3.
    """
    tensors = {
        "means": means,
        "log_scales": log_scales,
        "quats": quats,
        "opacity_logits": opacity_logits,
        "sh": sh,
    }
    for name, t in tensors.items():
        if not isinstance(t, Tensor):
            raise ExportError(f"{what}: {name} must be a torch.Tensor, got {type(t).__name__}")
    n = means.shape[0] if means.dim() >= 1 else -1
    if opacity_logits.dim() == 2 and opacity_logits.shape[1] == 1:
        opacity_logits = opacity_logits[:, 0]
    expected = {
        "means": (n, 3),
        "log_scales": (n, 3),
        "quats": (n, 4),
        "opacity_logits": (n,),
    }
    got = {
        "means": means,
        "log_scales": log_scales,
        "quats": quats,
        "opacity_logits": opacity_logits,
    }
    for name, shape in expected.items():
        if tuple(got[name].shape) != shape:
            raise ExportError(
                f"{what}: {name} has shape {tuple(got[name].shape)}, expected {shape} "
                f"(N={n} from means)"
            )
    if sh.dim() != 3 or sh.shape[0] != n or sh.shape[2] != 3:
        raise ExportError(f"{what}: sh has shape {tuple(sh.shape)}, expected (N={n}, K, 3)")
    try:
        degree_from_coeffs(sh.shape[1])
    except ValueError as exc:
        raise ExportError(f"{what}: sh: {exc}") from None

    # Detach and move once: exporters work on plain float32 CPU data.
    cpu = [
        t.detach().to("cpu", torch.float32) for t in (means, log_scales, quats, opacity_logits, sh)
    ]
    m, s, q, o, c = cpu
    finite = (
        torch.isfinite(m).all(1)
        & torch.isfinite(s).all(1)
        & torch.isfinite(q).all(1)
        & torch.isfinite(o)
        & torch.isfinite(c).flatten(1).all(1)
    )
    dropped = int((~finite).sum())
    if dropped:
        log.warning("%s: dropped %d of %d Gaussians with non-finite parameters", what, dropped, n)
        m, s, q, o, c = m[finite], s[finite], q[finite], o[finite], c[finite]
    return GaussianArrays(m, s, q, o, c, dropped)
