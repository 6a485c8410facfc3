"""The densification strategy of 3DGS as DNGaussian runs it (dngaussian-method.md §1.7).

Between ``densify_from`` and ``densify_until`` the photometric pass's screen-space gradients
are accumulated per Gaussian; every ``densify_interval`` iterations Gaussians with a large mean
gradient are cloned (small ones) or split (large ones), and the transparent ones (and, when
configured, the ones too large on screen or in the world) are pruned. At the
``clean_iterations`` Gaussians no training camera sees are pruned; with an
``opacity_reset_interval`` the 3DGS opacity reset runs.

The gradient accumulators themselves live on :class:`Gaussians` (its table surgery keeps them
row-aligned, and they are checkpointed with the model); the strategy owns the largest screen
radius seen per Gaussian (:attr:`DensifyStrategy.max_radii`). A run that never densifies nor
cleans (``DensifySettings.active`` false) builds no strategy.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.errors import EngineError
from sparsesplat.engine.gaussians import Gaussians
from sparsesplat.engine.raster import RasterOutput
from sparsesplat.engine.train.config import TrainConfig
from sparsesplat.engine.train.parts import Raster, StageTimer


class ModelCollapsed(EngineError, RuntimeError):
    """Training removed every Gaussian (e.g. a pruning threshold no Gaussian can pass)."""


@dataclass(frozen=True)
class DensifySettings:
    """The densification thresholds and schedule (from the flat :class:`TrainConfig`)."""

    densify_from: int
    """Densify for iterations > this ..."""
    densify_until: int
    """... and < this (gradient statistics and the opacity reset stop here too)."""
    interval: int
    """Densify every n iterations."""
    grad_threshold: float
    """Mean screen-space gradient (NDC units) from which a Gaussian is cloned or split."""
    percent_dense: float
    """Clone if max scale <= this x extent, else split."""
    split_opacity_threshold: float
    """Only Gaussians with opacity above this are cloned or split."""
    prune_opacity: float
    """Prune Gaussians with opacity below this at each densification."""
    opacity_reset_interval: int | None
    """3DGS opacity reset period; None = never."""
    max_screen_size: float | None
    """Prune Gaussians whose screen radius exceeded this many pixels (after the first opacity
    reset); None = off (and no radii are tracked)."""
    max_world_size: float | None
    """Prune Gaussians larger than this x extent; None = off."""
    max_gaussians: int | None
    """Cap on the number of Gaussians."""
    clean_iterations: tuple[int, ...]
    """Iterations at which Gaussians invisible from every training view are pruned."""

    @property
    def active(self) -> bool:
        """Whether the strategy does anything in a run: statistics (and with them
        densification and the opacity reset) need an iteration below ``densify_until``."""
        return self.densify_until > 1 or bool(self.clean_iterations)

    @classmethod
    def from_config(cls, cfg: TrainConfig) -> DensifySettings:
        """The densification part of ``cfg``."""
        return cls(
            densify_from=cfg.densify_from,
            densify_until=cfg.densify_until,
            interval=cfg.densify_interval,
            grad_threshold=cfg.densify_grad_threshold,
            percent_dense=cfg.percent_dense,
            split_opacity_threshold=cfg.split_opacity_threshold,
            prune_opacity=cfg.prune_opacity,
            opacity_reset_interval=cfg.opacity_reset_interval,
            max_screen_size=cfg.max_screen_size,
            max_world_size=cfg.max_world_size,
            max_gaussians=cfg.max_gaussians,
            clean_iterations=tuple(cfg.clean_iterations),
        )


class DensifyStrategy:
    """Clone/split/prune, clean-views pruning and the opacity reset, with their statistics.

    Hooks, in loop order: :meth:`step_pre_backward` (before any pass of the iteration: the
    clean-views pruning), :meth:`step_post_backward` (after the photometric backward, before
    its optimizer step: statistics, densification, opacity reset) and :meth:`finish` (after
    the last iteration)."""

    def __init__(
        self,
        settings: DensifySettings,
        cameras: list[Camera],
        raster: Raster,
        generator: torch.Generator,
    ) -> None:
        """``cameras``: the training cameras (clean-views pruning); ``raster``: the run's
        rasterizer; ``generator``: the run's generator (split samples)."""
        self.settings = settings
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
        if iteration not in self.settings.clean_iterations:
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
        s, g, it = self.settings, gaussians, iteration
        if it < s.densify_until and not cleaned:
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
        if s.densify_from < it < s.densify_until and it % s.interval == 0:
            if before_densify is not None:
                before_densify(g)
            reset_done = s.opacity_reset_interval is not None and it > s.opacity_reset_interval
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
        if s.opacity_reset_interval and it % s.opacity_reset_interval == 0 and it < s.densify_until:
            g.reset_opacity(optimizer)

    def finish(
        self, iteration: int, gaussians: Gaussians, optimizer: torch.optim.Optimizer
    ) -> None:
        """After the last iteration: clean views once more if it is a clean iteration."""
        if iteration in self.settings.clean_iterations:
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
