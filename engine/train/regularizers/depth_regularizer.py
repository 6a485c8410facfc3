"""DNGaussian's depth regulariser (dngaussian-method.md §1.5-§1.6): the hard and soft depth
passes with Global-Local depth normalization against a monocular prior.

Each pass is its own forward/backward and, as the reference code runs it, its own step of the
run's shared Adam optimizer (``zero_grad(set_to_none=True)`` after, so a pass moves only what it
reaches); with ``auxiliary_step='joint'`` the gradients instead join the photometric step (the
paper's single objective):

1. hard depth: opacity ``hard_opacity`` everywhere, scales/rotations detached → centres move;
2. soft depth: centres/scales/rotations detached → only opacities move; after
   ``depth.soft_start`` and, on DTU, only while the EMA of the hard loss is below a gate.

The part is constructed only when the config uses depth; it prepares the priors once (shape
checks, the empty-background edit, the [0, 257] guides of the smoothness weights).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.datasets.common import camera_layout
from sparsesplat.engine.errors import SceneError
from sparsesplat.engine.gaussians import inverse_sigmoid
from sparsesplat.engine.losses import DepthTarget, edge_aware_smoothness, global_local_depth_loss
from sparsesplat.engine.model.raster import Raster
from sparsesplat.engine.train.config import DepthConfig
from sparsesplat.engine.train.loop.parts import AuxiliaryStep, TrainView, finish_auxiliary_pass
from sparsesplat.engine.train.loop.schedule import ScheduleClock
from sparsesplat.engine.train.regularizers.dtu_background import fill_background_depth

HARD_EMA_DECAY = 0.9
"""Weight of the previous value in the running mean of the hard-depth loss (the DTU gate)."""


def empty_background_to_nearest(prior: Tensor, image: Tensor, background: Tensor) -> Tensor:
    """``prior`` (H, W) with the pixels where ``image`` (3, H, W) equals ``background`` to
    within half an 8-bit step set to the prior's smallest (nearest) value elsewhere."""
    empty = ((image - background.view(3, 1, 1)).abs() <= 0.5 / 255).all(dim=0)
    if not bool(empty.any()) or bool(empty.all()):
        return prior
    return torch.where(empty, prior[~empty].min(), prior)


def hard_downscale(settings: DepthConfig, cameras: list[Camera]) -> int:
    """The hard pass's resolution divisor: ``depth.hard_downscale``, or where that is None 2
    for training ``cameras`` that face forward and 1 for an inward-looking set (an orbit)."""
    if settings.hard_downscale is not None:
        return settings.hard_downscale
    return 2 if camera_layout(cameras).forward_facing else 1


def downscale_depth(depth: Tensor, size: tuple[int, int]) -> Tensor:
    """(H, W) depth averaged over the pixels of each cell of an ``size`` = (h, w) grid (area
    resampling: each coarse pixel is the mean of the fine pixels it covers)."""
    return F.interpolate(depth[None, None], size=size, mode="area")[0, 0]


