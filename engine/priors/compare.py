"""Agreement between two depth priors: Spearman rank correlation on confident pixels.

Rank correlation is the right comparison between a metric prior (plane sweep) and a
monocular one, whose depth is only known up to an unknown monotone map. Run as
``python -m sparsesplat.engine.priors.compare SCENE_DIR [--a plane_sweep] [--b pydnet]``.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence

import torch
from torch import Tensor

from sparsesplat.engine.priors.base import PriorDepth

MIN_PIXELS = 50
"""Fewer confident pixels than this gives NaN (no meaningful correlation)."""


def _ranks(x: Tensor) -> Tensor:
    """Ranks 0..n-1 (ties broken by order; continuous depths rarely tie)."""
    order = torch.argsort(x)
    ranks = torch.empty_like(order, dtype=torch.float64)
    ranks[order] = torch.arange(x.numel(), dtype=torch.float64)
    return ranks


def spearman(a: Tensor, b: Tensor) -> float:
    """Spearman rank correlation between two 1-D samples (NaN when too short / constant)."""
    if a.numel() < MIN_PIXELS:
        return float("nan")
    ra, rb = _ranks(a.double()), _ranks(b.double())
    ra, rb = ra - ra.mean(), rb - rb.mean()
    denom = float(ra.norm() * rb.norm())
    return float((ra * rb).sum()) / denom if denom > 0 else float("nan")


def prior_agreement(
    a: PriorDepth, b: PriorDepth, threshold: float = 0.5
) -> tuple[float, float, int]:
    """(Spearman rho, fraction of pixels used, pixel count) on pixels where both priors'
    confidences exceed ``threshold``."""
    if a.depth.shape != b.depth.shape:
        raise ValueError(f"prior shapes differ: {tuple(a.depth.shape)} vs {tuple(b.depth.shape)}")
    mask = (a.confidence > threshold) & (b.confidence > threshold)
    mask &= torch.isfinite(a.depth) & torch.isfinite(b.depth)
    n = int(mask.sum())
    return spearman(a.depth[mask], b.depth[mask]), n / mask.numel(), n


def scene_agreement(
    a: Sequence[PriorDepth], b: Sequence[PriorDepth], threshold: float = 0.5
) -> dict[str, object]:
    """Per-view and pixel-weighted mean Spearman rho between two prior lists of one scene."""
    rows = [prior_agreement(x, y, threshold) for x, y in zip(a, b, strict=True)]
    valid = [(r, n) for r, _, n in rows if r == r]
    total = sum(n for _, n in valid)
    mean = sum(r * n for r, n in valid) / total if total else float("nan")
    return {
        "rho_per_view": [r for r, _, _ in rows],
        "fraction_per_view": [f for _, f, _ in rows],
        "rho": mean,
    }


def main(argv: Sequence[str] | None = None) -> int:
    """CLI: print the agreement of two priors on one scene as JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene", help="scene folder")
    parser.add_argument("--a", default="plane_sweep", help="first prior setting")
    parser.add_argument("--b", default="pydnet", help="second prior setting")
    parser.add_argument("--views", type=int, default=None, help="training views")
    parser.add_argument("--threshold", type=float, default=0.5, help="confidence threshold")
    parser.add_argument("--cache-dir", default=None, help="prior cache folder")
    args = parser.parse_args(argv)
    from sparsesplat.engine.datasets import load_scene
    from sparsesplat.engine.priors import compute_priors

    scene = load_scene(args.scene, views=args.views)
    a = compute_priors(scene, args.a, cache_dir=args.cache_dir)
    b = compute_priors(scene, args.b, cache_dir=args.cache_dir)
    result = scene_agreement(a, b, args.threshold)
    print(json.dumps({"scene": scene.name, "a": args.a, "b": args.b, **result}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
