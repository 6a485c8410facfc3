"""The trained-model package on its own: a renderer loads none of the training package, a stored
config's raster settings are read in either stored form, and the render outputs' one writer and
empty-render rule."""

from __future__ import annotations

import io
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from PIL import Image

from sparsesplat.api.renders import EMPTY_RENDER_COVERAGE, empty_renders
from sparsesplat.engine.color.models import SHColor
from sparsesplat.engine.model import CHECKPOINT_NAME, save_checkpoint
from sparsesplat.engine.model import encode as encode_module
from sparsesplat.engine.model.encode import encode, encode_image, encode_png
from sparsesplat.engine.model.raster import RasterConfig, stored_raster_config
from sparsesplat.engine.train.config import TrainConfig
from sparsesplat.engine.train.config.overrides import FLAT_NAMES
from tests.web.synthetic import synthetic_gaussians

REPO = Path(__file__).resolve().parents[3]


def _sh_model_state(n: int = 200) -> dict[str, Any]:
    """A finished SH-colour model of ``n`` Gaussians around the origin, built without training."""
    g = synthetic_gaussians(n, seed=0)
    gaussians = {k: g[k] for k in ("means", "log_scales", "quats", "opacity_logits")}
    gaussians["sh_dc"], gaussians["sh_rest"] = g["sh"][:, :1], g["sh"][:, 1:]
    return {
        "version": 1,
        "config": TrainConfig().to_dict(),
        "iteration": 1,
        "background": torch.zeros(3),
        "raster_near": 0.01,
        "gaussians": gaussians,
        "color": SHColor(3, active_degree=3).state_dict(),
    }


_RENDER_WITHOUT_TRAINING = """
import sys
import torch
import sparsesplat.worker.render_server
from sparsesplat.engine.camera import Camera
from sparsesplat.engine.model import load_model
from sparsesplat.engine.model.encode import encode

model = load_model(sys.argv[1])
pose = torch.eye(4)
pose[2, 3] = 3.0  # the camera 3 units behind the origin, looking at it
out = model.render(Camera(pose, 40.0, 40.0, 16.0, 16.0, 32, 32), mode="baked")
image = out.image.permute(1, 2, 0).numpy()
encode("png", image, out.depth[0].numpy(), out.alpha[0].numpy(), 90)
assert float(out.alpha.mean()) > 0.05, float(out.alpha.mean())
print(sorted(m for m in sys.modules if m.startswith("sparsesplat.engine.train")))
"""


