"""Unit tests: Gaussians table surgery, hash grid, SH, colour models, losses, config."""

from __future__ import annotations

import math
import random

import pytest
import torch

from sparsesplat.engine.color.hashgrid import HashGrid
from sparsesplat.engine.color.models import NeuralColor, SHColor, make_color_model
from sparsesplat.engine.color.sh import sh_basis
from sparsesplat.engine.gaussians import Gaussians, knn_log_scales
from sparsesplat.engine.losses import (
    SSIMTarget,
    depth_norm_loss,
    edge_aware_smoothness,
    global_local_depth_loss,
    margin_mse,
    opacity_regularizer,
    scale_regularizer,
    shape_regularizer,
    ssim,
)
from sparsesplat.engine.train.config import PRESETS, ConfigError, TrainConfig, preset
from sparsesplat.engine.train.schedule import position_lr


def _seed() -> int:
    return random.randrange(1 << 30)


def test_knn_scales_match_brute_force() -> None:
    seed = _seed()
    pts = torch.rand(200, 3, generator=torch.Generator().manual_seed(seed))
    d2 = torch.cdist(pts, pts).square()
    d2.fill_diagonal_(float("inf"))
    want = torch.log(torch.sqrt(d2.topk(3, largest=False).values.mean(1)))
    got = knn_log_scales(pts, chunk=37)
    assert torch.allclose(got[:, 0], want, atol=1e-5), f"seed {seed}"
    assert torch.equal(got[:, 0], got[:, 2]), "initial scales must be isotropic"


def _table(n: int, seed: int) -> tuple[Gaussians, torch.optim.Adam]:
    g = torch.Generator().manual_seed(seed)
    gs = Gaussians.from_points(torch.rand(n, 3, generator=g), 0.5)
    groups = [{"name": k, "params": [p], "lr": 0.01} for k, p in gs.params.items()]
    opt = torch.optim.Adam(groups)
    loss = sum((p * torch.rand(p.shape, generator=g)).sum() for p in gs.params.values())
    loss.backward()  # type: ignore[union-attr]
    opt.step()
    return gs, opt


def test_prune_keeps_adam_moments_aligned() -> None:
    seed = _seed()
    gs, opt = _table(50, seed)
    means_before = gs.means.detach().clone()
    m_before = opt.state[gs.means]["exp_avg"].clone()
    keep = torch.rand(50, generator=torch.Generator().manual_seed(seed + 1)) > 0.5
    gs.prune(keep, opt)
    assert len(gs) == int(keep.sum()), f"seed {seed}"
    assert torch.equal(gs.means.detach(), means_before[keep])
    assert torch.equal(opt.state[gs.means]["exp_avg"], m_before[keep]), f"seed {seed}"
    assert opt.param_groups[0]["params"][0] is gs.means


def test_densify_clone_and_split() -> None:
    seed = _seed()
    gs, opt = _table(40, seed)
    gs.grad_accum[:10] = 1.0
    gs.grad_count[:10] = 1.0
    with torch.no_grad():
        gs.log_scales[:5] = math.log(10.0)  # big → split
        gs.log_scales[5:] = math.log(1e-3)  # small → clone
    counts = gs.densify_and_prune(
        opt, grad_threshold=0.5, percent_dense=0.01, scene_extent=1.0, min_opacity=0.01,
        split_opacity_threshold=0.1, generator=torch.Generator().manual_seed(seed),
    )  # fmt: skip
    assert counts["cloned"] == 5 and counts["split"] == 5, f"seed {seed}: {counts}"
    # 40 + 5 clones + 2*5 split samples - 5 split originals.
    assert len(gs) == 50, f"seed {seed}"
    assert torch.allclose(gs.scales.max(), torch.tensor(10.0 / 1.6), rtol=1e-4)
    state = opt.state[gs.means]
    assert state["exp_avg"].shape == (50, 3) and bool((state["exp_avg"][35:] == 0).all())


