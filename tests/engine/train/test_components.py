"""Unit tests: Gaussians table surgery, hash grid, SH, colour models, losses, config.

Numerical comparisons follow the float32 rule of ``tests/engine/numerics.py``: a float32 result
is measured against a float64 reference, with torch's float32 run of the same computation as the
scale of rounding; two float32 paths are never compared with each other directly.
"""

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
    gaussian_window_ssim,
    global_local_depth_loss,
    margin_mse,
    opacity_regularizer,
    scale_regularizer,
    shape_regularizer,
)
from sparsesplat.engine.train.config import (
    REFERENCE_ITERATIONS,
    ColorConfig,
    ConfigError,
    TrainConfig,
)
from sparsesplat.engine.train.config.overrides import config_from_dict, parse_override
from sparsesplat.engine.train.config.presets import PRESET_ITERATIONS, PRESETS, preset
from sparsesplat.engine.train.loop.schedule import position_lr
from tests.engine.color.colour_reference import field_reference
from tests.engine.numerics import FLOOR_ULPS, UNIT_ROUNDOFF, assert_float32_close


def _brute_force_knn(pts: torch.Tensor) -> torch.Tensor:
    """log sqrt(mean squared distance to the 3 nearest others), all pairs at once."""
    d2 = torch.cdist(pts, pts).square()
    d2.fill_diagonal_(float("inf"))
    return torch.log(torch.sqrt(d2.topk(3, largest=False).values.mean(1)))


def test_knn_scales_match_brute_force(seed: int) -> None:
    """Chunked k-NN scales within the float32 rule of the float64 brute force (the float32
    brute force as the scale: cdist's |a|^2 + |b|^2 - 2ab cancels for near neighbours)."""
    pts = torch.rand(200, 3, generator=torch.Generator().manual_seed(seed))
    got = knn_log_scales(pts, chunk=37)
    want = _brute_force_knn(pts.double())
    assert_float32_close(got[:, 0], want, _brute_force_knn(pts), what=f"seed {seed}")
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


def test_prune_keeps_adam_moments_aligned(seed: int) -> None:
    gs, opt = _table(50, seed)
    means_before = gs.means.detach().clone()
    m_before = opt.state[gs.means]["exp_avg"].clone()
    keep = torch.rand(50, generator=torch.Generator().manual_seed(seed + 1)) > 0.5
    gs.prune(keep, opt)
    assert len(gs) == int(keep.sum()), f"seed {seed}"
    assert torch.equal(gs.means.detach(), means_before[keep])
    assert torch.equal(opt.state[gs.means]["exp_avg"], m_before[keep]), f"seed {seed}"
    assert opt.param_groups[0]["params"][0] is gs.means


def test_densify_clone_and_split(seed: int) -> None:
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


def _naive_grid(grid: HashGrid, x: torch.Tensor, dtype: torch.dtype) -> torch.Tensor:
    """Point-by-point trilinear interpolation for the dense coarse levels only, in ``dtype``.
    The cell is chosen from ``x * scale + 0.5`` in float32 (the decision every float32
    implementation takes), the weights and the sum are in ``dtype``."""
    out = []
    table = grid.embeddings.detach().to(dtype)
    for level in range(grid.n_levels):
        if not grid.dense[level]:
            break
        stride = grid.resolutions[level] + 1
        feats = []
        for p in x:
            base = torch.floor(p * grid.scales[level] + 0.5).to(dtype)
            frac = p.to(dtype) * grid.scales[level] + 0.5 - base
            acc = torch.zeros(grid.n_features, dtype=dtype)
            for c in range(8):
                bits = torch.tensor([(c >> d) & 1 for d in range(3)])
                v = (base + bits).long()
                w = torch.prod(torch.where(bits.bool(), frac, 1 - frac))
                idx = int(v[0] + v[1] * stride + v[2] * stride * stride) % grid.sizes[level]
                acc += w * table[grid.offsets[level] + idx]
            feats.append(acc)
        out.append(torch.stack(feats))
    return torch.cat(out, dim=1)


