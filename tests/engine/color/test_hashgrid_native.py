"""Native C++ hash grid and SH encoding: values, table and position gradients, dispatch.

Numbers follow the float32 rule of ``tests/engine/numerics.py``: the native kernels and torch's
float32 implementation are both measured against a float64 reference (which takes the grid's
cell decisions from the float32 inputs, as both implementations do: ``colour_reference``), and
the native error stays within 4x of torch's pooled error plus a floor of a few dozen roundoffs.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import torch

from sparsesplat.engine.color.build import release_cached_memory
from sparsesplat.engine.color.hashgrid import HashGrid
from tests.engine.color.colour_reference import field_reference, grid_reference
from tests.engine.numerics import assert_float32_close, compare_float32, summed_terms


def _grid(seed: int, **kw: object) -> HashGrid:
    """A grid with a non-trivial table (U(-1, 1)) so gradients and values are O(1)."""
    g = torch.Generator().manual_seed(seed)
    grid = HashGrid(generator=g, **kw)  # type: ignore[arg-type]
    with torch.no_grad():
        grid.embeddings.uniform_(-1, 1, generator=g)
    return grid


def _points(grid: HashGrid, n: int, seed: int) -> torch.Tensor:
    """Random points inside, outside, exactly 0/1 per axis, and on cell boundaries of levels."""
    g = torch.Generator().manual_seed(seed)
    inside = torch.rand(n, 3, generator=g)
    outside = torch.rand(n // 4, 3, generator=g) * 1.4 - 0.2  # partly outside [0, 1]
    ends = torch.randint(0, 2, (n // 8, 3), generator=g).float()  # corners of the cube
    mixed = torch.rand(n // 8, 3, generator=g)
    mixed[torch.rand(n // 8, 3, generator=g) < 0.5] = 1.0
    mixed[torch.rand(n // 8, 3, generator=g) < 0.3] = 0.0
    # Vertex planes: x * scale + 0.5 an integer (as close as float32 gets) for a random level.
    bound = []
    for _ in range(n // 8):
        scale = grid.scales[int(torch.randint(0, grid.n_levels, (1,), generator=g))]
        k = torch.randint(1, max(2, int(scale)), (3,), generator=g).float()
        bound.append((k - 0.5) / scale)
    just_out = torch.tensor([[1.0 + 1e-7, 0.5, 0.5], [0.5, -1e-8, 0.5], [0.5, 0.5, 1.0]])
    return torch.cat([inside, outside, ends, mixed, torch.stack(bound), just_out]).contiguous()


def _run(
    grid: HashGrid, x: torch.Tensor, backend: str, upstream: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Values, table gradient and position gradient of ``backend`` ("native", "torch" in
    float32, or "float64": the reference)."""
    if backend == "float64":
        table = grid.embeddings.detach().double().requires_grad_(True)
        x64 = x.double().requires_grad_(True)
        out = grid_reference(grid, x, x64, table)
        out.backward(upstream.double())
        assert table.grad is not None and x64.grad is not None
        return out.detach(), table.grad, x64.grad
    grid.backend = backend
    grid.embeddings.grad = None
    xr = x.clone().requires_grad_(True)
    out = grid(xr)
    out.backward(upstream)
    assert grid.embeddings.grad is not None and xr.grad is not None
    return out.detach(), grid.embeddings.grad.clone(), xr.grad.clone()


NAMES = ("values", "d table", "d position")


def _terms(
    grid: HashGrid, x: torch.Tensor, upstream: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, None]:
    """Magnitude of the terms of each value (sum over corners of w |row|) and each table
    gradient entry (sum over the points that touch the row of w |upstream|): the trilinear
    weights are >= 0, so both are the reference run on absolute values. The position gradient
    sums a handful of terms per point: its row stands for them (``row_terms``)."""
    table = grid.embeddings.detach().double().abs().requires_grad_(True)
    out = grid_reference(grid, x, x.double(), table)
    out.backward(upstream.double().abs())
    assert table.grad is not None
    return out.detach(), table.grad, None


