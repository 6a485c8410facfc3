"""Held-out evaluation during training matches the metrics module's paper protocol."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import torch

from sparsesplat.engine.metrics import LPIPS, quantize
from sparsesplat.engine.metrics import Evaluator as PaperEvaluator
from sparsesplat.engine.metrics.image import composite_white
from sparsesplat.engine.train.evaluate import Evaluator
from tests.engine.numerics import assert_float32_close


def _lpips64(net: LPIPS, render: np.ndarray, truth: np.ndarray, mask: np.ndarray | None) -> float:
    """LPIPS in float64 of the images the paper protocol scores (8-bit, white-composited where
    masked): the reference for the float32 LPIPS of both evaluators."""
    render, truth = quantize(render), quantize(truth)
    if mask is not None:
        render, truth = composite_white(render, mask), composite_white(truth, mask)

    def nchw(a: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.asarray(a, dtype=np.float64)).permute(2, 0, 1)[None]

    with torch.no_grad():
        return float(net(nchw(render), nchw(truth))[0])


def test_cached_reference_features_match_the_paper_evaluator(models_dir: Path, seed: int) -> None:
    """PSNR and SSIM (float64 numpy on the same 8-bit images) equal the paper evaluator's;
    LPIPS, float32 in both, is within the float32 rule of LPIPS in float64 with the paper
    evaluator's as the scale (a sum of positive terms: the value is its own terms)."""
    if not (models_dir / "lpips_v0.1_lin_vgg.pth").exists():
        pytest.skip(f"LPIPS weights not in {models_dir}")
    g = torch.Generator().manual_seed(seed)
    gt = torch.rand(36, 44, 3, generator=g)
    mask = torch.rand(36, 44, generator=g) > 0.3
    ours, paper = Evaluator(), PaperEvaluator()
    net64 = copy.deepcopy(paper.lpips).double()
    for step in range(3):  # the same view scored repeatedly, as during training
        pred = (gt + 0.1 * (step + 1) * torch.randn(36, 44, 3, generator=g)).clamp(0, 1)
        for m in (None, mask):
            key = "view" if m is None else "masked-view"
            m_np = None if m is None else m.float().numpy()
            got = ours.score(pred.permute(2, 0, 1), gt, m, key=key)
            want = paper.score_view(pred.numpy(), gt.numpy(), m_np)
            for name in ("psnr", "ssim"):
                assert got[name] == want[name], f"{name}, seed {seed}"
            exact = _lpips64(net64, pred.numpy(), gt.numpy(), m_np)
            trio = [torch.tensor([float(v)], dtype=torch.float64)
                    for v in (got["lpips"], exact, want["lpips"])]  # fmt: skip
            assert_float32_close(*trio, what=f"lpips, step {step}, mask {m is not None}, "
                                 f"seed {seed}")  # fmt: skip
