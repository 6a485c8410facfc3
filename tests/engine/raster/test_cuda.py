"""gsplat (CUDA) backend and the GPU training path; skipped without a CUDA GPU.

Same float32 rule as the CPU kernel (``tests/engine/numerics.py``): gsplat's error against the
dense float64 reference stays within 4x of torch float32's own error on the scene. gsplat and
the CPU kernel are not compared with each other: two float32 implementations on two devices
need not round alike. gsplat compiles its kernels on first use (minutes, once per
``$TORCH_EXTENSIONS_DIR``).
"""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

import pytest
import torch

from sparsesplat.engine.errors import RasterError
from sparsesplat.engine.raster import rasterize

from .helpers import camera, compare_with_reference, random_gaussians

pytestmark = pytest.mark.cuda

SCREEN_GRAD_TOLERANCE = 1e-3
"""Relative L2 error of gsplat's screen-space gradient against the float64 reference's (pixels
at a float32 decision are out of the loss; measured errors are far smaller)."""


@pytest.fixture
def gsplat() -> Any:
    """gsplat, or skip."""
    return pytest.importorskip("gsplat")


@pytest.mark.parametrize("channels", [3, 0])
def test_gsplat_matches_reference(gsplat: Any, channels: int, seed: int) -> None:
    """Values and gradients within the float32 rule (same gsplat semantics as the reference)."""
    gs = random_gaussians(400, seed, channels=channels)
    cam = camera(96, 64, fx=80.0, fy=75.0, cx=45.0, cy=33.0)
    res = compare_with_reference(gs, cam, seed, f"gsplat C={channels}", backend="cuda")
    failed = [r.message() for r in res.comparisons if not r.passed]
    assert not failed, failed
    assert (res.out.radii.cpu() > 0).sum() > 0, f"nothing drawn (seed {seed})"


def test_gsplat_background_and_screen_gradient(gsplat: Any, seed: int) -> None:
    """A coloured background is blended once (the depth channel gets none), and ``means2d.grad``
    (what densification accumulates) is populated and matches the reference's."""
    gs = random_gaussians(300, seed)
    cam = camera(64, 48, fx=60.0)
    bg = torch.tensor([0.2, 0.5, 0.9])
    res = compare_with_reference(gs, cam, seed, "gsplat background", background=bg,
                                 backend="cuda")  # fmt: skip
    failed = [r.message() for r in res.comparisons if not r.passed]
    assert not failed, failed
    grad, ref = res.out.means2d.grad, res.ref.means2d.grad
    assert grad is not None, "means2d.grad is None: densification would see no gradient"
    assert ref is not None
    assert grad.shape == (300, 2) and res.out.means2d.is_cuda
    sure = ~res.windows.gaussians
    diff = (grad.detach().cpu().double() - ref)[sure]
    err = float(diff.norm() / ref[sure].norm().clamp_min(1e-30))
    assert err < SCREEN_GRAD_TOLERANCE, f"screen gradient off by {err:.2e} (seed {seed})"


def test_gsplat_empty_and_culled(gsplat: Any, seed: int) -> None:
    """No Gaussians (gsplat itself dies of SIGFPE there), or all behind the camera: the
    background, zero alpha and depth; a backward still works."""
    cam = camera(40, 30).to("cuda")
    bg = torch.tensor([0.1, 0.2, 0.3], device="cuda")
    empty = [torch.zeros(0, k, device="cuda", requires_grad=True) for k in (3, 3, 4)]
    logits = torch.zeros(0, device="cuda", requires_grad=True)
    feats = torch.zeros(0, 3, device="cuda", requires_grad=True)
    out = rasterize(*empty, logits, feats, cam, bg, backend="cuda")
    assert out.radii.shape == (0,) and out.means2d.shape == (0, 2)
    assert torch.equal(out.image, bg.view(3, 1, 1).expand(3, 30, 40))
    assert not out.alpha.any() and not out.depth.any()
    (out.image.sum() + out.depth.sum() + out.alpha.sum()).backward()
    assert empty[0].grad is not None and empty[0].grad.shape == (0, 3)
    gs = random_gaussians(50, seed)
    gs.means[:, 2] = -4.0  # behind the camera
    t = [x.cuda() for x in gs.tensors()]
    out = rasterize(*t, cam, bg, backend="cuda")
    assert not out.radii.any()
    assert torch.equal(out.image, bg.view(3, 1, 1).expand(3, 30, 40))


