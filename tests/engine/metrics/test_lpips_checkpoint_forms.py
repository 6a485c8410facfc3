"""LPIPS loads both the features-only file and a full torchvision VGG16 checkpoint
(what `sparsesplat fetch-weights` downloads), with identical results."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import torch

from sparsesplat.engine.metrics.lpips import LIN_FILE, LPIPS, VGG_FILE


def test_full_torchvision_checkpoint_loads(models_dir: Path, tmp_path: Path, seed: int) -> None:
    if not (models_dir / VGG_FILE).exists() or not (models_dir / LIN_FILE).exists():
        pytest.skip(f"LPIPS weights not in {models_dir}")
    state = torch.load(models_dir / VGG_FILE, map_location="cpu", weights_only=True)
    state["classifier.0.weight"] = torch.zeros(8, 8)  # what a full checkpoint adds
    state["classifier.0.bias"] = torch.zeros(8)
    torch.save(state, tmp_path / VGG_FILE)
    shutil.copy(models_dir / LIN_FILE, tmp_path / LIN_FILE)
    g = torch.Generator().manual_seed(seed)
    a, b = torch.rand(2, 1, 3, 40, 48, generator=g)
    full, features_only = LPIPS(tmp_path), LPIPS(models_dir)
    # The same weights through the same code on the same input: the same bits, not a tolerance.
    assert float(full(a, b)) == float(features_only(a, b)), f"seed {seed}"
    assert float(full(a, b)) > 0, f"seed {seed}"
