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


def _depth_norm_runs(
    d: torch.Tensor, prior: torch.Tensor, patch: int, margin: float, mode: str
) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """(loss, gradient) of depth_norm_loss: native float32, float64 reference, torch float32."""
    import os

    runs = []
    for dtype, impl in ((torch.float32, "native"), (torch.float64, "torch"),
                        (torch.float32, "torch")):  # fmt: skip
        os.environ["SPARSESPLAT_PHOTOMETRIC"] = impl
        try:
            x = d.to(dtype).requires_grad_(True)
            loss = depth_norm_loss(x, DepthTarget(prior.to(dtype)), patch, margin, mode)
            (grad,) = torch.autograd.grad(loss, x)
        finally:
            del os.environ["SPARSESPLAT_PHOTOMETRIC"]
        runs.append((loss.detach(), grad))
    return runs


@pytest.mark.parametrize("mode", ["global", "local"])
@pytest.mark.parametrize(("shape", "patch"), [((378, 504), 5), ((378, 504), 17), ((61, 47), 11),
                                              ((23, 30), 40)])  # fmt: skip
@pytest.mark.parametrize("seed", [0, 1])
def test_native_depth_norm_loss_matches_float64(
    mode: str, shape: tuple[int, int], patch: int, seed: int
) -> None:
    """The native patch-normalized depth loss (engine/photometric/cpu/depth_norm.cpp): value and
    gradient within the float32 rule of the torch definition run in float64, with torch's
    float32 run as the scale; pixels outside the patch grid get no gradient. The margin keeps
    about half of the residuals and none lies within 1e-5 of it, so float32 and float64 keep
    the same ones."""
    from tests.engine.numerics import assert_float32_close

    g = torch.Generator().manual_seed(seed)
    d = torch.rand(*shape, generator=g) * 3 + 1
    prior = torch.rand(*shape, generator=g) * 2 + 1
    # A margin away from every residual (float64), near the median so that both sides count.
    p = max(1, min(patch, *shape))
    # The residuals, recomputed here from the definition in float64.
    tgt = DepthTarget(prior.double())
    pd = patchify(d.double(), p)
    centred = pd - pd.mean(dim=1, keepdim=True)
    every = pd - pd.mean()
    eps = max(0.01 * float(every.square().sum() / (every.numel() - 1)) ** 0.5, 1e-8)
    if mode == "local":
        scale = (centred.square().sum(dim=1, keepdim=True) / (p * p - 1)).sqrt()
    else:
        flat = d.double().reshape(-1)
        scale = torch.tensor(float((flat - flat.mean()).square().sum() / (flat.numel() - 1)) ** 0.5)
    r = (centred / (scale + eps) - tgt.normalized(p, mode)).abs().reshape(-1).sort().values
    gaps = r[1:] - r[:-1]
    middle = len(r) // 2 + int(gaps[len(r) // 2 : len(r) // 2 + 2000].argmax())
    margin = float(r[middle] + r[middle + 1]) / 2
    # float32 puts a residual of size ~1 within ~1e-6 of its float64 value.
    assert float(gaps[middle]) > 2e-5, "no clear gap near the median"
    (got, g_got), (ref, g_ref), (t32, g_t32) = _depth_norm_runs(d, prior, patch, margin, mode)
    assert_float32_close(got.reshape(1), ref.reshape(1), t32.reshape(1), what=f"loss {mode}")
    assert_float32_close(g_got, g_ref, g_t32, g_ref.abs().max(), f"gradient {mode} p={patch}")
    rows, cols = (shape[0] // p) * p, (shape[1] // p) * p
    assert float(g_got[rows:].abs().sum() + g_got[:, cols:].abs().sum()) == 0.0


def test_native_depth_norm_loss_edge_cases() -> None:
    """A constant map: a finite gradient and the reference's loss; a margin above every
    residual: zero loss and gradient; the result does not depend on the thread count."""
    flat = torch.full((30, 40), 2.0)
    prior = torch.rand(30, 40, generator=torch.Generator().manual_seed(3)) + 1
    for mode in ("global", "local"):
        (loss, grad), *_ = _depth_norm_runs(flat, prior, 5, 1e9, mode)
        assert float(loss) == 0.0 and float(grad.abs().sum()) == 0.0
        (loss, grad), (ref, _), _ = _depth_norm_runs(flat, prior, 5, 1e-4, mode)
        assert torch.isfinite(grad).all() and abs(float(loss) - float(ref)) <= 1e-5 * float(ref)
    d = torch.rand(378, 504, generator=torch.Generator().manual_seed(4)) + 1
    results = []
    threads = torch.get_num_threads()
    try:
        for n in (1, 2):
            torch.set_num_threads(n)
            results.append(_depth_norm_runs(d, prior.repeat(13, 13)[:378, :504], 7, 1e-3,
                                            "local")[0])  # fmt: skip
    finally:
        torch.set_num_threads(threads)
    assert torch.equal(results[0][0], results[1][0]) and torch.equal(results[0][1], results[1][1])
