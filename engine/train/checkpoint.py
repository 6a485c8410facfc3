"""Native checkpoints: save/load the full training state, and load a model for rendering."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, get_args

import torch
from torch import Tensor

from sparsesplat.api.renders import DEFAULT_RENDER_MODE, RenderMode
from sparsesplat.engine.camera import Camera
from sparsesplat.engine.errors import EngineError
from sparsesplat.engine.raster.types import RasterOutput

CHECKPOINT_NAME = "checkpoint.pt"
"""File name of the checkpoint inside a run's output folder."""


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
level of the full-precision render (tests/engine/train/test_stored_model.py)."""
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
    if not isinstance(state, dict) or state.get("version") != 1 or "gaussians" not in state:
        raise CheckpointError(f"checkpoint {path}: not a sparsesplat v1 checkpoint")
    return state


RENDER_MODES: tuple[str, ...] = get_args(RenderMode)
"""The accepted render modes (``api.renders.RenderMode``: neural = exact, baked = SH bake)."""


class TrainedModel:
    """A trained scene ready to render: what does not depend on the view is computed once."""

    def __init__(self, state: dict[str, Any], device: str | torch.device = "cpu") -> None:
        """Build from a checkpoint state dict."""
        from sparsesplat.engine.color.models import NeuralColor, make_color_model
        from sparsesplat.engine.color.view_colors import NeuralViewColors
        from sparsesplat.engine.gaussians import Gaussians
        from sparsesplat.engine.train.config import TrainConfig

        self.device = torch.device(device)
        self.config = TrainConfig.from_dict(state["config"])
        self.gaussians = Gaussians({k: v.to(self.device) for k, v in state["gaussians"].items()})
        self.color = make_color_model(state["color"])
        self.background: Tensor = state["background"].to(self.device)
        self.iteration = int(state["iteration"])
        self.raster_near = float(state.get("raster_near", 0.01))
        self._baked_sh: Tensor | None = None
        self._colors: dict[str, Callable[[Tensor], Tensor]] = {}
        if isinstance(self.color, NeuralColor):
            self.color.field.to(self.device)
            self._colors["neural"] = NeuralViewColors(self.color.field, self.gaussians.means)

    def __len__(self) -> int:
        """Number of Gaussians."""
        return len(self.gaussians)

    def baked_sh(self) -> Tensor:
        """(N, K, 3) SH coefficients of the model's colours (float32, CPU; K = 16 when baked).

        The exact SH of an SH-colour model; for neural colour the one given to
        :meth:`use_baked_sh` (the trainer's export, fitted to the training directions too), else
        a least-squares bake over sphere directions made here once (seconds for 50k Gaussians).
        """
        from sparsesplat.engine.color.models import SHColor
        from sparsesplat.engine.train.recorder import model_sh

        if self._baked_sh is None:
            if isinstance(self.color, SHColor):
                self._baked_sh = model_sh(self.gaussians, self.color, [])
            else:
                from sparsesplat.engine.export import bake_sh

                fn = self.color.color_fn(self.gaussians)
                n = len(self.gaussians)
                self._baked_sh = bake_sh(fn, n, degree=3, device=self.device)
        return self._baked_sh

    def use_baked_sh(self, sh: Tensor) -> None:
        """Serve ``baked`` renders with ``sh`` (N, K, 3), e.g. the SH of the run's PLY export."""
        if sh.dim() != 3 or sh.shape[0] != len(self) or sh.shape[2] != 3:
            raise CheckpointError(
                f"baked SH of shape {tuple(sh.shape)} do not fit {len(self)} Gaussians"
            )
        self._baked_sh = sh.detach().float().cpu()
        self._colors.pop("baked", None)

    def _view_colors(self, mode: str) -> Callable[[Tensor], Tensor]:
        """The per-view colour function of ``mode``, built on first use."""
        from sparsesplat.engine.color.view_colors import BakedViewColors

        if mode not in RENDER_MODES:
            raise CheckpointError(f"render mode must be one of {RENDER_MODES}, got {mode!r}")
        if mode not in self._colors:
            if mode == "neural":  # an SH-colour model: its own coefficients are exact
                g, color = self.gaussians, self.color
                self._colors[mode] = lambda center: color.colors(g, center)
            else:
                self._colors[mode] = BakedViewColors(self.baked_sh(), self.gaussians.means)
        return self._colors[mode]

    def render(
        self,
        camera: Camera,
        background: Tensor | None = None,
        mode: RenderMode = DEFAULT_RENDER_MODE,
    ) -> RasterOutput:
        """Render one view: (3, H, W) image, depth, alpha (forward only, no gradients)."""
        from sparsesplat.engine.raster import rasterize

        cfg = self.config
        bg = self.background if background is None else torch.as_tensor(background).float()
        colors = self._view_colors(mode)
        cam = camera.to(self.device, torch.float32)
        g = self.gaussians
        with torch.no_grad():
            feats = colors(cam.center.to(g.means))
            return rasterize(
                g.means, g.log_scales, g.quats, g.opacity_logits, feats, cam,
                bg.to(self.device), near=self.raster_near, eps2d=cfg.raster.eps2d,
                backend=cfg.raster.backend,
            )  # fmt: skip

    def color_fn(self):  # type: ignore[no-untyped-def]
        """Per-Gaussian colours for arbitrary unit directions (for SH baking)."""
        return self.color.color_fn(self.gaussians)


def load_model(checkpoint: str | Path, device: str | torch.device = "cpu") -> TrainedModel:
    """Load a checkpoint (file or run folder) as a :class:`TrainedModel`."""
    return TrainedModel(load_checkpoint(checkpoint), device)
