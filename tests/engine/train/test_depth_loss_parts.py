"""The depth losses' fast parts against their plain definitions (float64)."""

from __future__ import annotations

import pytest
import torch
from torch.nn import functional as F

from sparsesplat.engine.losses import (
    DepthTarget,
    _smooth_weights,
    depth_norm_loss,
    edge_aware_smoothness,
    global_local_depth_loss,
    patchify,
)


@pytest.mark.parametrize("shape", [(37, 50), (17, 17), (5, 40)])
@pytest.mark.parametrize("patch", [1, 5, 16])
def test_patchify_is_unfold_with_stride_equal_to_kernel(shape: tuple[int, int], patch: int) -> None:
    d = torch.rand(*shape, generator=torch.Generator().manual_seed(patch), dtype=torch.float64)
    if patch > min(shape):
        pytest.skip("a patch larger than the map is clamped by depth_norm_loss, not patchify")
    want = F.unfold(d.reshape(1, 1, *shape), kernel_size=patch, stride=patch).squeeze(0).T
    assert torch.equal(patchify(d, patch), want)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_smoothness_gradient_is_the_plain_definitions(seed: int) -> None:
    """Value and gradient equal autograd's diff/abs chain in float64 (to roundoff) and pass
    gradcheck."""
    g = torch.Generator().manual_seed(seed)
    d = torch.rand(23, 31, generator=g, dtype=torch.float64).requires_grad_(True)
    guide = torch.rand(23, 31, generator=g, dtype=torch.float64) * 257
    weights = _smooth_weights(guide)
    fast = edge_aware_smoothness(d, None, weights)
    (g_fast,) = torch.autograd.grad(fast, d)
    pairs = zip((0, 1), weights, strict=True)
    plain = sum((torch.diff(d, dim=k).abs() * w).sum() for k, w in pairs)
    (g_plain,) = torch.autograd.grad(plain, d)
    assert abs(float(fast - plain)) <= 1e-12 * float(plain)
    assert float((g_fast - g_plain).abs().max()) <= 1e-15
    assert torch.autograd.gradcheck(lambda x: edge_aware_smoothness(x, None, weights), (d,))
    assert torch.allclose(edge_aware_smoothness(d, guide), fast, rtol=1e-14, atol=0)


@pytest.mark.parametrize("seed", [0, 1])
def test_cached_target_gives_the_same_loss_and_gradient(seed: int) -> None:
    """A DepthTarget (prior patches cached per size and mode) changes nothing: the same loss
    and gradient as normalizing the prior on every call, for every patch size drawn."""
    g = torch.Generator().manual_seed(seed)
    prior = torch.rand(40, 52, generator=g, dtype=torch.float64) + 1
    target = DepthTarget(prior)
    for _ in range(2):  # the second round reads the cache
        d = (torch.rand(40, 52, generator=g, dtype=torch.float64) + 1).requires_grad_(True)
        for mode in ("global", "local"):
            for patch in (5, 11, 17):
                a = depth_norm_loss(d, target, patch, 1e-4, mode)
                b = depth_norm_loss(d, prior, patch, 1e-4, mode)
                ga, gb = torch.autograd.grad(a, d)[0], torch.autograd.grad(b, d)[0]
                assert float(a) == float(b) and torch.equal(ga, gb)
    gen_a, gen_b = torch.Generator().manual_seed(3), torch.Generator().manual_seed(3)
    d = torch.rand(40, 52, generator=g, dtype=torch.float64)
    a = global_local_depth_loss(d, target, (5, 17), 1e-4, gen_a)
    assert float(a) == float(global_local_depth_loss(d, prior, (5, 17), 1e-4, gen_b))


def test_constant_patches_give_a_finite_gradient() -> None:
    """A rendered depth that is constant (empty space renders 0) has zero std per patch:
    the loss and its gradient stay finite (Tensor.std's backward would give 0/0)."""
    d = torch.zeros(30, 30, dtype=torch.float64, requires_grad=True)
    prior = torch.rand(30, 30, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    for mode in ("local", "global"):
        loss = depth_norm_loss(d, prior, 6, 0.0, mode)
        (grad,) = torch.autograd.grad(loss, d)
        assert bool(torch.isfinite(loss)) and bool(torch.isfinite(grad).all())
