"""Metric test fixtures: a deterministic test photo and the LPIPS network (skips without it)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sparsesplat.engine.metrics import LPIPS
from sparsesplat.engine.weights import WeightsNotFound


def fixed_photo(h: int = 64, w: int = 96) -> np.ndarray:
    """A smooth, structured float image in [0, 1] that needs no file: gradients, stripes and a
    disc, so blur and noise have something to destroy."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    r = 0.5 + 0.5 * np.sin(x / 3.0) * np.cos(y / 5.0)
    g = x / (w - 1)
    b = ((x - w / 2) ** 2 + (y - h / 2) ** 2 < (h / 3) ** 2).astype(np.float64) * 0.8 + 0.1
    return np.stack([r, g, b], axis=-1)


@pytest.fixture(scope="session")
def lpips_net(models_dir: Path) -> LPIPS:
    """The LPIPS-VGG network from the models directory."""
    try:
        return LPIPS(models_dir)
    except WeightsNotFound as exc:
        pytest.skip(f"LPIPS weights not available: {exc}")
