"""Score novel views the way the paper does: the one evaluator of the project (benchmarks and
the trainer's held-out records alike).

Renders and ground truth are first rounded to 8 bits (the reference writes PNGs and re-reads
them). LLFF/Blender: PSNR, SSIM and LPIPS on the full images. DTU (views with a mask):
PSNR over pixels where the mask is exactly 1 after compositing both images on white; SSIM and
LPIPS on the white-composited full images. Scene values are means over the test views; AVGE
is computed from the scene means (as ``metrics_count.py`` does)."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
from torch import Tensor

from sparsesplat.engine.metrics.image import (
    avge,
    composite_white,
    masked_psnr,
    psnr,
    quantize,
    ssim,
)
from sparsesplat.engine.metrics.lpips import LPIPS
from sparsesplat.engine.weights import WeightsNotFound

log = logging.getLogger(__name__)

PSNR_CEILING = 99.0
"""PSNR of identical images is +inf; training records keep this finite, recognisable ceiling
instead so JSON/CSV stay valid numbers."""

LpipsMode = Literal["required", "optional", "off"]
"""LPIPS: the weights must load; used when they load (else None, with one warning); never."""


@dataclass
class SceneScores:
    """Paper metrics for one scene."""

    psnr: float
    """Mean PSNR over the test views (masked PSNR for DTU)."""
    ssim: float
    """Mean scikit-image SSIM."""
    lpips: float | None
    """Mean LPIPS-VGG (DNGaussian's [0, 1] input convention); None without the network."""
    avge: float | None
    """Geometric mean of MSE(psnr), sqrt(1 - ssim), lpips, from the means above."""
    per_view: list[dict[str, float | None]] = field(default_factory=list)
    """Per test view: psnr, ssim, lpips."""

    def as_dict(self) -> dict[str, Any]:
        """Plain dict for JSON reports."""
        return {
            "psnr": self.psnr,
            "ssim": self.ssim,
            "lpips": self.lpips,
            "avge": self.avge,
            "per_view": self.per_view,
        }


def _cpu(image: Any) -> Any:
    """A tensor as a detached CPU float tensor; arrays pass through."""
    return image.detach().float().cpu() if isinstance(image, Tensor) else image


class Evaluator:
    """Scores (render, gt, mask) views; holds one LPIPS network and, per keyed ground truth,
    its LPIPS features (held-out views are scored again and again during training)."""

    def __init__(
        self,
        models_dir: Path | None = None,
        quantize_8bit: bool = True,
        lpips: LPIPS | None = None,
        lpips_mode: LpipsMode = "required",
        psnr_ceiling: float | None = None,
    ) -> None:
        """``quantize_8bit``: round both images to 8 bits first, as the reference does;
        ``lpips``: an already built network to share (else one is loaded per ``lpips_mode``);
        ``psnr_ceiling``: clamp each view's PSNR to this (None: +inf stays)."""
        self.lpips: LPIPS | None = lpips
        if lpips is None and lpips_mode != "off":
            try:
                self.lpips = LPIPS(models_dir)
            except WeightsNotFound as exc:
                if lpips_mode == "required":
                    raise
                log.warning("LPIPS disabled: %s", exc)
        self.quantize_8bit = quantize_8bit
        self.psnr_ceiling = psnr_ceiling
        self._reference: dict[str, list[Tensor]] = {}

    def _lpips(self, render: np.ndarray, truth: np.ndarray, key: str | None) -> float:
        assert self.lpips is not None

        def to_nchw(a: np.ndarray) -> Tensor:
            return torch.from_numpy(np.asarray(a, dtype=np.float64)).float().permute(2, 0, 1)[None]

        with torch.no_grad():
            reference = self._reference.get(key) if key is not None else None
            if reference is None:
                reference = self.lpips.features_of(to_nchw(truth))
                if key is not None:
                    self._reference[key] = reference
            return float(self.lpips.distance_to_features(to_nchw(render), reference)[0])

    def score_view(
        self, render: Any, gt: Any, mask: Any | None = None, key: str | None = None
    ) -> dict[str, float | None]:
        """PSNR, SSIM, LPIPS of one view (DTU convention when ``mask`` is given). Images are
        (H, W, 3) arrays or tensors; a tensor render is clamped to [0, 1]. ``key`` names a
        fixed ground truth whose LPIPS features are kept."""
        render, gt = _cpu(render), _cpu(gt)
        if isinstance(render, Tensor):
            render = render.clamp(0, 1)
        if self.quantize_8bit:
            render, gt = quantize(render), quantize(gt)
        if mask is not None:
            m = mask.detach().cpu().float().numpy() if isinstance(mask, Tensor) else mask
            value = masked_psnr(render, gt, m)
            render, gt = composite_white(render, m), composite_white(gt, m)
        else:
            value = psnr(render, gt)
        if self.psnr_ceiling is not None:
            value = min(value, self.psnr_ceiling)
        lp = self._lpips(render, gt, key) if self.lpips is not None else None
        return {"psnr": value, "ssim": ssim(render, gt), "lpips": lp}

    def mean(self, scores: Sequence[dict[str, float | None]]) -> dict[str, float | None]:
        """Scene means plus AVGE; a metric missing from any view is None (and so is AVGE)."""
        out: dict[str, float | None] = {}
        for key in ("psnr", "ssim", "lpips"):
            vals = [s[key] for s in scores if s[key] is not None]
            out[key] = sum(vals) / len(vals) if vals and len(vals) == len(scores) else None  # type: ignore[arg-type]
        p, s, lp = out["psnr"], out["ssim"], out["lpips"]
        out["avge"] = None if p is None or s is None or lp is None else avge(p, s, lp)
        return out

    def score(self, items: Sequence[tuple[Any, Any, Any | None]]) -> SceneScores:
        """Scene scores for (render, gt, mask-or-None) triples, one per test view."""
        rows = [self.score_view(r, g, m) for r, g, m in items]
        if not rows:
            raise ValueError("no views to evaluate")
        mean = self.mean(rows)
        p, s = mean["psnr"], mean["ssim"]
        assert p is not None and s is not None  # computed for every view
        return SceneScores(p, s, mean["lpips"], mean["avge"], rows)
