"""SH evaluation and baking: basis constants, exact recovery, neural-like fields, baking error."""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable

import pytest
import torch
from torch import Tensor

import sparsesplat.engine.raster as raster_pkg
from sparsesplat.engine.camera import Camera
from sparsesplat.engine.export import (
    ExportError,
    bake_sh,
    eval_sh,
    fibonacci_sphere,
    sh_baking_error,
    sh_basis,
    view_directions,
)
from sparsesplat.engine.raster.types import RasterOutput


def _sh_field(n: int, degree: int, seed: int) -> Tensor:
    """Random SH coefficients whose colour stays >= 0 everywhere (so no clamp is active)."""
    g = torch.Generator().manual_seed(seed)
    sh = torch.randn(n, (degree + 1) ** 2, 3, generator=g) * 0.05
    sh[:, 0] = torch.rand(n, 3, generator=g) / 0.28209479177387814  # rgb 0.5..1.5 at DC
    return sh


def _neural_like(n: int, seed: int) -> tuple[Tensor, Tensor, Tensor]:
    """Parameters of a non-SH, sharply view-dependent field (sigmoid of a high-frequency code)."""
    g = torch.Generator().manual_seed(seed)
    axis = torch.nn.functional.normalize(torch.randn(n, 3, 3, generator=g), dim=-1)
    freq = 2.0 + 6.0 * torch.rand(n, 3, generator=g)
    bias = torch.randn(n, 3, generator=g)
    return axis, freq, bias


def _neural_fn(params: tuple[Tensor, Tensor, Tensor]) -> Callable[[Tensor], Tensor]:
    axis, freq, bias = params

    def color(dirs: Tensor) -> Tensor:
        phase = (axis * dirs[:, None, :]).sum(-1) * freq
        return torch.sigmoid(3.0 * torch.sin(phase) + bias)

    return color


def test_basis_is_orthonormal() -> None:
    """Catches a wrong constant or sign: the 16 functions are orthonormal on the sphere."""
    dirs = fibonacci_sphere(20000)
    y = sh_basis(dirs, 3)
    gram = y.T @ y * (4.0 * math.pi / dirs.shape[0])
    torch.testing.assert_close(gram, torch.eye(16, dtype=gram.dtype), atol=2e-3, rtol=0)