def _assert_rule(got: tuple[torch.Tensor, ...], grid: HashGrid, x: torch.Tensor,
                 upstream: torch.Tensor, msg: str) -> None:  # fmt: skip
    """Values and both gradients of ``got`` within the float32 rule of the float64 reference,
    with torch's float32 implementation as the scale and ``_terms`` as the terms."""
    ref = _run(grid, x, "float64", upstream)
    t32 = _run(grid, x, "torch", upstream)
    terms = _terms(grid, x, upstream)
    for name, a, b, c, t in zip(NAMES, got, ref, t32, terms, strict=True):
        assert_float32_close(a, b, c, t, what=f"{name}, {msg}")


LAYOUTS = [
    # (n_levels, n_features, log2_table_size, base, finest): coarse levels dense, fine ones hashed
    (8, 2, 12, 4, 256),
    (4, 1, 10, 8, 64),
    (6, 4, 11, 3, 128),
    (3, 8, 9, 5, 40),
]


@pytest.mark.parametrize("layout", LAYOUTS)
def test_native_matches_reference(layout: tuple[int, int, int, int, int], seed: int) -> None:
    """Forward values, table gradient and position gradient within the float32 rule."""
    levels, feats, log2, base, finest = layout
    grid = _grid(
        seed,
        n_levels=levels,
        n_features=feats,
        log2_table_size=log2,
        base_resolution=base,
        finest_resolution=finest,
    )
    assert any(grid.dense) and not all(grid.dense), "layout must mix dense and hashed levels"
    x = _points(grid, 3000, seed + 1)
    gen = torch.Generator().manual_seed(seed)
    upstream = torch.randn(x.shape[0], levels * feats, generator=gen)
    # Unrendered Gaussians: whole rows of exact zeros; and single zero entries.
    upstream[torch.rand(x.shape[0], generator=gen) < 0.3] = 0.0
    upstream[torch.rand(upstream.shape, generator=gen) < 0.1] = 0.0
    got = _run(grid, x, "native", upstream)
    msg = f"seed={seed} layout={layout}"
    _assert_rule(got, grid, x, upstream, msg)
    outside = ~((x >= 0) & (x <= 1)).all(dim=1)
    assert outside.any() and not got[0][outside].any(), f"outside points need zeros, {msg}"
    assert not got[2][outside].any(), f"outside points get no position gradient, {msg}"


def test_native_default_layout_and_thread_independence(seed: int) -> None:
    """The trainer's 16-level layout; the native results do not depend on the thread count
    (bitwise: the kernel partitions work so that each output is summed in one fixed order)."""
    grid = _grid(seed, log2_table_size=16)
    x = _points(grid, 4000, seed + 1)
    upstream = torch.randn(x.shape[0], 32, generator=torch.Generator().manual_seed(seed))
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        two = _run(grid, x, "native", upstream)
        torch.set_num_threads(1)
        one = _run(grid, x, "native", upstream)
    finally:
        torch.set_num_threads(threads)
    for a, b, name in zip(one, two, NAMES, strict=True):
        assert torch.equal(a, b), f"{name} differ between 1 and 2 threads, seed={seed}"
    _assert_rule(two, grid, x, upstream, f"seed={seed}")


@pytest.mark.parametrize(("target", "relative"), [(0, 1e-3), (1, -1e-3), (2, -2.0)])
def test_the_check_catches_one_wrong_entry(target: int, relative: float, seed: int) -> None:
    """One value or gradient entry off by 1e-3 of itself (or a flipped sign) fails the rule."""
    grid = _grid(seed, n_levels=6, log2_table_size=11, base_resolution=4, finest_resolution=128)
    x = _points(grid, 2000, seed + 1)
    gen = torch.Generator().manual_seed(seed)
    upstream = torch.randn(x.shape[0], grid.output_dim, generator=gen)
    got = list(_run(grid, x, "native", upstream))
    ref = _run(grid, x, "float64", upstream)
    t32 = _run(grid, x, "torch", upstream)
    terms = _terms(grid, x, upstream)[target]
    assert compare_float32(got[target], ref[target], t32[target], terms).passed, f"seed={seed}"
    spoiled = got[target].clone()
    spoiled.view(-1)[int(spoiled.abs().argmax())] *= 1 + relative
    assert not compare_float32(spoiled, ref[target], t32[target], terms).passed, f"seed={seed}"


