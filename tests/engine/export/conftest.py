"""Helpers shared by the export tests: random Gaussians from a seed (the suite's ``seed``
fixture, tests/conftest.py, gives each test a fresh one and prints it on failure)."""

from __future__ import annotations

import torch
from torch import Tensor


def random_gaussians(n: int, degree: int, seed: int) -> dict[str, Tensor]:
    """N random Gaussians with SH of ``degree``, from ``seed``."""
    g = torch.Generator().manual_seed(seed)
    return {
        "means": torch.randn(n, 3, generator=g) * 2.0,
        "log_scales": torch.randn(n, 3, generator=g) - 3.0,
        "quats": torch.randn(n, 4, generator=g),
        "opacity_logits": torch.randn(n, generator=g) * 2.0,
        "sh": torch.randn(n, (degree + 1) ** 2, 3, generator=g) * 0.3,
    }