def test_eval_sh_known_values() -> None:
    """Values that follow from the 3DGS convention: l=1 is (-C1 y, C1 z, -C1 x)."""
    sh = torch.zeros(3, 4, 3)
    sh[:, 1, 0] = 1.0  # coefficient of -C1*y on red
    sh[:, 2, 1] = 1.0  # coefficient of C1*z on green
    sh[:, 3, 2] = 1.0  # coefficient of -C1*x on blue
    dirs = torch.tensor([[0.0, -2.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])  # normalised inside
    rgb = eval_sh(sh, dirs)
    c1 = 0.4886025119029199
    expected = torch.tensor([[0.5 + c1, 0.5, 0.5], [0.5, 0.5 + c1, 0.5], [0.5, 0.5, 0.5 - c1]])
    torch.testing.assert_close(rgb, expected)
    assert eval_sh(torch.full((1, 1, 3), -10.0), dirs[:1]).min() == 0.0  # clamped at 0


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_bake_recovers_an_sh_field_exactly(degree: int, seed: int) -> None:
    sh = _sh_field(300, degree, seed)
    g = torch.Generator().manual_seed(seed)
    got = bake_sh(lambda d: eval_sh(sh, d), 300, degree=degree, n_dirs=32, generator=g)
    assert got.shape == sh.shape
    err = (got - sh).abs().max()
    assert err < 1e-5, f"seed {seed}, degree {degree}: max coefficient error {err}"
    # with per-Gaussian training directions added to the equations, still exact
    views = torch.nn.functional.normalize(torch.randn(300, 3, 3, generator=g), dim=-1)
    got = bake_sh(lambda d: eval_sh(sh, d), 300, degree=degree, generator=g, view_dirs=views)
    err = (got - sh).abs().max()
    assert err < 1e-5, f"seed {seed}, degree {degree}, view_dirs: max coefficient error {err}"


def test_bake_of_non_sh_field_improves_with_degree(seed: int) -> None:
    """Least squares over one fixed direction set: the residual cannot grow with the degree."""
    field = _neural_fn(_neural_like(200, seed))
    dirs = fibonacci_sphere(64, torch.Generator().manual_seed(seed))
    residual = []
    for degree in range(4):
        sh = bake_sh(field, 200, degree, 64, torch.Generator().manual_seed(seed))
        assert torch.isfinite(sh).all(), f"seed {seed}"
        errs = [
            (eval_sh(sh, d.float().expand(200, 3)) - field(d.float().expand(200, 3))).pow(2).mean()
            for d in dirs
        ]
        residual.append(float(torch.stack(errs).mean()))
    assert all(b <= a + 1e-6 for a, b in itertools.pairwise(residual)), (
        f"seed {seed}: residual by degree {residual}"
    )
    assert residual[3] < residual[0], f"seed {seed}: {residual}"


def test_bake_rejects_bad_arguments() -> None:
    with pytest.raises(ExportError, match="n_dirs"):
        bake_sh(lambda d: d, 5, degree=3, n_dirs=10)
    with pytest.raises(ExportError, match="degree"):
        bake_sh(lambda d: d, 5, degree=4)
    with pytest.raises(ExportError, match="color_fn returned"):
        bake_sh(lambda d: d[:, :2], 5, degree=1)
    with pytest.raises(ExportError, match="view_dirs"):
        bake_sh(lambda d: d, 5, degree=1, view_dirs=torch.zeros(4, 2, 3))


def _look_at(eye: Tensor, size: int = 24) -> Camera:
    """OpenCV camera at ``eye`` looking at the origin."""
    fwd = torch.nn.functional.normalize(-eye, dim=0)
    right = torch.nn.functional.normalize(
        torch.linalg.cross(fwd, torch.tensor([0.0, 0.0, 1.0])), dim=0
    )
    down = torch.linalg.cross(fwd, right)
    r = torch.stack([right, down, fwd])
    w2c = torch.eye(4)
    w2c[:3, :3], w2c[:3, 3] = r, -r @ eye
    return Camera(w2c, 30.0, 30.0, size / 2, size / 2, size, size)


def _point_raster(*args: Tensor | Camera, background: Tensor | None = None) -> RasterOutput:
    """A stand-in renderer: each Gaussian paints the pixel its centre projects to.

    Called as ``rasterize`` is, positionally (means, log_scales, quats, opacity_logits,
    features, camera); only the centres, the features and the camera matter here.
    """
    means, features, camera = args[0], args[4], args[5]
    assert isinstance(means, Tensor) and isinstance(features, Tensor)
    assert isinstance(camera, Camera)
    cam = camera.world_to_camera[:3, :3] @ means.T + camera.world_to_camera[:3, 3:]
    u = (camera.fx * cam[0] / cam[2] + camera.cx).long().clamp(0, camera.width - 1)
    v = (camera.fy * cam[1] / cam[2] + camera.cy).long().clamp(0, camera.height - 1)
    image = torch.zeros(features.shape[1], camera.height, camera.width)
    image[:, v, u] = features.T
    n = means.shape[0]
    return RasterOutput(image, image[:1] * 0, image[:1] * 0, torch.ones(n), torch.zeros(n, 2))


def _scene(seed: int) -> tuple[dict[str, Tensor], list[Camera]]:
    g = torch.Generator().manual_seed(seed)
    n = 150
    gauss = {
        "means": torch.rand(n, 3, generator=g) - 0.5,
        "log_scales": torch.full((n, 3), math.log(0.05)),
        "quats": torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(n, 1),
        "opacity_logits": torch.full((n,), 2.0),
    }
    eyes = [torch.tensor([3.0, 0.3 * i, 1.0]) for i in range(-1, 2)]
    return gauss, [_look_at(e) for e in eyes]


def _baking_error_checks(seed: int) -> None:
    gauss, cams = _scene(seed)
    n = gauss["means"].shape[0]
    field = _neural_fn(_neural_like(n, seed))

    def neural_for(cam: Camera) -> Tensor:
        return field(torch.nn.functional.normalize(gauss["means"] - cam.center, dim=-1))

    g = torch.Generator().manual_seed(seed)
    uniform = bake_sh(field, n, 3, 64, g)
    views = view_directions(gauss["means"], torch.stack([c.center for c in cams]))
    focused = bake_sh(field, n, 3, 64, g, view_dirs=views, view_weight=4.0)
    err_uniform = sh_baking_error(**gauss, sh=uniform, neural_color_fn=neural_for, cameras=cams)
    err_focused = sh_baking_error(**gauss, sh=focused, neural_color_fn=neural_for, cameras=cams)
    assert math.isfinite(err_uniform) and err_uniform > 5.0, f"seed {seed}: {err_uniform}"
    assert err_focused > err_uniform, f"seed {seed}: focused {err_focused} uniform {err_uniform}"
    sh_field = _sh_field(n, 2, seed)

    def exact_for(cam: Camera) -> Tensor:
        return eval_sh(sh_field, gauss["means"] - cam.center)

    exact = sh_baking_error(**gauss, sh=sh_field, neural_color_fn=exact_for, cameras=cams)
    assert exact > 60.0, f"seed {seed}: identical colours gave {exact} dB"


def test_baking_error_with_stand_in_renderer(monkeypatch: pytest.MonkeyPatch, seed: int) -> None:
    monkeypatch.setattr(raster_pkg, "rasterize", _point_raster, raising=False)
    _baking_error_checks(seed)


def test_baking_error_with_real_renderer(seed: int) -> None:
    if not hasattr(raster_pkg, "rasterize"):
        pytest.skip("engine.raster.rasterize not available yet")
    _baking_error_checks(seed)


def test_baking_error_needs_cameras() -> None:
    gauss, _ = _scene(0)
    with pytest.raises(ExportError, match="no cameras"):
        sh_baking_error(**gauss, sh=torch.zeros(150, 1, 3), neural_color_fn=None, cameras=[])  # type: ignore[arg-type]