def test_native_gradients_only_where_asked() -> None:
    """No position gradient without requires_grad on x; no table gradient for a frozen table."""
    grid = _grid(0, n_levels=4, log2_table_size=10, finest_resolution=64)
    grid.backend = "native"
    x = torch.rand(100, 3, requires_grad=True)
    grid.embeddings.requires_grad_(False)
    grid(x).sum().backward()
    assert x.grad is not None and x.grad.abs().sum() > 0
    grid.embeddings.requires_grad_(True)
    x2 = torch.rand(100, 3)
    grid(x2).sum().backward()
    assert grid.embeddings.grad is not None and grid.embeddings.grad.abs().sum() > 0
    assert grid(torch.zeros(0, 3)).shape == (0, grid.output_dim)


def test_recycled_gradient_block_starts_from_zero() -> None:
    """The table gradient's memory is recycled once the previous gradient is freed: a backward
    into a recycled block (which still holds the last gradient) gives the same bits as one into
    fresh memory, and a gradient still held elsewhere is never written over."""
    grid = _grid(3, log2_table_size=17)  # 16 MB of table: the huge-page path
    grid.backend = "native"
    x = _points(grid, 4000, 3)
    g = torch.Generator().manual_seed(3)
    up1, up2 = (torch.rand(len(x), grid.output_dim, generator=g) for _ in range(2))

    def table_grad(upstream: torch.Tensor) -> torch.Tensor:
        grid.embeddings.grad = None
        grid(x).backward(upstream)
        grad = grid.embeddings.grad
        assert grad is not None
        return grad

    first = table_grad(up1).clone()
    grid.embeddings.grad = None  # frees the first gradient's block for reuse
    recycled = table_grad(up2)  # into that block
    held = recycled
    fresh = table_grad(up2)  # ``held`` keeps the block busy: fresh memory
    assert fresh.data_ptr() != held.data_ptr()
    assert torch.equal(held, fresh)
    assert not torch.equal(first, fresh)  # the two upstreams differ, so must their gradients
    again = table_grad(up1)  # the held block is still busy; ``fresh``'s was freed and reused
    assert torch.equal(again, first) and torch.equal(held, fresh)

    # Released, the kept block is unmapped once; the next backward maps a fresh one.
    del held, recycled, fresh, again
    grid.embeddings.grad = None
    assert release_cached_memory() >= grid.embeddings.numel() * 4
    assert release_cached_memory() == 0
    assert torch.equal(table_grad(up1), first)


def test_training_run_releases_the_kept_gradient_block(tmp_path: Path) -> None:
    """A finished run leaves no table-gradient block behind for a backward that may not come."""
    from sparsesplat.engine.datasets import load_scene
    from sparsesplat.engine.train import Trainer, preset
    from tests.cli.scenes import write_object_scene

    scene = load_scene(write_object_scene(tmp_path / "scene", count=4, test=1, size=24))
    overrides: dict[str, Any] = {
        "record.export": False, "record.eval_lpips": False, "record.eval_interval_s": 0,
        "depth.prior": "none", "color.model": "neural",
    }  # fmt: skip
    trainer = Trainer(scene, preset("object", iterations=3, **overrides), None)
    assert trainer.color.field.grid.uses_native(torch.zeros(1, 3))  # type: ignore[union-attr]
    trainer.run()
    assert release_cached_memory() == 0


