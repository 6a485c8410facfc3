"""Helpers shared by the export tests: random Gaussians with a logged seed."""

from __future__ import annotations

import random

import pytest
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


@pytest.fixture
def seed() -> int:
    """A fresh random seed per test; tests put it in their assertion messages."""
    return random.randrange(2**31)
