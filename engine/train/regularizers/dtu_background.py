"""DTU's black-background handling, as the DNGaussian reference code runs it.

None of this is in the paper (dngaussian-method.md §6 item 4: "undocumented extras"); it is
read from the reference ``train_dtu.py`` (§1.6, §1.8, §2 "DTU background mask", §1.9 "black
(dark GT pixels forced to 0)"). DTU photos show the object on a dark table/backdrop that the
evaluation masks away; the code makes the model render true black there:

1. **Mask** (every iteration, from the training image): a pixel is background when its largest
   RGB channel is below 30/255 (15/255 on scan110) *and* so are the 49 pixels directly above
   it in the same column (fewer near the top edge: only the rows that exist). The column run
   keeps dark object pixels (shadows, black paint) with a bright pixel above them out of the
   mask. :func:`background_mask`.
2. **Target edits** on the mask: the ground-truth image is set to 0 there (before every pass,
   :func:`blacken_background`); in both depth passes the prior *and* the rendered depth
   (detached) are set to their own foreground means there (:func:`fill_background_depth`), so
   the background adds no depth structure to the Global-Local loss.
3. **Background-alpha pass** (every iteration, after the soft-depth pass and before the
   photometric one, with its own backward and Adam step): render with real opacities and
   centres/scales/rotations detached (the soft-depth render), loss = mean of alpha^2 over the
   mask (:func:`background_alpha_loss`). It pushes the opacity of Gaussians covering the
   backdrop down. The reference runs it from iteration 1 whatever ``soft_depth_start`` is.
4. **Black/white Gaussians** at each densification step (every 100 iterations, before
   densify-and-prune), from each Gaussian's colour as seen from the current iteration's
   camera: near-black (max channel < 20/255) -> screen-gradient accumulator / 10 and opacity
   set to 0.1 (Adam moments untouched); near-white (min channel > 240/255) -> accumulator / 2.
   The code also resets near-white opacities to 0.1 when ``iteration % 2001 == 0``, which never
   holds on a multiple of 100 within 6000 iterations; kept literally
   (:func:`black_white_rule`). Scene-name exceptions: scan110 skips both rules (and uses the
   15/255 mask threshold), scan114 and scan21 skip the white rule
   (:meth:`DtuBackgroundSettings.for_scene`).

Deviations on purpose: the reference's means over empty selections are NaN (an all-background
view, a view with no background); here an empty mask gives a zero loss and unchanged depth, an
all-background view gives constant depth maps (which the guarded depth loss scores 0).
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor

from sparsesplat.engine.errors import SceneError
from sparsesplat.engine.gaussians import Gaussians
from sparsesplat.engine.losses import SSIMTarget
from sparsesplat.engine.model.raster import Raster
from sparsesplat.engine.train.config import DtuConfig
from sparsesplat.engine.train.loop.parts import AuxiliaryStep, TrainView, finish_auxiliary_pass


@dataclass(frozen=True)
class DtuBackgroundSettings:
    """The thresholds and switches of the DTU background handling for one scene."""

    dark_threshold: float = 30.0 / 255.0
    """A pixel is dark when its largest channel is strictly below this."""
    run: int = 50
    """A background pixel and the ``run - 1`` pixels above it must all be dark."""
    black_max: float = 20.0 / 255.0
    """A Gaussian is near-black when its largest colour channel is strictly below this."""
    white_min: float = 240.0 / 255.0
    """A Gaussian is near-white when its smallest colour channel is strictly above this."""
    black_rule: bool = True
    """Apply the near-black rule at densification."""
    white_rule: bool = True
    """Apply the near-white rule at densification."""
    black_grad_divisor: float = 10.0
    """Near-black Gaussians' accumulated screen gradient is divided by this."""
    white_grad_divisor: float = 2.0
    """Near-white Gaussians' accumulated screen gradient is divided by this."""
    reset_opacity: float = 0.1
    """Opacity the rule sets (near-black always, near-white on ``white_reset_every``)."""
    white_reset_every: int = 2001
    """Near-white opacities are reset when ``iteration % white_reset_every == 0`` (the
    reference's value never fires on its 100-iteration densification grid)."""

    def __post_init__(self) -> None:
        if self.run < 1:
            raise SceneError(f"DTU background: run must be >= 1, got {self.run}")
        if not 0.0 < self.reset_opacity < 1.0:
            raise SceneError(f"DTU background: reset_opacity must be in (0, 1), got "
                             f"{self.reset_opacity}")  # fmt: skip
        if self.black_grad_divisor <= 0 or self.white_grad_divisor <= 0:
            raise SceneError("DTU background: gradient divisors must be > 0")
        if self.white_reset_every < 1:
            raise SceneError("DTU background: white_reset_every must be >= 1")

    @classmethod
    def for_scene(cls, name: str) -> DtuBackgroundSettings:
        """The reference's per-scan settings, keyed on ``scanNNN`` in the scene name (the code
        tests the source path): scan110 -> mask threshold 15/255 and no black/white rules;
        scan114, scan21 -> no white rule; every other scan the defaults."""
        match = re.search(r"scan(\d+)", name)
        scan = int(match.group(1)) if match else None
        if scan == 110:
            return cls(dark_threshold=15.0 / 255.0, black_rule=False, white_rule=False)
        if scan in (114, 21):
            return cls(white_rule=False)
        return cls()