def test_backend_selection(monkeypatch: pytest.MonkeyPatch) -> None:
    """float32 CPU → native by default; env var forces torch; float64 falls back; bad values."""
    grid = _grid(0, n_levels=4, log2_table_size=10, finest_resolution=64)
    x = torch.rand(10, 3)
    assert grid.uses_native(x)
    assert not grid.uses_native(x.double())
    monkeypatch.setenv("SPARSESPLAT_HASHGRID", "torch")
    assert not grid.uses_native(x)
    monkeypatch.setenv("SPARSESPLAT_HASHGRID", "gpu")
    with pytest.raises(ValueError, match="SPARSESPLAT_HASHGRID"):
        grid.uses_native(x)
    monkeypatch.delenv("SPARSESPLAT_HASHGRID")
    grid.backend = "native"
    with pytest.raises(ValueError, match="float32"):
        grid(x.double())
    with pytest.raises(ValueError, match="backend"):
        HashGrid(n_levels=2, log2_table_size=8, backend="cuda")
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        grid(torch.rand(4, 2))


def _field_reference(field, means: torch.Tensor, cam: torch.Tensor) -> torch.Tensor:
    """The colour field layer by layer, torch grid and torch SH (the unfused definition)."""
    from sparsesplat.engine.color.sh import sh_basis

    dirs = torch.nn.functional.normalize(means - cam, dim=-1)
    code = field.grid.forward_torch((means - field.center) / (2 * field.bound) + 0.5)
    geo = field.sigma_mlp(code)[:, 1:]
    h = field.color_mlp(torch.cat([sh_basis(dirs, 3), geo], dim=-1))
    return torch.sigmoid(h) * 1.002 - 0.001


def test_fused_color_field_matches_layer_by_layer(seed: int) -> None:
    """Training path (native grid + SH, merged 64x64 weights) = the unfused field: colours and
    gradients w.r.t. centres and every parameter within the float32 rule of the layer-by-layer
    field in float64, with the layer-by-layer torch float32 field as the scale; the cached
    inference path too. Points with a ReLU within float32's error of zero are left out (a unit
    that float32 switches off where float64 does not changes that point's gradients by a term).
    """
    from sparsesplat.engine.color.models import NeuralColor

    g = torch.Generator().manual_seed(seed)
    pts = torch.randn(2000, 3, generator=g)
    color = NeuralColor.create(pts, g, log2_table_size=14)
    field = color.field
    with torch.no_grad():
        field.grid.embeddings.uniform_(-0.5, 0.5, generator=g)
    cam = torch.randn(3, generator=g) * 5
    upstream = torch.randn(len(pts), 3, generator=g)

    def reference_grads(up: torch.Tensor) -> tuple[torch.Tensor, list[torch.Tensor]]:
        """Colours and the gradients (centres, then every parameter) of the float64 field."""
        params = {k: p.detach().double().requires_grad_(True) for k, p in field.named_parameters()}
        means64 = pts.double().requires_grad_(True)
        colours, _ = field_reference(field, params, pts, cam, means64)
        grads = torch.autograd.grad(colours, [means64, *params.values()], up.double())
        return colours.detach(), list(grads)

    _, ambiguous = field_reference(
        field, {k: p.detach().double() for k, p in field.named_parameters()}, pts, cam
    )
    assert float(ambiguous.double().mean()) < 0.1, f"seed={seed}: too many ReLUs at 0"
    keep = ~ambiguous
    upstream = upstream * keep.unsqueeze(-1)
    want, (want_dm, *want_dp) = reference_grads(upstream)
    # A weight's gradient sums the contributions of every point's 3 colours, which cancel.
    sizes = summed_terms(lambda up: reference_grads(up)[1][1:], upstream,
                         3 * int(keep.sum()), seed)  # fmt: skip
    results = []
    for fn in (lambda m: field(m, cam), lambda m: _field_reference(field, m, cam)):
        field.zero_grad(set_to_none=True)
        means = pts.clone().requires_grad_(True)
        out = fn(means)
        out.backward(upstream)
        grads = [p.grad.clone() for p in field.parameters()]
        results.append((out.detach(), means.grad.clone(), grads))
    (got, got_dm, got_dp), (t32, t32_dm, t32_dp) = results
    msg = f"seed={seed}"
    assert_float32_close(got[keep], want[keep], t32[keep], what=f"colours {msg}")
    assert_float32_close(got_dm, want_dm, t32_dm, what=f"grad of means {msg}")
    names = [name for name, _ in field.named_parameters()]
    for name, a, b, c, size in zip(names, got_dp, want_dp, t32_dp, sizes, strict=True):
        assert_float32_close(a, b, c, b.abs() + size, f"grad of {name} {msg}")
    assert got_dp[-3][0].abs().sum() == 0, "the density row must get no gradient"
    geo = field.geo_features(pts)
    dirs = torch.nn.functional.normalize(pts - cam, dim=-1)
    cached = field.colors_from_features(geo, dirs)
    assert_float32_close(cached[keep], want[keep], t32[keep], what=f"cached {msg}")


