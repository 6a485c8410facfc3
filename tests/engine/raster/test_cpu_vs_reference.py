"""The native CPU kernel against the dense float64 reference: values and gradients."""

from __future__ import annotations

import json
import os
import random
import subprocess
import sys

import pytest
import torch

from sparsesplat.engine.raster import rasterize

from .helpers import assert_matches_reference, camera, random_gaussians


@pytest.mark.parametrize("channels", [3, 1, 0])
def test_random_scenes_match_reference(channels: int) -> None:
    """Fresh seeds each run: rel error < 1e-4 on the outputs and on all five gradients."""
    seed = random.randrange(2**31)
    gs = random_gaussians(120, seed, channels=channels)
    cam = camera(37, 29, fx=45.0, fy=41.0, cx=17.3, cy=15.1)
    bg = torch.rand(channels, generator=torch.Generator().manual_seed(seed))
    assert_matches_reference(gs, cam, seed, f"random scene C={channels}", background=bg)


def test_dense_scene_saturates_like_reference() -> None:
    """Many opaque Gaussians: early termination (T <= 1e-4) decides most pixels."""
    seed = random.randrange(2**31)
    gs = random_gaussians(300, seed, spread=0.4)
    gs.opacity_logits = gs.opacity_logits.abs() + 3.0
    gs.log_scales = gs.log_scales + 0.5
    out, _ = assert_matches_reference(gs, camera(48, 32), seed, "saturated scene")
    assert float(out.alpha.detach().max()) > 0.999, f"scene did not saturate (seed {seed})"


def test_reference_matches_finite_differences() -> None:
    """The oracle itself: autograd of the float64 reference against central differences."""
    seed = random.randrange(2**31)
    gs = random_gaussians(4, seed, channels=2, spread=0.3)
    cam = camera(9, 7, fx=12.0)
    params = [t.double().requires_grad_(True) for t in gs.tensors()]

    def f(*ps: torch.Tensor) -> torch.Tensor:
        out = rasterize(*ps, cam, backend="reference")
        return torch.cat([out.image.flatten(), out.depth.flatten(), out.alpha.flatten()])

    assert torch.autograd.gradcheck(f, params, eps=1e-6, atol=1e-5, rtol=1e-4), f"seed {seed}"


def test_avx2_variant_matches_default() -> None:
    """The AVX2 baseline kernels (forced by env) render what the run-time default renders."""
    code = (
        "import json, torch\n"
        "from sparsesplat.engine.raster import rasterize\n"
        "from sparsesplat.engine.raster.build import load_extension\n"
        "from tests.engine.raster.helpers import camera, random_gaussians\n"
        "gs = random_gaussians(200, 5)\n"
        "ps = [t.requires_grad_() for t in gs.tensors()]\n"
        "out = rasterize(*ps, camera(50, 34))\n"
        "(out.image.sum() + out.depth.sum()).backward()\n"
        "print(json.dumps({'v': load_extension().variant(), 'img': out.image.sum().item(),\n"
        "  'g': [p.grad.abs().sum().item() for p in ps]}))\n"
    )
    results = {}
    for isa in ("avx2", "default"):
        env = dict(os.environ)
        env.pop("SPARSESPLAT_RASTER_ISA", None)
        if isa == "avx2":
            env["SPARSESPLAT_RASTER_ISA"] = "avx2"
        done = subprocess.run(
            [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
        )
        results[isa] = json.loads(done.stdout.strip().splitlines()[-1])
    assert results["avx2"]["v"] == "avx2"
    a, b = results["avx2"], results["default"]
    assert abs(a["img"] - b["img"]) <= 1e-5 * abs(b["img"]), (a, b)
    for ga, gb in zip(a["g"], b["g"], strict=True):
        assert abs(ga - gb) <= 1e-4 * abs(gb) + 1e-9, (a, b)


@pytest.mark.parametrize("channels", [0, 3])
def test_opacity_only_backward_matches_full_backward(channels: int) -> None:
    """The soft-depth pass's case (only opacities require grad) takes the kernel's
    geometry-free backward; its opacity and feature gradients equal the full backward's."""
    seed = random.randrange(2**31)
    gs = random_gaussians(150, seed, channels=channels)
    cam = camera(41, 33)
    gen = torch.Generator().manual_seed(seed)
    weights = [torch.rand(channels, 33, 41, generator=gen), torch.rand(1, 33, 41, generator=gen)]

    def grads(geometry: bool) -> list[torch.Tensor]:
        means = gs.means.clone().requires_grad_(geometry)
        logits = gs.opacity_logits.clone().requires_grad_(True)
        feats = gs.features.clone().requires_grad_(channels > 0)
        out = rasterize(means, gs.log_scales, gs.quats, logits, feats, cam, backend="cpu")
        loss = (out.image * weights[0]).sum() + (out.depth * weights[1]).sum()
        wanted = [logits] + ([feats] if channels else [])
        return list(torch.autograd.grad(loss, wanted))

    for full, opacity_only in zip(grads(True), grads(False), strict=True):
        assert torch.allclose(full, opacity_only, rtol=1e-5, atol=1e-7), f"seed {seed}"
    assert float(grads(False)[0].abs().max()) > 0, f"seed {seed}: no opacity gradient"