def background_mask(image: Tensor, settings: DtuBackgroundSettings | None = None) -> Tensor:
    """(H, W) bool background mask of a (3, H, W) image in [0, 1] (see the module docstring).

    Pixel (r, c) is background iff every pixel (k, c) with ``max(0, r - run + 1) <= k <= r``
    is dark; computed with a running count of bright pixels down each column."""
    s = settings or DtuBackgroundSettings()
    if image.dim() != 3 or image.shape[0] != 3:
        raise SceneError(f"DTU background: expected a (3, H, W) image, got {tuple(image.shape)}")
    img = image.detach()
    # A NaN pixel is not evidence of background: count it bright.
    bright = ((img.amax(dim=0) >= s.dark_threshold) | img.isnan().any(dim=0)).to(torch.int64)
    h = bright.shape[0]
    count = torch.cumsum(bright, dim=0)  # bright pixels in rows [0, r]
    shifted = torch.zeros_like(count)
    if s.run < h:
        shifted[s.run :] = count[: h - s.run]  # bright pixels in rows [0, r - run]
    return (count - shifted) == 0


def blacken_background(image: Tensor, mask: Tensor) -> Tensor:
    """The (3, H, W) target with the background pixels set to 0 (a new tensor)."""
    _check_mask(mask, image)
    return image.masked_fill(mask.unsqueeze(0), 0.0)


def fill_background_depth(rendered: Tensor, prior: Tensor, mask: Tensor) -> tuple[Tensor, Tensor]:
    """Rendered and prior depth (same shape, (H, W) or (1, H, W)) with their background pixels
    replaced by their own foreground means; the rendered one's mean is detached, so only its
    foreground pixels carry gradient (as the reference's in-place edit does).

    Empty mask: both returned unchanged. All-background: both constant 0 (the rendered one
    still attached to the graph with zero gradient), which the guarded depth loss scores 0."""
    if rendered.shape != prior.shape:
        raise SceneError(f"DTU background: depth shapes {tuple(rendered.shape)} and "
                         f"{tuple(prior.shape)} differ")  # fmt: skip
    _check_mask(mask, rendered)
    m = mask.expand_as(rendered)
    if not bool(m.any()):
        return rendered, prior
    fg = ~m
    if not bool(fg.any()):
        zero = rendered.new_zeros(())
        return torch.where(m, zero, rendered), torch.zeros_like(prior)
    r_mean = rendered.detach()[fg].mean()
    p_mean = prior.detach()[fg].mean()
    return torch.where(m, r_mean, rendered), torch.where(m, p_mean, prior)


def background_alpha_loss(alpha: Tensor, mask: Tensor) -> Tensor:
    """Mean of ``alpha^2`` over the background pixels; 0 (attached, zero gradient) when the
    mask is empty. ``alpha`` is the (1, H, W) or (H, W) accumulated opacity of the soft render
    (real opacities, geometry detached)."""
    a = alpha.reshape(alpha.shape[-2:])
    _check_mask(mask, a)
    m = mask
    count = int(m.sum())
    if count == 0:
        return (a * 0.0).sum()
    return (a * a).masked_fill(~m, 0.0).sum() / count


@dataclass(frozen=True)
class DensifyAdjustment:
    """What the black/white rule asks the densification strategy to do before it densifies."""

    grad_scale: Tensor
    """(N,) factor for each Gaussian's accumulated screen-space gradient (1, 1/10 or 1/2)."""
    reset: Tensor
    """(N,) bool: set these Gaussians' opacity to ``reset_opacity`` (logit written in place,
    optimizer moments kept)."""
    reset_logit: float
    """``logit(reset_opacity)``, the value to write into the reset rows' opacity logits."""
    black: Tensor
    """(N,) bool near-black Gaussians (for logs)."""
    white: Tensor
    """(N,) bool near-white Gaussians (for logs)."""


