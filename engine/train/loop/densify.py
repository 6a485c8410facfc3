"""The densification strategy of 3DGS as DNGaussian runs it (dngaussian-method.md §1.7).

Between ``densify.start`` and ``densify.until`` the photometric pass's screen-space gradients
are accumulated per Gaussian; every ``densify.interval`` iterations Gaussians with a large mean
gradient are cloned (small ones) or split (large ones), and the transparent ones (and, when
configured, the ones too large on screen or in the world) are pruned. At the
``clean_iterations`` Gaussians no training camera sees are pruned; with an
``opacity_reset_interval`` the 3DGS opacity reset runs.

The gradient accumulators themselves live on :class:`Gaussians` (its table surgery keeps them
row-aligned, and they are checkpointed with the model); the strategy owns the largest screen
radius seen per Gaussian (:attr:`DensifyStrategy.max_radii`). A run that never densifies nor
cleans (``DensifyConfig.active`` false) builds no strategy.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch
from torch import Tensor

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.errors import EngineError
from sparsesplat.engine.gaussians import Gaussians
from sparsesplat.engine.model.raster import Raster
from sparsesplat.engine.raster import RasterOutput
from sparsesplat.engine.train.config import DensifyConfig
from sparsesplat.engine.train.loop.parts import StageTimer
from sparsesplat.engine.train.loop.schedule import ScheduleClock


class ModelCollapsed(EngineError, RuntimeError):
    """Training removed every Gaussian (e.g. a pruning threshold no Gaussian can pass)."""


class DensifyStrategy:
    """Clone/split/prune, clean-views pruning and the opacity reset, with their statistics.

    Hooks, in loop order: :meth:`step_pre_backward` (before any pass of the iteration: the
    clean-views pruning), :meth:`step_post_backward` (after the photometric backward, before
    its optimizer step: statistics, densification, opacity reset) and :meth:`finish` (after
    the last iteration)."""

    def __init__(
        self,
        settings: DensifyConfig,
        cameras: list[Camera],
        raster: Raster,
        generator: torch.Generator,
        clock: ScheduleClock,
    ) -> None:
        """``cameras``: the training cameras (clean-views pruning); ``raster``: the run's
        rasterizer; ``generator``: the run's generator (split samples); ``clock``: the run's
        schedule position (the window, the resets and the clean iterations follow it)."""
        self.settings = settings
        self.clock = clock
        self.cameras = cameras
        self.raster = raster
        self.generator = generator
        self.max_radii: Tensor | None = None
        """Largest screen radius (pixels, CPU) per Gaussian since the last densification;
        None until the first statistics step."""

    def step_pre_backward(
        self, iteration: int, gaussians: Gaussians, optimizer: torch.optim.Optimizer
    ) -> bool:
        """Clean-views pruning at the clean iterations; returns whether it ran (no statistics
        are gathered and no densification happens in that iteration)."""
        if not any(self.clock.crossed(c, iteration) for c in self.settings.clean_iterations):
            return False
        self.clean_views(gaussians, optimizer)
        if len(gaussians) == 0:
            raise ModelCollapsed(f"step {iteration}: no Gaussian is visible from any training view")
        return True

    def step_post_backward(
        self,
        iteration: int,
        gaussians: Gaussians,
        optimizer: torch.optim.Optimizer,
        out: RasterOutput,
        camera: Camera,
        cleaned: bool,
        extent: float,
        timer: StageTimer,
        before_densify: Callable[[Gaussians], None] | None = None,
    ) -> None:
        """After the photometric backward: accumulate the statistics of ``out`` (the
        photometric render through ``camera``), densify when due, reset opacities when due.
        ``before_densify``: called with the model just before densify-and-prune (the DTU
        black/white rule)."""
        s, g, it, pos = self.settings, gaussians, iteration, self.clock.position(iteration)
        if pos < s.until and not cleaned:
            grad = out.means2d.grad
            if grad is not None:
                w, h = camera.width, camera.height
                # Our means2d are pixels; the reference thresholds are in the 3DGS rasterizer's
                # NDC-gradient units: d/dndc = d/dpix * (size / 2).
                ndc = grad * torch.tensor([0.5 * w, 0.5 * h], device=grad.device)
                g.add_densification_stats(ndc, out.radii > 0)
            if s.max_screen_size is not None:
                # Kept on the model's device: a copy to the host would sync a GPU every step.
                r = out.radii.detach().float()
                prev = (
                    self.max_radii.to(r.device)
                    if self.max_radii is not None
                    else torch.zeros(len(g), device=r.device)
                )
                self.max_radii = torch.maximum(prev, r) if prev.shape == r.shape else r
        if s.start < pos < s.until and it % s.interval == 0:
            if before_densify is not None:
                before_densify(g)
            reset_done = s.opacity_reset_interval is not None and pos > s.opacity_reset_interval
            g.densify_and_prune(
                optimizer,
                grad_threshold=s.grad_threshold,
                percent_dense=s.percent_dense,
                scene_extent=extent,
                min_opacity=s.prune_opacity,
                split_opacity_threshold=s.split_opacity_threshold,
                generator=self.generator,
                max_screen_radius=self.max_radii if reset_done else None,
                max_screen_size=s.max_screen_size if reset_done else None,
                max_world_size=s.max_world_size * extent if s.max_world_size else None,
                max_gaussians=s.max_gaussians,
            )
            self.max_radii = torch.zeros(len(g), device=g.means.device)
            if len(g) == 0:
                raise ModelCollapsed(
                    f"step {it}: every Gaussian was pruned (prune_opacity={s.prune_opacity})"
                )
            timer.tick("densify")
        reset = s.opacity_reset_interval
        if reset and self.clock.crossed_multiple(reset, it) and pos < s.until:
            g.reset_opacity(optimizer)

    def finish(
        self, iteration: int, gaussians: Gaussians, optimizer: torch.optim.Optimizer
    ) -> None:
        """After the last iteration: clean views once more if it is a clean iteration."""
        if any(self.clock.crossed(c, iteration) for c in self.settings.clean_iterations):
            self.clean_views(gaussians, optimizer)

    def clean_views(self, gaussians: Gaussians, optimizer: torch.optim.Optimizer) -> None:
        """Prune Gaussians not visible (radius 0) from every training camera."""
        g = gaussians
        visible = torch.zeros(len(g), dtype=torch.bool, device=g.means.device)
        empty = g.means.new_zeros(len(g), 0)
        with torch.no_grad():
            for cam in self.cameras:
                out = self.raster(
                    g.means, g.log_scales, g.quats, g.opacity_logits, empty, cam, None
                )
                visible |= out.radii > 0
        if not bool(visible.all()):
            g.prune(visible, optimizer)
            if self.max_radii is not None:
                self.max_radii = self.max_radii[visible.to(self.max_radii.device)]

    def state_dict(self) -> dict[str, Any]:
        """Checkpoint entries (``max_radii``; the accumulators are saved with the model)."""
        return {"max_radii": None if self.max_radii is None else self.max_radii.cpu()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore the entries of :meth:`state_dict`."""
        if state.get("max_radii") is not None:
            self.max_radii = state["max_radii"]
