"""Held-out evaluation during training: the one paper-protocol evaluator, with the LPIPS
features of a fixed ground truth cached across evaluations."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from sparsesplat.engine.metrics import LPIPS, quantize
from sparsesplat.engine.metrics.evaluate import PSNR_CEILING, Evaluator
from sparsesplat.engine.metrics.image import composite_white
from tests.engine.numerics import assert_float32_close


def _lpips64(net: LPIPS, render: np.ndarray, truth: np.ndarray, mask: np.ndarray | None) -> float:
    """LPIPS in float64 of the images the paper protocol scores (8-bit, white-composited where
    masked): the reference for the float32 LPIPS of the evaluator."""
    render, truth = quantize(render), quantize(truth)
    if mask is not None:
        render, truth = composite_white(render, mask), composite_white(truth, mask)

    def nchw(a: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.asarray(a, dtype=np.float64)).permute(2, 0, 1)[None]

    with torch.no_grad():
        return float(net(nchw(render), nchw(truth))[0])


def test_cached_reference_features_give_the_uncached_scores(models_dir: Path, seed: int) -> None:
    """A keyed ground truth (its LPIPS features kept) scores exactly as an unkeyed one, tensor
    input exactly as the same images as arrays; LPIPS, float32, is within the float32 rule of
    LPIPS in float64 (a sum of positive terms: the value is its own terms)."""
    if not (models_dir / "lpips_v0.1_lin_vgg.pth").exists():
        pytest.skip(f"LPIPS weights not in {models_dir}")
    g = torch.Generator().manual_seed(seed)
    gt = torch.rand(36, 44, 3, generator=g)
    mask = torch.rand(36, 44, generator=g) > 0.3
    ev = Evaluator(models_dir)
    assert ev.lpips is not None
    net64 = copy.deepcopy(ev.lpips).double()
    for step in range(3):  # the same view scored repeatedly, as during training
        pred = (gt + 0.1 * (step + 1) * torch.randn(36, 44, 3, generator=g)).clamp(0, 1)
        for m in (None, mask):
            key = "view" if m is None else "masked-view"
            m_np = None if m is None else m.float().numpy()
            got = ev.score_view(pred, gt, m, key=key)
            want = ev.score_view(pred.numpy(), gt.numpy(), m_np)
            assert got == want, f"step {step}, mask {m is not None}, seed {seed}"
            exact = _lpips64(net64, pred.numpy(), gt.numpy(), m_np)
            pair = [torch.tensor([float(v)], dtype=torch.float64)
                    for v in (got["lpips"], exact, want["lpips"])]  # fmt: skip
            assert_float32_close(*pair, what=f"lpips, step {step}, mask {m is not None}, "
                                 f"seed {seed}")  # fmt: skip


def test_ceiling_and_lpips_off() -> None:
    """Identical images: +inf PSNR by default, the ceiling when one is set; no LPIPS (and no
    AVGE) when it is off."""
    img = torch.rand(20, 24, 3, generator=torch.Generator().manual_seed(3))
    raw = Evaluator(lpips_mode="off")
    capped = Evaluator(lpips_mode="off", psnr_ceiling=PSNR_CEILING)
    assert raw.score_view(img, img)["psnr"] == math.inf
    row = capped.score_view(img, img)
    assert row["psnr"] == PSNR_CEILING and row["lpips"] is None
    assert capped.mean([row, row]) == {"psnr": PSNR_CEILING, "ssim": 1.0, "lpips": None,
                                       "avge": None}  # fmt: skip