@dataclass
class DepthLevel:
    """The priors of every training view at one resolution, prepared for the depth loss."""

    downscale: int
    """Image side over this level's side (1: the training resolution)."""
    priors: list[Tensor]
    """(h, w) prior per training view."""
    guides: list[Tensor]
    """The priors on the [0, 257] scale the reference's smoothness weights see."""
    targets: list[DepthTarget]
    """The priors' fixed loss parts (normalized patches, smoothness weights), per view; not
    used where a view's background mask edits the prior each iteration (DTU)."""
    patch_range: tuple[int, int]
    """Patch sides of the normalization at this resolution: the configured range divided by
    ``downscale`` (rounded up), so a patch covers the same part of the image."""

    @classmethod
    def build(
        cls, priors: list[Tensor], downscale: int, patch_range: tuple[int, int], smooth: bool
    ) -> DepthLevel:
        """The level of ``priors`` (full resolution) at 1/``downscale`` of their side."""
        if downscale > 1:
            priors = [
                downscale_depth(p, _coarse_size(p.shape[-2], p.shape[-1], downscale))
                for p in priors
            ]
        guides = []
        for d in priors:
            span = float(d.max() - d.min())
            guides.append((d - d.min()) / span * 257.0 if span > 0 else d * 0)
        targets = [
            DepthTarget(p, g if smooth else None) for p, g in zip(priors, guides, strict=True)
        ]
        lo, hi = (-(-p // downscale) for p in patch_range)
        return cls(downscale, priors, guides, targets, (lo, hi))


def _coarse_size(height: int, width: int, downscale: int) -> tuple[int, int]:
    """The (h, w) of an image of (height, width) rendered at 1/``downscale`` of its side: the
    size ``Camera.scaled`` gives (rounded, at least 1)."""
    return max(1, round(height / downscale)), max(1, round(width / downscale))


class DepthRegularizer:
    """The hard and soft depth passes, their schedules and the hard-loss EMA gate.

    Hook: :meth:`step_pre_photometric` (after the view is drawn, before the photometric pass;
    takes its own optimizer steps)."""

    def __init__(
        self,
        settings: DepthConfig,
        priors: list[Any] | None,
        images: list[Tensor],
        background: Tensor,
        view_names: list[str],
        raster: Raster,
        generator: torch.Generator,
        clock: ScheduleClock,
        views: set[int] | None = None,
        joint: bool = False,
        fill_background: bool = False,
        hard_downscale: int | None = None,
    ) -> None:
        """Check and prepare ``priors`` (one PriorDepth or (H, W) tensor per training view,
        aligned with ``images`` (3, H, W)); SceneError names the view of a bad one. ``clock``:
        the run's schedule position (the starts and ``until`` follow it). ``views``: the
        training views whose prior is used (None: all). ``joint``: ``optim.auxiliary_step ==
        'joint'``, the passes leave their gradients for the photometric step. ``fill_background``:
        DTU, fill the view's background mask (``TrainView.mask``) in rendered and prior depth
        with their foreground means (``dtu.enabled`` and ``dtu.depth_fill``).
        ``hard_downscale``: the hard pass's resolved ``depth.hard_downscale`` (None: the
        setting's, 1 when it is None too)."""
        self.settings = settings
        self.clock = clock
        self.joint = joint
        self.fill_background = fill_background
        self.views = views
        """Positions of the training views the depth passes run on (None: every view)."""
        self.raster = raster
        self.generator = generator
        if priors is None or len(priors) != len(images):
            got = "none" if priors is None else str(len(priors))
            raise SceneError(
                f"priors: depth_prior={settings.prior!r} needs one prior per training view "
                f"({len(images)}), got {got}"
            )
        full: list[Tensor] = []
        for i, p in enumerate(priors):
            d = torch.as_tensor(getattr(p, "depth", p), dtype=torch.float32).to(images[i].device)
            h, w = images[i].shape[1:]
            if d.shape[-2:] != (h, w) or not bool(torch.isfinite(d).all()):
                raise SceneError(
                    f"priors[{i}]: depth must be finite ({h}, {w}) for view "
                    f"{view_names[i]!r}, got shape {tuple(d.shape)}"
                )
            d = d.reshape(h, w)
            if settings.empty_background:
                d = empty_background_to_nearest(d, images[i], background)
            full.append(d)
        smooth = settings.smooth_weight > 0
        self.full = DepthLevel.build(full, 1, settings.patch_range, smooth)
        """The priors at the training resolution (the soft term's)."""
        n = hard_downscale or settings.hard_downscale or 1
        self.hard_level = (
            self.full if n == 1 else DepthLevel.build(full, n, settings.patch_range, smooth)
        )
        """The priors at the hard pass's resolution (``depth.hard_downscale``)."""
        self.hard_logit = float(inverse_sigmoid(torch.tensor(settings.hard_opacity)))
        """The hard pass's constant opacity as a logit."""
        self.hard_ema: float | None = None
        """Running mean of the hard-depth loss (None before the first hard step)."""

    def step_pre_photometric(self, step: AuxiliaryStep) -> None:
        """The iteration's hard and soft passes, each with its own optimizer step (or, joint,
        its gradients left for the photometric step), when the schedules say so."""
        s, g, view, iteration = self.settings, step.gaussians, step.view, step.iteration
        pos = self.clock.position(iteration)
        if not self._due(iteration, view):
            return
        n = len(g)
        empty = g.means.new_zeros(n, 0)
        mask = view.mask if self.fill_background else None
        if s.hard and pos > s.hard_start:
            hard = torch.full((n,), self.hard_logit, device=g.means.device)
            level = self.hard_level
            camera = (
                view.camera if level.downscale == 1 else view.camera.scaled(1 / level.downscale)
            )
            out = self.raster(
                g.means, g.log_scales.detach(), g.quats.detach(), hard, empty, camera, None
            )
            hard_mask = mask if mask is None or level.downscale == 1 else _coarse_mask(mask, level)
            loss = self.depth_loss(out.depth, view.index, iteration, step.extent, hard_mask, level)
            finish_auxiliary_pass(step, loss, "the hard-depth loss", self.joint)
            hv = float(loss.detach())
            ema = self.hard_ema
            self.hard_ema = hv if ema is None else HARD_EMA_DECAY * ema + 0.1 * hv
            step.timer.tick("hard_depth")
        if self._soft_due(iteration) and not s.soft_fused:
            out = self.raster(
                g.means.detach(),
                g.log_scales.detach(),
                g.quats.detach(),
                g.opacity_logits,
                empty,
                view.camera,
                None,
            )
            loss = self.depth_loss(out.depth, view.index, iteration, step.extent, mask)
            finish_auxiliary_pass(step, loss, "the soft-depth loss", self.joint)
            step.timer.tick("soft_depth")

    def _due(self, iteration: int, view: TrainView) -> bool:
        """Whether the depth schedule and the view's prior allow a depth term this iteration."""
        s, pos = self.settings, self.clock.position(iteration)
        if iteration % s.every != 0 or (s.until is not None and pos >= s.until):
            return False
        return self.views is None or view.index in self.views

    def _soft_due(self, iteration: int) -> bool:
        """Whether the soft term's schedule and (DTU) the hard-loss gate are open."""
        s = self.settings
        gate_open = s.soft_ema_gate is None or (
            self.hard_ema is not None and self.hard_ema < s.soft_ema_gate
        )
        return s.soft and self.clock.position(iteration) > s.soft_start and gate_open

    def wants_fused_soft(self, iteration: int, view: TrainView) -> bool:
        """Whether the photometric render must provide ``opacity_depth`` for :meth:`soft_loss`
        this iteration (call after :meth:`step_pre_photometric`, which updates the gate)."""
        return self.settings.soft_fused and self._due(iteration, view) and self._soft_due(iteration)

    def soft_loss(
        self, opacity_depth: Tensor, view: TrainView, iteration: int, extent: float
    ) -> Tensor:
        """The soft-depth term on the photometric render's opacity-only depth (its gradient
        reaches the opacities alone), to be added to the photometric loss."""
        mask = view.mask if self.fill_background else None
        return self.depth_loss(opacity_depth, view.index, iteration, extent, mask)

    @property
    def priors(self) -> list[Tensor]:
        """The prepared (H, W) priors at the training resolution, one per training view."""
        return self.full.priors

    def depth_loss(
        self,
        depth: Tensor,
        index: int,
        iteration: int,
        extent: float,
        mask: Tensor | None = None,
        level: DepthLevel | None = None,
    ) -> Tensor:
        """Global-local depth loss of a rendered ``depth`` against prior ``index``, plus the
        edge-aware smoothness once it is on (rendered depth in units of the scene extent).
        ``mask``: background pixels filled with the foreground means in both depths first.
        ``level``: the resolution of ``depth`` (default: the training resolution)."""
        s, lv = self.settings, self.full if level is None else level
        d = depth.reshape(depth.shape[-2], depth.shape[-1])
        prior: Tensor | DepthTarget = lv.targets[index]
        if mask is not None:
            d, prior = fill_background_depth(d, lv.priors[index], mask)
        loss = global_local_depth_loss(
            d,
            prior,
            lv.patch_range,
            s.error_tolerance,
            self.generator,
            s.global_weight,
            s.local_weight,
        )
        if s.smooth_weight > 0 and self.clock.position(iteration) > s.smooth_start:
            weights = lv.targets[index].smooth_weights
            smooth = edge_aware_smoothness(d / extent, lv.guides[index], weights)
            loss = loss + s.smooth_weight * smooth
        return loss

    def state_dict(self) -> dict[str, Any]:
        """Checkpoint entries (``hard_ema``)."""
        return {"hard_ema": self.hard_ema}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore from a checkpoint."""
        self.hard_ema = state.get("hard_ema")


def _coarse_mask(mask: Tensor, level: DepthLevel) -> Tensor:
    """A full-resolution background mask at ``level``: a coarse pixel is background when most
    of the fine pixels it covers are."""
    h, w = level.priors[0].shape[-2:]
    flat = mask.reshape(mask.shape[-2], mask.shape[-1]).to(torch.float32)
    return (downscale_depth(flat, (h, w)) > 0.5).reshape(*mask.shape[:-2], h, w)
