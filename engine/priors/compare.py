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
from sparsesplat.engine.scene import Scene, View

MIN_PIXELS = 50
"""Fewer confident pixels than this gives NaN (no meaningful correlation)."""


def _ranks(x: Tensor) -> Tensor:
    """Ranks 0..n-1, tied values sharing the mean of their ranks (Spearman's definition: a
    constant or a coarsely quantised prior must not get an order from the sort)."""
    values, order = torch.sort(x)
    n = x.numel()
    first = torch.ones(n, dtype=torch.bool, device=x.device)
    first[1:] = values[1:] != values[:-1]
    group = torch.cumsum(first.long(), 0) - 1
    starts = torch.nonzero(first).squeeze(1)
    ends = torch.cat([starts[1:], starts.new_tensor([n])]) - 1
    ranks = torch.empty(n, dtype=torch.float64, device=x.device)
    ranks[order] = ((starts + ends).double() / 2)[group]
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


def warp_error(
    ref: View, other: View, prior: PriorDepth, threshold: float = 0.5
) -> dict[str, float]:
    """Held-out check of a metric prior: warp ``other`` (a view not used for the prior) into
    ``ref`` through the prior's depth and report the mean absolute colour error on confident
    pixels that land inside ``other``, next to the same error for a constant depth (the
    median), which is what a prior with no geometric information would get."""
    import torch.nn.functional as F

    def err(depth: Tensor) -> tuple[float, Tensor]:
        cam, oc = ref.camera, other.camera
        h, w = depth.shape
        v, u = torch.meshgrid(
            torch.arange(h, dtype=torch.float64) + 0.5,
            torch.arange(w, dtype=torch.float64) + 0.5,
            indexing="ij",
        )
        z = depth.double()
        pts = torch.stack([(u - cam.cx) / cam.fx * z, (v - cam.cy) / cam.fy * z, z], -1)
        rel = oc.world_to_camera.double() @ cam.camera_to_world.double()
        q = pts.reshape(-1, 3) @ rel[:3, :3].T + rel[:3, 3]
        qz = q[:, 2].clamp_min(1e-9)
        gx = (oc.fx * q[:, 0] / qz + oc.cx) / oc.width * 2 - 1
        gy = (oc.fy * q[:, 1] / qz + oc.cy) / oc.height * 2 - 1
        grid = torch.stack([gx, gy], -1).float().view(1, h, w, 2)
        img = other.image.permute(2, 0, 1)[None].float()
        warped = F.grid_sample(img, grid, align_corners=False)[0].permute(1, 2, 0)
        used = (
            (prior.confidence > threshold) & (grid[0].abs() <= 1).all(-1) & (q[:, 2] > 0).view(h, w)
        )
        diff = (warped - ref.image.float()).abs().mean(-1)
        return (float(diff[used].mean()) if bool(used.any()) else float("nan")), used

    value, used = err(prior.depth)
    confident = prior.depth[prior.confidence > threshold]
    median = float(confident.median()) if confident.numel() else float(prior.depth.median())
    baseline, _ = err(torch.full_like(prior.depth, median))
    return {
        "error": value,
        "constant_depth_error": baseline,
        "fraction": float(used.float().mean()),
    }


MIN_HELDOUT_ANGLE_DEG = 5.0
"""``--heldout auto`` skips test views within this angle of a training view: a near-duplicate
viewpoint warps well under any depth and says nothing about the prior."""


def closest_pair(scene: Scene) -> tuple[int, int]:
    """(test position, train position) of the held-out view whose viewing direction is
    closest to a training view's, at least :data:`MIN_HELDOUT_ANGLE_DEG` apart."""
    import math

    limit = math.cos(math.radians(MIN_HELDOUT_ANGLE_DEG))
    best, pair = -2.0, (0, 0)
    for i, t in enumerate(scene.test):
        for j, v in enumerate(scene.train):
            dot = float(t.camera.world_to_camera[2, :3] @ v.camera.world_to_camera[2, :3])
            if best < dot < limit:
                best, pair = dot, (i, j)
    return pair


def main(argv: Sequence[str] | None = None) -> int:
    """CLI: print the agreement of two priors on one scene as JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene", help="scene folder")
    parser.add_argument("--a", default="plane_sweep", help="first prior setting")
    parser.add_argument("--b", default="pydnet", help="second prior setting")
    parser.add_argument("--views", type=int, default=None, help="training views")
    parser.add_argument("--threshold", type=float, default=0.5, help="confidence threshold")
    parser.add_argument("--cache-dir", default=None, help="prior cache folder")
    parser.add_argument(
        "--heldout",
        default=None,
        metavar="TEST:TRAIN",
        help="also warp test view TEST (source index) into training view number TRAIN "
        "(0-based position) through prior --a and report the colour error; 'auto' picks the "
        "test/training pair with the closest viewing directions",
    )
    args = parser.parse_args(argv)
    from sparsesplat.engine.datasets import load_scene
    from sparsesplat.engine.priors import compute_priors

    scene = load_scene(args.scene, views=args.views)
    a = compute_priors(scene, args.a, cache_dir=args.cache_dir)
    b = compute_priors(scene, args.b, cache_dir=args.cache_dir)
    result: dict[str, object] = scene_agreement(a, b, args.threshold)
    if args.heldout:
        if args.heldout == "auto":
            test_pos, train_pos = closest_pair(scene)
        else:
            test_id, train_pos = (int(x) for x in args.heldout.split(":"))
            test_pos = scene.test_indices.index(test_id)
        other = scene.test[test_pos]
        result["heldout_pair"] = [scene.test_indices[test_pos], train_pos]
        result["heldout"] = warp_error(scene.train[train_pos], other, a[train_pos], args.threshold)
    print(json.dumps({"scene": scene.name, "a": args.a, "b": args.b, **result}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