def test_hash_grid_matches_naive_and_zero_outside(seed: int) -> None:
    """The grid (native) within the float32 rule of a naive float64 evaluation of the dense
    levels (the naive float32 one as the scale); zeros outside the unit cube."""
    g = torch.Generator().manual_seed(seed)
    grid = HashGrid(log2_table_size=14, generator=g)
    with torch.no_grad():
        grid.embeddings.uniform_(-1, 1, generator=g)
    x = torch.rand(7, 3, generator=g)
    want = _naive_grid(grid, x, torch.float64)
    got = grid(x)[:, : want.shape[1]].detach()
    assert want.shape[1] >= 4, "expected some dense levels"
    assert_float32_close(got, want, _naive_grid(grid, x, torch.float32), what=f"seed {seed}")
    outside = grid(torch.tensor([[1.5, 0.5, 0.5], [-0.1, 0.2, 0.2]]))
    assert bool((outside == 0).all())


def test_hash_grid_gradients(seed: int) -> None:
    """Autograd of the torch grid against central differences (float64). The points keep
    1e-3 of a cell from every vertex plane: a difference step across one measures the jump
    of the piecewise-trilinear position gradient, not the derivative."""
    g = torch.Generator().manual_seed(seed)
    grid = HashGrid(n_levels=4, log2_table_size=10, finest_resolution=64).double()
    scales = torch.tensor(grid.scales, dtype=torch.float64)
    rows = []
    while len(rows) < 5:
        p = torch.rand(3, dtype=torch.float64, generator=g)
        pos = p[None, :] * scales[:, None] + 0.5
        if float((pos - pos.round()).abs().min()) > 1e-3:
            rows.append(p)
    x = torch.stack(rows).requires_grad_(True)
    table = grid.embeddings.detach().clone().uniform_(-1, 1, generator=g).requires_grad_(True)

    def fn(points: torch.Tensor, emb: torch.Tensor) -> torch.Tensor:
        return torch.func.functional_call(grid, {"embeddings": emb}, (points,))

    assert torch.autograd.gradcheck(fn, (x, table)), f"seed {seed}"


def test_sh_basis_is_orthonormal(seed: int) -> None:
    """Monte Carlo Gram matrix over 200k float64 directions: its error is ~1/sqrt(200k) times a
    constant of order 1, so 0.03 is over ten standard deviations."""
    d = torch.nn.functional.normalize(
        torch.randn(200_000, 3, generator=torch.Generator().manual_seed(seed), dtype=torch.float64),
        dim=1,
    )
    y = sh_basis(d, 3)
    gram = y.T @ y * (4 * math.pi / d.shape[0])
    assert torch.allclose(gram, torch.eye(16, dtype=gram.dtype), atol=0.03), f"seed {seed}"