def test_densify_respects_cap_and_opacity_gate() -> None:
    gs, opt = _table(30, 3)
    gs.grad_accum[:] = 1.0
    gs.grad_count[:] = 1.0
    with torch.no_grad():
        gs.log_scales[:] = math.log(1e-3)
        gs.opacity_logits[:10] = -5.0  # opacity 0.007 < gate, and then pruned
    counts = gs.densify_and_prune(
        opt, 0.5, 0.01, 1.0, 0.01, 0.1, torch.Generator().manual_seed(0), max_gaussians=35
    )
    assert counts["cloned"] == 5 and counts["pruned"] == 10
    assert len(gs) == 25


def _naive_grid(grid: HashGrid, x: torch.Tensor) -> torch.Tensor:
    """Point-by-point trilinear interpolation for the dense coarse levels only."""
    out = []
    for level in range(grid.n_levels):
        if not grid.dense[level]:
            break
        stride = grid.resolutions[level] + 1
        feats = []
        for p in x:
            pos = p * grid.scales[level] + 0.5
            base = torch.floor(pos)
            acc = torch.zeros(grid.n_features)
            for c in range(8):
                bits = torch.tensor([(c >> d) & 1 for d in range(3)])
                v = (base + bits).long()
                w = torch.prod(torch.where(bits.bool(), pos - base, 1 - (pos - base)))
                idx = int(v[0] + v[1] * stride + v[2] * stride * stride) % grid.sizes[level]
                acc += w * grid.embeddings[grid.offsets[level] + idx]
            feats.append(acc)
        out.append(torch.stack(feats))
    return torch.cat(out, dim=1)


def test_hash_grid_matches_naive_and_zero_outside() -> None:
    seed = _seed()
    g = torch.Generator().manual_seed(seed)
    grid = HashGrid(log2_table_size=14, generator=g)
    with torch.no_grad():
        grid.embeddings.uniform_(-1, 1, generator=g)
    x = torch.rand(7, 3, generator=g)
    want = _naive_grid(grid, x).detach()
    got = grid(x)[:, : want.shape[1]].detach()
    assert want.shape[1] >= 4, "expected some dense levels"
    assert torch.allclose(got, want, atol=1e-5), f"seed {seed}"
    outside = grid(torch.tensor([[1.5, 0.5, 0.5], [-0.1, 0.2, 0.2]]))
    assert bool((outside == 0).all())


def test_hash_grid_gradients() -> None:
    grid = HashGrid(n_levels=4, log2_table_size=10, finest_resolution=64).double()
    x = torch.rand(5, 3, dtype=torch.float64, requires_grad=True)
    table = grid.embeddings.detach().clone().uniform_(-1, 1).requires_grad_(True)

    def fn(points: torch.Tensor, emb: torch.Tensor) -> torch.Tensor:
        return torch.func.functional_call(grid, {"embeddings": emb}, (points,))

    assert torch.autograd.gradcheck(fn, (x, table))


def test_sh_basis_is_orthonormal() -> None:
    seed = _seed()
    d = torch.nn.functional.normalize(
        torch.randn(200_000, 3, generator=torch.Generator().manual_seed(seed), dtype=torch.float64),
        dim=1,
    )
    y = sh_basis(d, 3)
    gram = y.T @ y * (4 * math.pi / d.shape[0])
    assert torch.allclose(gram, torch.eye(16, dtype=gram.dtype), atol=0.03), f"seed {seed}"


def test_neural_cached_colors_match_training_path() -> None:
    seed = _seed()
    g = torch.Generator().manual_seed(seed)
    means = torch.rand(30, 3, generator=g)
    color = NeuralColor.create(means, g, log2_table_size=12)
    gs = Gaussians.from_points(means)
    cam = torch.tensor([0.3, -2.0, 0.5])
    full = color.colors(gs, cam).detach()
    cached = color.colors_cached(color.geo_features(gs), gs.means.detach(), cam)
    assert torch.allclose(full, cached, atol=1e-6), f"seed {seed}"
    fn = color.color_fn(gs)
    assert torch.allclose(fn(gs.means.detach() - cam), full, atol=1e-6)
    assert float(full.min()) >= -0.001 and float(full.max()) <= 1.001
    rebuilt = make_color_model(color.state_dict())
    assert isinstance(rebuilt, NeuralColor)
    assert torch.allclose(rebuilt.colors(gs, cam).detach(), full)