def test_the_render_worker_renders_without_the_training_package(tmp_path: Path) -> None:
    """Issue 54: the render worker imports the model package, not the trainer (directly or
    through anything it imports), also when it loads, renders and encodes a model."""
    save_checkpoint(_sh_model_state(), tmp_path / CHECKPOINT_NAME)
    result = subprocess.run(
        [sys.executable, "-c", _RENDER_WITHOUT_TRAINING, str(tmp_path)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert result.stdout.strip() == "[]"


def test_stored_raster_settings_are_read_from_either_stored_form() -> None:
    nested = TrainConfig().to_dict()
    nested["raster"].update(backend="reference", eps2d=0.5)
    assert stored_raster_config(nested) == RasterConfig("reference", None, 0.5)
    flat = {"eps2d": 0.1, "raster_backend": "cpu", "raster_near": 0.2, "lambda_dssim": 0.2}
    assert stored_raster_config(flat) == RasterConfig("cpu", 0.2, 0.1)
    assert stored_raster_config({}) == RasterConfig()
    # The config reader takes the same old names for the same fields.
    assert {FLAT_NAMES[k] for k in ("eps2d", "raster_backend", "raster_near")} == {
        "raster.eps2d",
        "raster.backend",
        "raster.near",
    }


def test_one_empty_render_rule_for_the_service_and_the_command() -> None:
    seen, empty = 2 * EMPTY_RENDER_COVERAGE, EMPTY_RENDER_COVERAGE / 2
    assert empty_renders([seen]) == []
    assert empty_renders([empty]) == [0]
    assert empty_renders([seen, empty, EMPTY_RENDER_COVERAGE, empty]) == [1, 3]


def test_one_image_writer_with_each_callers_settings() -> None:
    rng = np.random.default_rng(0)
    image = rng.uniform(-0.1, 1.1, (9, 7, 3)).astype(np.float32)
    rgb = (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    # No options: Pillow's defaults (the local command's files, as it wrote them before).
    buffer = io.BytesIO()
    Image.fromarray(rgb).save(buffer, format="PNG")
    assert encode_image(image, "png") == buffer.getvalue()
    # The service's PNG: its own writer (encode_png), the same pixels.
    served = encode("png", image, np.zeros((9, 7)), np.ones((9, 7)), 90)
    assert served == encode_png(rgb)
    assert np.array_equal(np.asarray(Image.open(io.BytesIO(served))), rgb)
    # A render's image is a (3, H, W) tensor seen as (H, W, 3): the same bytes from that view.
    planes = np.ascontiguousarray(image.transpose(2, 0, 1))
    assert encode("png", planes.transpose(1, 2, 0), np.zeros((9, 7)), np.ones((9, 7)), 90) == served


@pytest.mark.parametrize("split", [False, True])
@pytest.mark.parametrize(
    "shape", [(1, 1), (1, 5, 3), (6, 1, 3), (37, 29), (64, 48, 3), (378, 504, 3)]
)
def test_the_service_png_writer_is_lossless(
    shape: tuple[int, ...], split: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """encode_png's files decode (Pillow, with its CRC checks) to exactly the pixels given, grey
    and RGB, at any size including one row or one column, deflated in one pass or (the large
    images' way) in two halves joined, here also for the smallest images."""
    monkeypatch.setattr(encode_module, "PNG_SPLIT_BYTES", 1 if split else 2**40)
    pixels = np.random.default_rng(1).integers(0, 256, shape, dtype=np.uint8)
    pixels[: shape[0] // 2] //= 32  # a smoother half: runs for the deflate to find
    image = Image.open(io.BytesIO(encode_png(pixels)))
    image.load()
    assert image.mode == ("RGB" if len(shape) == 3 else "L")
    assert image.size == (shape[1], shape[0])
    assert np.array_equal(np.asarray(image), pixels)


def test_the_service_png_writer_compresses_a_mostly_empty_frame() -> None:
    """A render that sees little (a flat background around a small patch) comes out far
    smaller than its raw pixels: the filtered zero rows deflate to runs."""
    flat = np.zeros((378, 504, 3), dtype=np.uint8)
    flat[100:200, 100:300] = np.random.default_rng(2).integers(0, 256, (100, 200, 3))
    assert len(encode_png(flat)) < 100 * 200 * 3 + 571_536 // 50


def test_the_service_png_writer_refuses_what_it_cannot_write() -> None:
    with pytest.raises(ValueError, match="uint8"):
        encode_png(np.zeros((4, 4, 3), dtype=np.float32))
    with pytest.raises(ValueError, match="uint8"):
        encode_png(np.zeros((4, 4, 4), dtype=np.uint8))
    with pytest.raises(ValueError, match="one pixel"):
        encode_png(np.zeros((0, 4), dtype=np.uint8))


def test_the_alpha_output_is_an_8_bit_grey_png_of_the_coverage() -> None:
    alpha = np.linspace(-0.2, 1.2, 63, dtype=np.float32).reshape(9, 7)
    served = encode("alpha", np.zeros((9, 7, 3)), np.zeros((9, 7)), alpha, 90)
    image = Image.open(io.BytesIO(served))
    assert image.mode == "L"
    expected = (np.clip(alpha, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    assert np.array_equal(np.asarray(image), expected)
