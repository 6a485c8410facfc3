"""A finished model keeps what it needs to render and export, and renders as the full state.

After success the service replaces the training checkpoint by :func:`model_state`: no
optimizer or densification state, the colour field's hash tables at half precision. The render
from it must stay within one 8-bit level of the full-precision render at every pixel, and its
size within 2x the .ply plus the tables at their stored precision.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from sparsesplat.engine.datasets import load_scene
from sparsesplat.engine.model import TrainedModel
from sparsesplat.engine.model.checkpoint import (
    TABLE_DTYPE,
    CheckpointError,
    load_checkpoint,
    model_state,
    save_checkpoint,
)
from sparsesplat.engine.train import Trainer, preset
from tests.cli.scenes import write_object_scene


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("stored")
    scene = load_scene(write_object_scene(root / "scene", size=32))
    # The neural field, named: the stored model's budget below is about its hash table.
    config = preset("object", iterations=30, depth_prior="none", init_points=400,
                    color_model="neural", hash_log2_size=14, eval_lpips=False,
                    seed=3)  # fmt: skip
    Trainer(scene, config, out_dir=root / "run").run()
    return root / "run"


def _eight_bit(model: TrainedModel, camera: object) -> torch.Tensor:
    image = model.render(camera).image.clamp(0, 1)  # type: ignore[arg-type]
    return (image * 255.0 + 0.5).floor().to(torch.int16)


def test_the_stored_model_renders_within_one_8bit_level(trained: Path) -> None:
    full = load_checkpoint(trained)
    slim = model_state(full)
    assert "optimizer" not in slim and "grad_accum" not in slim and slim["model_only"]
    assert slim["color"]["weights"]["grid.embeddings"].dtype == TABLE_DTYPE
    scene = load_scene(trained.parent / "scene")
    a, b = TrainedModel(full), TrainedModel(slim)
    for view in [*scene.train, *scene.test]:
        difference = (_eight_bit(a, view.camera) - _eight_bit(b, view.camera)).abs()
        assert int(difference.max()) <= 1, view.name
    # Not vacuous: the models render something, and the tables did lose precision.
    assert float(a.render(scene.test[0].camera).alpha.mean()) > 0.05
    table = full["color"]["weights"]["grid.embeddings"]
    assert not torch.equal(table, table.to(TABLE_DTYPE).float())


def test_the_stored_model_is_small_and_cannot_be_resumed(trained: Path, tmp_path: Path) -> None:
    slim = save_checkpoint(model_state(load_checkpoint(trained)), tmp_path / "model.pt")
    table = load_checkpoint(slim)["color"]["weights"]["grid.embeddings"]
    ply = (trained / "model.ply").stat().st_size
    full = (trained / "checkpoint.pt").stat().st_size
    budget = 2 * ply + table.numel() * table.element_size()
    assert slim.stat().st_size <= budget, (slim.stat().st_size, budget, full)
    assert slim.stat().st_size < full / 2
    scene = load_scene(trained.parent / "scene")
    config = preset("object", iterations=40, depth_prior="none", color_model="neural",
                    hash_log2_size=14)  # fmt: skip
    with pytest.raises(CheckpointError, match="cannot resume"):
        Trainer(scene, config, resume_from=slim)