def test_sh_color_allocates_only_what_it_uses() -> None:
    g = torch.Generator().manual_seed(0)
    assert set(SHColor(0).init_per_gaussian(4, g)) == {"sh_dc"}
    rest = SHColor(2).init_per_gaussian(4, g)["sh_rest"]
    assert rest.shape == (4, 8, 3)
    model = SHColor(3)
    for it in range(1, 3001):
        model.step_hook(it)
    assert model.active_degree == 3


def test_ssim_identity_and_drop() -> None:
    x = torch.rand(3, 20, 24, generator=torch.Generator().manual_seed(1))
    assert float(ssim(x, x)) == pytest.approx(1.0, abs=1e-5)
    assert float(ssim(x, x.flip(-1))) < 0.5


def _ssim_2d_reference(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """The 3DGS formula with the full 11x11 window in float64 (the definition, unoptimized)."""
    x, y = x.double().unsqueeze(0), y.double().unsqueeze(0)
    c = x.shape[1]
    coords = torch.arange(11, dtype=torch.float64) - 5
    g = torch.exp(-(coords**2) / (2 * 1.5**2))
    g = g / g.sum()
    w = (g[:, None] * g[None, :]).expand(c, 1, 11, 11)

    def blur(t: torch.Tensor) -> torch.Tensor:
        return torch.nn.functional.conv2d(t, w, padding=5, groups=c)

    mx, my = blur(x), blur(y)
    sxx, syy, sxy = blur(x * x) - mx**2, blur(y * y) - my**2, blur(x * y) - mx * my
    num = (2 * mx * my + 1e-4) * (2 * sxy + 9e-4)
    den = (mx**2 + my**2 + 1e-4) * (sxx + syy + 9e-4)
    return (num / den).mean()


def test_separable_ssim_and_cached_target_match_the_2d_definition() -> None:
    seed = _seed()
    gen = torch.Generator().manual_seed(seed)
    y = torch.rand(3, 37, 53, generator=gen)
    x = (y + 0.2 * torch.randn(3, 37, 53, generator=gen)).clamp(0, 1).requires_grad_(True)
    want = _ssim_2d_reference(x.detach(), y)
    direct, cached = ssim(x, y), ssim(x, SSIMTarget(y))
    assert float(direct) == pytest.approx(float(want), abs=1e-5), f"seed {seed}"
    assert float(cached) == pytest.approx(float(want), abs=1e-5), f"seed {seed}"
    (grad,) = torch.autograd.grad(cached, x)
    xr = x.detach().double().requires_grad_(True)
    (want_grad,) = torch.autograd.grad(_ssim_2d_reference(xr, y), xr)
    assert torch.allclose(grad.double(), want_grad, atol=1e-7, rtol=1e-3), f"seed {seed}"


def test_depth_loss_invariant_to_affine_prior() -> None:
    seed = _seed()
    d = torch.rand(1, 30, 40, generator=torch.Generator().manual_seed(seed)) + 1.0
    for mode in ("local", "global"):
        loss = depth_norm_loss(d, 3.0 * d + 7.0, 6, 0.0, mode)
        assert float(loss) < 1e-6, f"seed {seed} mode {mode}: {float(loss)}"
        worse = depth_norm_loss(d, -d, 6, 0.0, mode)
        assert float(worse) > 0.1, f"seed {seed} mode {mode}"


@pytest.mark.parametrize("where", ["patch", "image"])
def test_depth_loss_constant_prior_is_finite(where: str) -> None:
    d = torch.rand(1, 24, 24, requires_grad=True)
    prior = torch.full((24, 24), 3.0)
    if where == "patch":
        prior[12:, :] = torch.rand(12, 24)
    g = torch.Generator().manual_seed(0)
    loss = global_local_depth_loss(d, prior, (5, 17), 0.00025, g)
    loss.backward()
    assert bool(torch.isfinite(loss)) and bool(torch.isfinite(d.grad).all())  # type: ignore[arg-type]
    # A constant rendered depth too (zero variance on both sides).
    flat = torch.full((1, 24, 24), 2.0, requires_grad=True)
    loss = global_local_depth_loss(flat, torch.full((24, 24), 1.0), (5, 17), 0.0, g)
    loss.backward()
    assert float(loss.detach()) == 0.0 and bool(torch.isfinite(flat.grad).all())  # type: ignore[arg-type]


def test_margin_mse_empty_selection_and_patch_bigger_than_image() -> None:
    r = torch.full((10,), 1e-5, requires_grad=True)
    loss = margin_mse(r, 0.1)
    loss.backward()
    assert float(loss) == 0.0 and r.grad is not None
    assert float(margin_mse(torch.tensor([0.0, 2.0]), 0.1)) == pytest.approx(4.0)
    d = torch.rand(1, 4, 6)
    assert bool(torch.isfinite(depth_norm_loss(d, d * 2, 50, 0.0)))


def test_regularizers() -> None:
    s = torch.tensor([[1.0, 2.0, 4.0], [1.0, 1.0, 1.0]])
    assert float(shape_regularizer(s)) == pytest.approx(2.5)
    assert float(scale_regularizer(s)) == pytest.approx(8.5)
    assert float(opacity_regularizer(torch.tensor([0.5, 0.1]))) == pytest.approx(1 - 0.25 + 0.81)
    assert float(opacity_regularizer(torch.tensor([0.9]))) == pytest.approx(1 - 0.81)
    assert float(shape_regularizer(torch.zeros(0, 3))) == 0.0
    flat = torch.ones(1, 8, 8)
    assert float(edge_aware_smoothness(flat, torch.rand(8, 8))) == 0.0


def test_position_lr_schedule() -> None:
    assert position_lr(100, 0.016, 0.00016, 500, 5500, 2.0) == pytest.approx(0.032)
    assert position_lr(6000, 0.016, 0.00016, 500, 5500, 2.0) == pytest.approx(0.00032)
    mid = position_lr(3250, 0.016, 0.00016, 500, 5500, 1.0)
    assert mid == pytest.approx(0.0016, rel=1e-6)


def test_presets_and_config_errors() -> None:
    for name in PRESETS:
        cfg = preset(name)
        assert TrainConfig.from_dict(cfg.to_dict()) == cfg, name
    assert preset("dtu").patch_min == 17 and preset("blender").soft_depth is False
    assert preset("llff", iterations=10).iterations == 10
    with pytest.raises(ConfigError, match="nonsense"):
        preset("llff", nonsense=1)
    with pytest.raises(ConfigError, match="unknown preset"):
        preset("nope")
    with pytest.raises(ConfigError, match="patch"):
        preset("llff", patch_min=9, patch_max=3)
    with pytest.raises(ConfigError, match="sh_degree"):
        preset("llff", color_model="sh", sh_degree=4)


def test_with_iterations_compresses_the_schedule() -> None:
    base = preset("dtu")
    n = random.randrange(100, base.iterations)
    short = base.with_iterations(n)
    factor = n / base.iterations
    assert short.iterations == n
    assert short.densify_until == round(base.densify_until * factor)
    assert short.soft_depth_start == round(base.soft_depth_start * factor)
    assert short.lr_means_steps == round(base.lr_means_steps * factor)
    assert short.clean_iterations[-1] == n and len(short.clean_iterations) <= 7, f"n={n}"
    assert short.densify_interval == base.densify_interval  # statistics need ~100 iterations
    longer = base.with_iterations(9000)
    assert longer.iterations == 9000 and longer.densify_until == base.densify_until
    with pytest.raises(ConfigError, match="iterations"):
        base.with_iterations(0)
