"""Checkpoint files: the full training state (a running job's) or the finished model's part of it.

The trainer writes and reads them (``engine/train/loop/state.py`` says what the state holds);
:class:`~sparsesplat.engine.model.trained.TrainedModel` loads one for rendering and export.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import torch

from sparsesplat.engine.errors import EngineError

CHECKPOINT_NAME = "checkpoint.pt"
"""File name of the checkpoint inside a run's output folder."""
CHECKPOINT_VERSION = 1
"""The checkpoint format (``engine/train/loop/state.py`` writes it; :func:`load_checkpoint`
accepts only it)."""


class CheckpointError(EngineError, ValueError):
    """A checkpoint file is missing, unreadable or not a sparsesplat checkpoint."""


def save_checkpoint(state: dict[str, Any], path: str | Path) -> Path:
    """Write ``state`` atomically (temp file + rename) so a crash never leaves half a file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    torch.save(state, tmp)
    os.replace(tmp, path)
    return path


MODEL_KEYS = (
    "version", "config", "scene_name", "iteration", "elapsed_s", "extent", "raster_near",
    "background", "gaussians", "color", "records",
)  # fmt: skip
"""What a stored model needs to render and to be exported (:class:`TrainedModel`, the .ply and
.splat exports): no optimizer, densification, generator or depth-pass state."""
TABLE_DTYPE = torch.float16
"""Precision the colour field's hash tables are stored at in a finished model: their values
are small feature offsets, and a render from half-precision tables stays within one 8-bit
level of the full-precision render (tests/engine/model/test_stored_model.py)."""
_TABLE_KEYS = ("grid.embeddings",)
"""Colour-field weights that are hash tables (the bulk of a model: 2^19 x 16 levels x 2)."""


def model_state(state: dict[str, Any]) -> dict[str, Any]:
    """The finished-model form of a training checkpoint ``state``: only :data:`MODEL_KEYS`,
    the colour field's tables at :data:`TABLE_DTYPE`, marked ``model_only`` (a run cannot be
    resumed from it; a running job's checkpoints keep everything)."""
    model = {k: state[k] for k in MODEL_KEYS if k in state}
    color = dict(model["color"])
    if "weights" in color:
        color["weights"] = {
            k: v.to(TABLE_DTYPE) if k in _TABLE_KEYS and v.is_floating_point() else v
            for k, v in color["weights"].items()
        }
    model["color"] = color
    model["model_only"] = True
    return model


def load_checkpoint(path: str | Path) -> dict[str, Any]:
    """Read a checkpoint written by :func:`save_checkpoint` (CheckpointError if invalid)."""
    path = Path(path)
    if path.is_dir():
        path = path / CHECKPOINT_NAME
    if not path.is_file():
        raise CheckpointError(f"checkpoint {path}: no such file")
    try:
        # weights_only=False: the state holds the generator state and plain dicts we wrote.
        state = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:
        raise CheckpointError(f"checkpoint {path}: cannot be read ({exc})") from exc
    if (
        not isinstance(state, dict)
        or state.get("version") != CHECKPOINT_VERSION
        or "gaussians" not in state
    ):
        raise CheckpointError(
            f"checkpoint {path}: not a sparsesplat v{CHECKPOINT_VERSION} checkpoint"
        )
    return state