def test_native_sh_matches_reference(seed: int) -> None:
    """Fused SH encoding and its direction gradient within the float32 rule of sh_basis in
    float64 (sh_basis in float32 as the scale)."""
    from sparsesplat.engine.color.native import sh16_native
    from sparsesplat.engine.color.sh import sh_basis

    g = torch.Generator().manual_seed(seed)
    dirs = torch.nn.functional.normalize(torch.randn(5000, 3, generator=g), dim=-1)
    dirs[:3] = torch.eye(3)
    upstream = torch.randn(5000, 16, generator=g)
    outs = []
    for fn, dtype in ((sh16_native, torch.float32), (lambda d: sh_basis(d, 3), torch.float32),
                      (lambda d: sh_basis(d, 3), torch.float64)):  # fmt: skip
        d = dirs.to(dtype).clone().requires_grad_(True)
        y = fn(d)
        y.backward(upstream.to(dtype))
        assert d.grad is not None
        outs.append((y.detach(), d.grad))
    (got, got_d), (t32, t32_d), (ref, ref_d) = outs
    assert_float32_close(got, ref, t32, what=f"SH values, seed={seed}")
    assert_float32_close(got_d, ref_d, t32_d, what=f"SH direction gradient, seed={seed}")


def test_position_gradient_with_and_without_forward_jacobian(seed: int) -> None:
    """The kernel's two position-gradient paths (forward Jacobian, re-gather) both follow the
    float32 rule; the forward values and table gradients, computed the same way on both
    paths, are bitwise equal."""
    from sparsesplat.engine.color.build import load_extension

    ext = load_extension()
    grid = _grid(seed, n_levels=6, log2_table_size=11, base_resolution=4, finest_resolution=128)
    x = _points(grid, 2000, seed + 1)
    gen = torch.Generator().manual_seed(seed)
    upstream = torch.randn(x.shape[0], grid.output_dim, generator=gen)
    upstream[torch.rand(x.shape[0], generator=gen) < 0.3] = 0.0
    table = grid.embeddings.detach()
    out, jac = ext.forward(x, table, *grid.layout(), True)
    out2, none = ext.forward(x, table, *grid.layout(), False)
    assert none is None and torch.equal(out, out2), f"seed={seed}"
    gx_jac, gt_jac = ext.backward(x, table, upstream, *grid.layout(), True, True, jac)
    gx_re, gt_re = ext.backward(x, table, upstream, *grid.layout(), True, True, None)
    assert torch.equal(gt_jac, gt_re), f"table gradients differ, seed={seed}"
    ref = _run(grid, x, "float64", upstream)[2]
    t32 = _run(grid, x, "torch", upstream)[2]  # position gradients: rows are their terms
    for name, gx in (("forward Jacobian", gx_jac), ("re-gather", gx_re)):
        assert_float32_close(gx, ref, t32, what=f"d position, {name}, seed={seed}")
