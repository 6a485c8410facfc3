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
import torch
from PIL import Image

from sparsesplat.api.renders import EMPTY_RENDER_COVERAGE, empty_renders
from sparsesplat.engine.color.models import SHColor
from sparsesplat.engine.model import CHECKPOINT_NAME, save_checkpoint
from sparsesplat.engine.model.encode import encode, encode_image
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
    # The service's PNG: the same pixels at its faster compression.
    served = encode("png", image, np.zeros((9, 7)), np.ones((9, 7)), 90)
    assert served == encode_image(image, "png", compress_level=1)
    assert np.array_equal(np.asarray(Image.open(io.BytesIO(served))), rgb)
