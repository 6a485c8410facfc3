"""A trained model loaded from its checkpoint, ready to render: what does not depend on the view
is computed once (the render worker keeps these in its cache; ``sparsesplat render`` loads one).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, get_args

import torch
from torch import Tensor

from sparsesplat.api.renders import DEFAULT_RENDER_MODE, RenderMode
from sparsesplat.engine.camera import Camera
from sparsesplat.engine.color.models import ColorModel, NeuralColor, make_color_model
from sparsesplat.engine.color.view_colors import BakedViewColors, NeuralViewColors
from sparsesplat.engine.export.ply import read_ply
from sparsesplat.engine.gaussians import Gaussians
from sparsesplat.engine.model.checkpoint import CheckpointError, load_checkpoint
from sparsesplat.engine.model.raster import bind_raster, stored_raster_config
from sparsesplat.engine.model.render import ViewColors, render_view
from sparsesplat.engine.model.sh import model_sh
from sparsesplat.engine.raster import RasterOutput

log = logging.getLogger(__name__)

RENDER_MODES: tuple[str, ...] = get_args(RenderMode)
"""The accepted render modes (``api.renders.RenderMode``: neural = exact, baked = SH bake)."""


class TrainedModel:
    """A trained scene: its Gaussians and colour model, rendered view by view."""

    def __init__(self, state: dict[str, Any], device: str | torch.device = "cpu") -> None:
        """Build from a checkpoint state dict (a training checkpoint or a finished model)."""
        self.device = torch.device(device)
        self.raster = stored_raster_config(state["config"])
        """The run's raster settings (its backend and screen-space dilation)."""
        self.gaussians = Gaussians({k: v.to(self.device) for k, v in state["gaussians"].items()})
        self.color: ColorModel = make_color_model(state["color"])
        self.background: Tensor = state["background"].to(self.device)
        self.iteration = int(state["iteration"])
        self.raster_near = float(state.get("raster_near", 0.01))
        self._raster = bind_raster(self.raster_near, self.raster.eps2d, self.raster.backend)
        self._baked_sh: Tensor | None = None
        self._colors: dict[str, ViewColors] = {}
        if isinstance(self.color, NeuralColor):
            self.color.field.to(self.device)
            self._colors["neural"] = NeuralViewColors(self.color.field, self.gaussians.means)

    def __len__(self) -> int:
        """Number of Gaussians."""
        return len(self.gaussians)

    def baked_sh(self) -> Tensor:
        """(N, K, 3) SH coefficients of the model's colours (float32, CPU; K = 16 when baked).

        The exact SH of an SH-colour model; for neural colour the one given to
        :meth:`use_baked_sh` (the run's export, fitted to the training directions too), else
        a bake over sphere directions made here once (seconds for 50k Gaussians).
        """
        if self._baked_sh is None:
            self._baked_sh = model_sh(self.gaussians, self.color, [])
        return self._baked_sh

    def use_baked_sh(self, sh: Tensor) -> None:
        """Serve ``baked`` renders with ``sh`` (N, K, 3), e.g. the SH of the run's PLY export."""
        if sh.dim() != 3 or sh.shape[0] != len(self) or sh.shape[2] != 3:
            raise CheckpointError(
                f"baked SH of shape {tuple(sh.shape)} do not fit {len(self)} Gaussians"
            )
        self._baked_sh = sh.detach().float().cpu()
        self._colors.pop("baked", None)

    def use_export_sh(self, ply: Path) -> bool:
        """Serve ``baked`` renders with the SH of the run's .ply export when it is this model's
        (same centres); True when it was taken.

        The run baked them fitting the training directions as well as the sphere, which is
        more faithful where the model was trained than a bake from sphere directions alone;
        without a matching export the model bakes its own on the first ``baked`` render.
        """
        if not ply.is_file():
            return False
        try:
            data = read_ply(ply)
        except Exception:  # an unreadable export only costs the fidelity of the bake
            log.warning("cannot read the .ply export; baked renders bake again", exc_info=True)
            return False
        means = self.gaussians.means.detach().cpu()
        if data["means"].shape != means.shape or not bool((data["means"] == means).all()):
            return False
        self.use_baked_sh(data["sh"])
        return True

    def _view_colors(self, mode: str) -> ViewColors:
        """The per-view colour function of ``mode``, built on first use."""
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
        bg = self.background if background is None else torch.as_tensor(background).float()
        colors = self._view_colors(mode)
        cam = camera.to(self.device, torch.float32)
        return render_view(self.gaussians, colors, cam, bg, self._raster)


def load_model(checkpoint: str | Path, device: str | torch.device = "cpu") -> TrainedModel:
    """Load a checkpoint (file or run folder) as a :class:`TrainedModel`."""
    return TrainedModel(load_checkpoint(checkpoint), device)