def test_auto_backend_on_cuda(gsplat: Any, seed: int) -> None:
    """``auto`` renders CUDA tensors with gsplat; gsplat renders float32 only."""
    gs = random_gaussians(200, seed)
    cam = camera(48, 32).to("cuda")
    t = [x.cuda() for x in gs.tensors()]
    a = rasterize(*t, cam, backend="auto")
    b = rasterize(*t, cam, backend="cuda")
    assert a.image.is_cuda and a.stats is None  # the CPU kernel reports pair counts
    assert torch.equal(a.image, b.image) and torch.equal(a.radii, b.radii)
    with pytest.raises(RasterError, match="float32"):
        rasterize(*(x.double() for x in t), cam, backend="cuda")


def test_neural_color_on_cuda(seed: int) -> None:
    """The neural colour field runs on the GPU (plain-torch hash grid) with the CPU's values and
    gradients (float32 rounding apart)."""
    from sparsesplat.engine.color import NeuralColor

    g = torch.Generator().manual_seed(seed)
    pts = torch.rand(3000, 3, generator=g) * 2 - 1
    cpu = NeuralColor.create(pts, g, log2_table_size=14).field
    cpu.grid.backend = "torch"  # the reference implementation, not the native CPU kernels
    gpu = copy.deepcopy(cpu).cuda()
    center = torch.tensor([0.3, -0.2, 3.0])
    m_cpu, m_gpu = pts.clone().requires_grad_(True), pts.cuda().requires_grad_(True)
    a, b = cpu(m_cpu, center), gpu(m_gpu, center.cuda())
    assert b.is_cuda
    torch.testing.assert_close(b.cpu(), a, rtol=1e-4, atol=1e-5)
    w = torch.rand(a.shape, generator=g)
    (a * w).sum().backward()
    (b * w.cuda()).sum().backward()
    pairs = [(m_gpu.grad, m_cpu.grad), (gpu.grid.embeddings.grad, cpu.grid.embeddings.grad)]
    pairs += list(zip((p.grad for p in gpu.parameters()), (p.grad for p in cpu.parameters()),
                      strict=True))  # fmt: skip
    for got, want in pairs:
        assert got is not None and want is not None and got.is_cuda
        err = float((got.cpu() - want).norm() / want.norm().clamp_min(1e-30))
        assert err < 1e-3, f"gradient off by {err:.2e} (seed {seed})"


def test_trainer_on_cuda(gsplat: Any, tmp_path: Path, seed: int) -> None:
    """A smoke-scale DNGaussian run on the GPU: densification sees screen gradients, the model
    stays on the GPU, the held-out PSNR is finite, and export (SH baking) works. The
    pseudo-view pass runs too (its depth network runs on the CPU, its render on the GPU), and
    so does the training cameras' refinement (for cameras estimated from the photos)."""
    from sparsesplat.engine.synthetic import make_scene
    from sparsesplat.engine.train import Trainer, preset

    scene, priors = make_scene(seed=seed)
    cfg = preset(
        "llff", iterations=40, init_points=250, eval_interval_s=0, eval_lpips=False, export=True,
        hash_log2_size=14, lr_means_start=0, lr_means_steps=40, soft_depth_start=15,
        densify_from=10, densify_until=38, densify_interval=10, depth_smooth_start=20,
        checkpoint_interval_s=0,
        **{"pseudo.weight": 1.0, "pseudo.start": 20, "pseudo.every": 5, "poses.enabled": True},
    )  # fmt: skip
    trainer = Trainer(scene, cfg, priors, tmp_path, device="cuda")
    assert trainer.pseudo is not None and trainer.poses is not None
    result = trainer.run()
    g = trainer.gaussians
    assert result.iteration == 40 and g.means.is_cuda
    refined = [c.world_to_camera for c in trainer.poses.refined()]
    given = [c.world_to_camera for c in trainer.cameras]
    assert all(bool(torch.isfinite(m).all()) for m in refined)
    assert any(not torch.equal(a, b) for a, b in zip(refined, given, strict=True))
    assert float(g.grad_count.sum()) > 0 and float(g.grad_accum.sum()) > 0, "no screen gradient"
    psnr = result.metrics["psnr"]
    assert psnr is not None and math.isfinite(psnr)
    assert (tmp_path / "model.ply").is_file()


def test_depth_network_on_a_cuda_image(seed: int) -> None:
    """The monocular network (an ONNX CPU session) takes a GPU image, as the pseudo-view pass
    gives it, and returns its depth on the GPU, equal to the CPU image's depth."""
    from sparsesplat.engine.priors.onnx_depth import describe, predict
    from sparsesplat.engine.weights import resolve_weight

    network = describe("pydnet", {})
    path = resolve_weight(network.filename, None)
    image = torch.rand(60, 80, 3, generator=torch.Generator().manual_seed(seed))
    on_cpu = predict(image, network, path)
    on_gpu = predict(image.cuda(), network, path)
    assert on_gpu.is_cuda and on_gpu.shape == (60, 80)
    assert torch.equal(on_gpu.cpu(), on_cpu)
