"""Held-out evaluation during training matches the metrics module's paper protocol."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from sparsesplat.engine.metrics import Evaluator as PaperEvaluator
from sparsesplat.engine.train.evaluate import Evaluator


def test_cached_reference_features_match_the_paper_evaluator(models_dir: Path) -> None:
    if not (models_dir / "lpips_v0.1_lin_vgg.pth").exists():
        pytest.skip(f"LPIPS weights not in {models_dir}")
    seed = int(torch.randint(0, 2**31 - 1, ()).item())
    g = torch.Generator().manual_seed(seed)
    gt = torch.rand(36, 44, 3, generator=g)
    mask = torch.rand(36, 44, generator=g) > 0.3
    ours, paper = Evaluator(), PaperEvaluator()
    for step in range(3):  # the same view scored repeatedly, as during training
        pred = (gt + 0.1 * (step + 1) * torch.randn(36, 44, 3, generator=g)).clamp(0, 1)
        for m in (None, mask):
            key = "view" if m is None else "masked-view"
            got = ours.score(pred.permute(2, 0, 1), gt, m, key=key)
            want = paper.score_view(pred.numpy(), gt.numpy(), None if m is None else m.numpy())
            for name in ("psnr", "ssim", "lpips"):
                assert got[name] == pytest.approx(want[name], rel=1e-5), f"{name}, seed {seed}"