def black_white_rule(
    colors: Tensor, iteration: int, settings: DtuBackgroundSettings | None = None
) -> DensifyAdjustment:
    """The reference's DTU near-black / near-white Gaussian rule at a densification step.

    ``colors`` (N, 3): each Gaussian's colour for the current iteration's camera (the neural
    field's output for that view direction, computed without gradient). The strategy applies
    the result before densify-and-prune: ``accum *= grad_scale`` (the count is unchanged, so the
    mean gradient scales) and ``opacity_logits[reset] = reset_logit``."""
    s = settings or DtuBackgroundSettings()
    if colors.dim() != 2 or colors.shape[1] != 3:
        raise SceneError(f"DTU background: colours must be (N, 3), got {tuple(colors.shape)}")
    c = colors.detach()
    n = c.shape[0]
    none = torch.zeros(n, dtype=torch.bool, device=c.device)
    black = c.amax(dim=1) < s.black_max if s.black_rule else none
    white = c.amin(dim=1) > s.white_min if s.white_rule else none
    scale = torch.ones(n, dtype=c.dtype, device=c.device)
    scale = torch.where(black, scale / s.black_grad_divisor, scale)
    scale = torch.where(white, scale / s.white_grad_divisor, scale)
    reset = black | (white if iteration % s.white_reset_every == 0 else none)
    logit = math.log(s.reset_opacity / (1.0 - s.reset_opacity))
    return DensifyAdjustment(scale, reset, logit, black, white)


def _check_mask(mask: Tensor, image: Tensor) -> None:
    if mask.dtype != torch.bool or tuple(mask.shape) != tuple(image.shape[-2:]):
        raise SceneError(
            f"DTU background: mask must be bool {tuple(image.shape[-2:])}, got "
            f"{mask.dtype} {tuple(mask.shape)}"
        )


class DtuBackground:
    """The trainer's DTU background part. No state (the masks follow from the images).

    Hooks: :meth:`adjust_view` (after the view is drawn), :meth:`step_pre_photometric` (after
    the depth passes; own optimizer step), :meth:`black_white` (called by the densification
    strategy just before densify-and-prune)."""

    def __init__(
        self,
        settings: DtuConfig,
        scene_name: str,
        images: list[Tensor],
        raster: Raster,
        joint: bool = False,
    ) -> None:
        """``images``: the (3, H, W) training targets; the per-scan thresholds come from
        ``scene_name`` (:meth:`DtuBackgroundSettings.for_scene`). ``joint``:
        ``optim.auxiliary_step == 'joint'``, the alpha pass leaves its gradient for the
        photometric step instead of taking its own optimizer step."""
        self.settings = settings
        self.joint = joint
        self.scan = DtuBackgroundSettings.for_scene(scene_name)
        self.raster = raster
        self.masks = [background_mask(img, self.scan) for img in images]
        """(H, W) bool background mask per training view."""
        self.targets: list[tuple[Tensor, SSIMTarget] | None] = [
            (t := blacken_background(img, m), SSIMTarget(t)) if settings.blacken_target else None
            for img, m in zip(images, self.masks, strict=True)
        ]

    def adjust_view(self, view: TrainView) -> TrainView:
        """The view with its mask and, when on, its blackened target."""
        edit = self.targets[view.index]
        if edit is None:
            return dataclasses.replace(view, mask=self.masks[view.index])
        return dataclasses.replace(
            view, image=edit[0], ssim_target=edit[1], mask=self.masks[view.index]
        )

    def step_pre_photometric(self, step: AuxiliaryStep) -> None:
        """The background-alpha pass (real opacities, geometry detached: moves only opacities)
        with its own optimizer step (joint: its gradient left for the photometric step);
        skipped when off or when the view has no background (an empty mask gives no gradient,
        and an Adam step on zero gradients would still move)."""
        mask = self.masks[step.view.index]
        if not self.settings.alpha_loss or not bool(mask.any()):
            return
        g = step.gaussians
        out = self.raster(
            g.means.detach(),
            g.log_scales.detach(),
            g.quats.detach(),
            g.opacity_logits,
            g.means.new_zeros(len(g), 0),
            step.view.camera,
            None,
        )
        loss = background_alpha_loss(out.alpha, mask)
        finish_auxiliary_pass(step, loss, "the DTU background-alpha loss", self.joint)
        step.timer.tick("dtu_alpha")

    def densify_rule(
        self, iteration: int, colors: Callable[[Gaussians], Tensor]
    ) -> Callable[[Gaussians], None] | None:
        """The black/white rule for this iteration's densification step (None when
        ``dtu.black_white`` is off); ``colors`` gives the Gaussians' colours seen from this
        iteration's camera."""
        if not self.settings.black_white:
            return None

        def rule(g: Gaussians) -> None:
            with torch.no_grad():
                self.black_white(iteration, g, colors(g))

        return rule

    def black_white(self, iteration: int, gaussians: Gaussians, colors: Tensor) -> None:
        """Apply :func:`black_white_rule` for ``colors`` (N, 3), the Gaussians' colours seen
        from this iteration's camera: scale the gradient accumulators, reset opacities."""
        adj = black_white_rule(colors, iteration, self.scan)
        g = gaussians
        g.grad_accum *= adj.grad_scale.to(g.grad_accum)
        if bool(adj.reset.any()):
            with torch.no_grad():
                g.opacity_logits[adj.reset] = adj.reset_logit