def test_neural_cached_colors_match_training_path(
    seed: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The training path, the cached inference path and the export colour function all within
    the float32 rule of the layer-by-layer field in float64 (the torch-grid float32 field as the
    scale; points with a ReLU at float32's error of zero left out). A model rebuilt from the
    state dict computes the same thing the same way: bit for bit."""
    g = torch.Generator().manual_seed(seed)
    means = torch.rand(30, 3, generator=g)
    color = NeuralColor.create(means, g, log2_table_size=12)
    gs = Gaussians.from_points(means)
    cam = torch.tensor([0.3, -2.0, 0.5])
    full = color.colors(gs, cam).detach()
    params = {k: p.detach().double() for k, p in color.field.named_parameters()}
    want, ambiguous = field_reference(color.field, params, gs.means.detach(), cam)
    keep = ~ambiguous
    with monkeypatch.context() as m:
        m.setenv("SPARSESPLAT_HASHGRID", "torch")
        torch32 = color.colors(gs, cam).detach()
    cached = color.colors_cached(color.geo_features(gs), gs.means.detach(), cam)
    fn = color.color_fn(gs)
    for name, got in (("training", full), ("cached", cached),
                      ("color_fn", fn(gs.means.detach() - cam))):  # fmt: skip
        assert_float32_close(got[keep], want[keep], torch32[keep], what=f"{name}, seed {seed}")
    assert float(full.min()) >= -0.001 and float(full.max()) <= 1.001
    rebuilt = make_color_model(color.state_dict())
    assert isinstance(rebuilt, NeuralColor)
    assert torch.equal(rebuilt.colors(gs, cam).detach(), full)


def test_sh_color_allocates_only_what_it_uses() -> None:
    g = torch.Generator().manual_seed(0)
    assert set(SHColor(0).init_per_gaussian(4, g)) == {"sh_dc"}
    rest = SHColor(2).init_per_gaussian(4, g)["sh_rest"]
    assert rest.shape == (4, 8, 3)
    model = SHColor(3)
    for it in range(1, 3001):
        model.step_hook(it, it - 1)
    assert model.active_degree == 3


def test_ssim_identity_and_drop(seed: int) -> None:
    """SSIM of an image with itself is 1 up to float32 rounding of per-pixel ratios of O(1)
    terms (a few dozen roundoffs); a flipped image scores far lower."""
    x = torch.rand(3, 20, 24, generator=torch.Generator().manual_seed(seed))
    one = float(gaussian_window_ssim(x, x))
    assert one == pytest.approx(1.0, abs=FLOOR_ULPS * UNIT_ROUNDOFF), f"seed {seed}"
    assert float(gaussian_window_ssim(x, x.flip(-1))) < 0.5


def _ssim_2d_reference(
    x: torch.Tensor, y: torch.Tensor, dtype: torch.dtype = torch.float64
) -> torch.Tensor:
    """The 3DGS formula with the full 11x11 window in ``dtype`` (the definition, unoptimized)."""
    x, y = x.to(dtype).unsqueeze(0), y.to(dtype).unsqueeze(0)
    c = x.shape[1]
    coords = torch.arange(11, dtype=dtype) - 5
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


def test_separable_ssim_and_cached_target_match_the_2d_definition(seed: int) -> None:
    """Separable SSIM (direct and with cached target statistics) and its gradient within the
    float32 rule of the 2D definition in float64 (the 2D definition in float32 as the scale).
    The SSIM is a mean of per-pixel ratios of O(1) terms: its terms are 1."""
    gen = torch.Generator().manual_seed(seed)
    y = torch.rand(3, 37, 53, generator=gen)
    x = (y + 0.2 * torch.randn(3, 37, 53, generator=gen)).clamp(0, 1).requires_grad_(True)
    xr = x.detach().double().requires_grad_(True)
    want = _ssim_2d_reference(xr, y)
    (want_grad,) = torch.autograd.grad(want, xr)
    x32 = x.detach().clone().requires_grad_(True)
    want32 = _ssim_2d_reference(x32, y, torch.float32)
    (grad32,) = torch.autograd.grad(want32, x32)
    direct, cached = gaussian_window_ssim(x, y), gaussian_window_ssim(x, SSIMTarget(y))
    for name, value in (("direct", direct), ("cached", cached)):
        assert_float32_close(value.detach().reshape(1), want.detach().reshape(1),
                             want32.detach().reshape(1), 1.0, f"{name}, seed {seed}")  # fmt: skip
    (grad,) = torch.autograd.grad(cached, x)
    # Each pixel's gradient sums the 11x11 windows around it; their largest stands for the
    # terms (a pixel's own gradient may cancel to ~0).
    scale = float(want_grad.abs().max())
    assert_float32_close(grad, want_grad, grad32, scale, f"gradient, seed {seed}")


def test_depth_loss_invariant_to_affine_prior(seed: int) -> None:
    """An affine copy of the depth normalises to the same values: the loss, a mean of
    differences of O(1) normalised depths, is 0 up to a few dozen float32 roundoffs."""
    d = torch.rand(1, 30, 40, generator=torch.Generator().manual_seed(seed)) + 1.0
    for mode in ("local", "global"):
        loss = depth_norm_loss(d, 3.0 * d + 7.0, 6, 0.0, mode)
        bound = FLOOR_ULPS * UNIT_ROUNDOFF
        assert float(loss) <= bound, f"seed {seed} mode {mode}: {float(loss)}"
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
        assert config_from_dict(cfg.to_dict()) == cfg, name
    assert preset("dtu").depth.patch_min == 17 and preset("blender").depth.soft is False
    # The matched parts where they measured better (DTU), and nowhere else.
    dtu = preset("dtu")
    assert dtu.init.add_matched and dtu.correspondence.enabled
    assert dtu.matches.method == "xfeat-lighterglue"
    for name in set(PRESETS) - {"dtu"}:
        cfg = preset(name)
        assert not cfg.init.add_matched and not cfg.correspondence.enabled, name
    assert preset("llff", iterations=10).iterations == 10
    with pytest.raises(ConfigError, match="nonsense"):
        preset("llff", nonsense=1)
    with pytest.raises(ConfigError, match="unknown preset"):
        preset("nope")
    with pytest.raises(ConfigError, match="patch"):
        preset("llff", patch_min=9, patch_max=3)
    with pytest.raises(ConfigError, match=r"color\.sh_degree"):
        preset("llff", color_model="sh", sh_degree=4)


def test_presets_train_their_default_length_and_any_length_from_the_reference() -> None:
    assert TrainConfig().iterations == REFERENCE_ITERATIONS
    for name in PRESETS:
        assert preset(name).iterations == PRESET_ITERATIONS[name], name
    reference = preset("llff", iterations=REFERENCE_ITERATIONS)
    assert (reference.densify.until, reference.depth.soft_start) == (6000, 1000)
    longer = preset("dtu", iterations=3000)  # longer than the default 1500, still exact
    assert (longer.densify.until, longer.depth.soft_start) == (3000, 500)
    # with_iterations on a compressed config can only shorten: the reason preset() exists
    assert preset("llff", iterations=1500).with_iterations(3000).densify.until == 1500
    with pytest.raises(ConfigError, match="iterations must be"):
        preset("llff", iterations="many")
    with pytest.raises(ConfigError, match="iterations must be >= 1"):
        preset("llff", iterations=0)


def test_fixed_choice_fields_name_the_field_and_the_choices() -> None:
    """Literal-typed fields accept their values only, from overrides and from construction."""
    assert preset("llff", color_model="sh", raster_backend="cpu").raster.backend == "cpu"
    with pytest.raises(ConfigError, match=r"color\.model must be 'neural' or 'sh', got 'rgb'"):
        preset("llff", **{"color.model": "rgb"})
    with pytest.raises(ConfigError, match=r"raster\.backend must be .*'reference', got 'gpu'"):
        preset("llff", raster_backend="gpu")
    with pytest.raises(ConfigError, match=r"color\.model"):
        TrainConfig(color=ColorConfig(model="rgb")).validate()  # type: ignore[arg-type]


def test_with_iterations_compresses_the_schedule(seed: int) -> None:
    base = preset("dtu")
    n = random.Random(seed).randrange(100, base.iterations)
    short = base.with_iterations(n)
    factor = n / base.iterations
    assert short.iterations == n
    assert short.densify.until == round(base.densify.until * factor)
    assert short.depth.soft_start == round(base.depth.soft_start * factor)
    assert short.optim.lr_means_steps == round(base.optim.lr_means_steps * factor)
    clean = short.densify.clean_iterations
    assert clean[-1] == n and len(clean) <= 7, f"n={n}"
    assert short.densify.interval == base.densify.interval  # statistics need ~100 iterations
    longer = base.with_iterations(9000)
    assert longer.iterations == 9000 and longer.densify.until == base.densify.until
    with pytest.raises(ConfigError, match="iterations"):
        base.with_iterations(0)


@pytest.mark.parametrize(
    ("item", "want"),
    [("lambda_dssim=0.3", ("lambda_dssim", 0.3)), ("dropout=true", ("dropout", True)),
     ("background=white", ("background", "white")), ("init_box=[[0,0,0],[1,1,1]]",
     ("init_box", [[0, 0, 0], [1, 1, 1]])), ("extra={\"a\": 1}", ("extra", {"a": 1}))],
)  # fmt: skip
def test_override_values_are_json_or_plain_strings(item: str, want: tuple) -> None:
    assert parse_override(item) == want


@pytest.mark.parametrize("item", ["lambda_dssim", "=0.3", ""])
def test_override_without_field_and_value_names_the_form(item: str) -> None:
    with pytest.raises(ConfigError, match="FIELD=JSON"):
        parse_override(item)


@pytest.mark.parametrize("degree", [0, 1, 2])
def test_neural_view_degree_keeps_only_the_low_direction_bands(
    degree: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A field limited to ``view_degree`` computes, within the float32 rule, the float64 field
    whose direction bands above that degree are zero (the torch-grid float32 field as the
    scale; points with a ReLU at float32's error of zero left out); degree 0 leaves no view
    dependence at all; the limit survives the state dict, and a state dict written before the
    limit existed loads with every band."""
    g = torch.Generator().manual_seed(degree)
    means = torch.rand(40, 3, generator=g)
    color = NeuralColor.create(means, g, log2_table_size=12, view_degree=degree)
    gs = Gaussians.from_points(means)
    cams = (torch.tensor([0.3, -2.0, 0.5]), torch.tensor([-1.5, 0.7, 2.5]))
    params = {k: p.detach().double() for k, p in color.field.named_parameters()}
    for cam in cams:
        got = color.colors(gs, cam).detach()
        want, ambiguous = field_reference(color.field, params, gs.means.detach(), cam)
        with monkeypatch.context() as m:
            m.setenv("SPARSESPLAT_HASHGRID", "torch")
            torch32 = color.colors(gs, cam).detach()
        keep = ~ambiguous
        assert_float32_close(got[keep], want[keep], torch32[keep], what=f"degree {degree}")
    if degree == 0:
        assert torch.equal(color.colors(gs, cams[0]), color.colors(gs, cams[1]))
    else:
        assert not torch.equal(color.colors(gs, cams[0]), color.colors(gs, cams[1]))
    state = color.state_dict()
    assert state["view_degree"] == degree
    assert make_color_model(state).field.view_degree == degree  # type: ignore[attr-defined]
    old = {k: v for k, v in state.items() if k != "view_degree"}
    assert make_color_model(old).field.view_degree == 3  # type: ignore[attr-defined]
    with pytest.raises(ConfigError, match=r"color\.view_degree"):
        preset("llff", **{"color.view_degree": 4})


def test_neural_view_degree_schedule_grows_like_the_sh_degree() -> None:
    """With ``view_degree_interval`` the field starts without view dependence and gains one
    band every interval up to ``view_degree``, as the SH model's degree does on the same
    schedule; a model rebuilt from its state dict keeps the band and the schedule."""
    g = torch.Generator().manual_seed(0)
    means = torch.rand(20, 3, generator=g)
    color = NeuralColor.create(means, g, log2_table_size=12, view_degree=2, view_interval=500)
    sh = SHColor(2, 500)
    gs = Gaussians.from_points(means)
    cams = (torch.tensor([0.3, -2.0, 0.5]), torch.tensor([-1.5, 0.7, 2.5]))
    assert torch.equal(color.colors(gs, cams[0]), color.colors(gs, cams[1]))
    seen = []
    for it in range(1, 1601):
        color.step_hook(it, it - 1)
        sh.step_hook(it, it - 1)
        assert color.field.view_degree == sh.active_degree, it
        if it in (499, 500, 999, 1000, 1600):
            seen.append(color.field.view_degree)
    assert seen == [0, 1, 1, 2, 2]
    rebuilt = make_color_model(color.state_dict())
    assert isinstance(rebuilt, NeuralColor)
    assert (rebuilt.field.view_degree, rebuilt.view_interval, rebuilt.view_max) == (2, 500, 2)
    assert torch.equal(rebuilt.colors(gs, cams[0]), color.colors(gs, cams[0]))
    cfg = preset("llff", iterations=1500, **{"color.view_degree_interval": 1000})
    assert cfg.color.view_degree_interval == 1000  # an override is the value the run uses
    assert preset("llff").color.view_degree_interval is None  # every band at once, as the reference
    with pytest.raises(ConfigError, match=r"color\.view_degree_interval"):
        preset("llff", **{"color.view_degree_interval": 0})
