"""Random Gaussian dropout with opacity compensation (DropGaussian, Park et al., CVPR 2025).

During training each Gaussian is dropped from the photometric render with probability ``r``
(an independent Bernoulli draw per Gaussian, as ``torch.nn.Dropout`` on a vector of ones does
in the authors' snippet), and every kept Gaussian's activated opacity is multiplied by
``1 / (1 - r)`` so that the expected opacity mass reaching a pixel is unchanged. The paper grows
the rate over training, ``r_t = gamma * t / T``; the authors' published snippet uses a fixed
``0.1``, which is the default maximum here. Evaluation, export and the depth passes never drop.

Where it runs in an iteration (the photometric pass only, dngaussian-method.md §1.6 step 3)::

    rate = schedule.rate(iteration, total_iterations)
    drop = draw_dropout(len(gaussians), rate, generator, device)
    colors = color_model.colors(gaussians, cam.center, drop.index)  # kept rows only
    out = rasterize(drop.select(means), drop.select(log_scales), drop.select(quats),
                    drop.opacity_logits(opacity_logits), colors, cam, bg)
    loss(out.image, gt).backward()
    grad2d = drop.scatter(out.means2d.grad)     # (N, 2), zero for dropped Gaussians
    visible = drop.scatter(out.radii) > 0        # dropped Gaussians count as not visible

Rendering only the kept rows (instead of zeroing dropped opacities) is the same image and
saves ``r`` of the rasterizer's work; colouring only the kept rows saves ``r`` of the colour
field's.

Deviation, forced by the rasterizer taking opacity *logits*: a compensated opacity cannot
exceed 1, while the reference multiplies the activated opacity and lets the rasterizer clamp
``o G`` at 0.99 per pixel. Here the compensated opacity is capped at :data:`OPACITY_CEILING`
(the rasterizer's own alpha cap), with the gradient of the uncapped value passed straight
through, so a capped Gaussian still receives the gradient the reference gives it on the pixels
where its alpha is below the cap. DropoutGS (Xu et al., CVPR 2025) drops the same way but adds
a consistency loss between the full and the dropped render; that loss is not implemented here.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from sparsesplat.engine.raster import RasterOutput
from sparsesplat.engine.train.config import ConfigError, DropoutConfig
from sparsesplat.engine.train.loop.schedule import ScheduleClock

OPACITY_CEILING = 0.999
"""Largest compensated opacity handed to the rasterizer (its per-pixel alpha cap)."""


@dataclass(frozen=True)
class DropoutSchedule:
    """The drop rate over training: ``max_rate * t / T`` (progressive) or ``max_rate``."""

    max_rate: float = 0.1
    """``gamma``: the rate reached at the last iteration (progressive) or used throughout."""
    progressive: bool = True
    """Grow the rate linearly from 0 (the paper's schedule) instead of a constant rate."""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.max_rate) and 0.0 <= self.max_rate < 1.0):
            raise ConfigError(f"dropout max_rate must be in [0, 1), got {self.max_rate}")

    def rate(self, iteration: float, total: int) -> float:
        """Drop rate for 1-based ``iteration`` of ``total``; 0 outside [1, total]."""
        if total < 1:
            raise ConfigError(f"dropout schedule: total iterations must be >= 1, got {total}")
        if iteration < 1 or iteration > total:
            return 0.0
        if not self.progressive:
            return self.max_rate
        return self.max_rate * iteration / total


def compensated_logits(
    opacity_logits: Tensor, rate: float, ceiling: float = OPACITY_CEILING
) -> Tensor:
    """Logits of ``min(sigmoid(x) / (1 - rate), ceiling)`` for the opacity logits ``x``.

    Computed in log space (``log sigmoid(x) - log(1 - rate)``), so logits far below 0 keep full
    relative precision. Where the cap binds, the value is ``logit(ceiling)`` and the gradient
    w.r.t. ``x`` is that of the uncapped opacity (straight-through, see the module docstring);
    everywhere it is finite. ``rate == 0`` returns ``opacity_logits`` itself."""
    if not (math.isfinite(rate) and 0.0 <= rate < 1.0):
        raise ConfigError(f"dropout rate must be in [0, 1), got {rate}")
    if not 0.0 < ceiling < 1.0:
        raise ConfigError(f"opacity ceiling must be in (0, 1), got {ceiling}")
    if rate == 0.0:
        return opacity_logits
    log_o = F.logsigmoid(opacity_logits) - math.log1p(-rate)
    capped = log_o >= math.log(ceiling)
    # Uncapped: logit(o) = log o - log(1 - o); o is clamped below the cap so that the branch
    # torch.where discards never sees 1 - o <= 0 (a NaN there would poison the gradient).
    o = torch.exp(log_o).clamp(max=ceiling)
    free = log_o - torch.log1p(-o)
    # Capped: value logit(ceiling), derivative d/dx [o_uncapped] / (c (1 - c)) = the chain rule
    # through logit at the cap applied to the uncapped opacity's derivative.
    c = ceiling
    surrogate = torch.sigmoid(opacity_logits) / ((1.0 - rate) * c * (1.0 - c))
    pinned = math.log(c / (1.0 - c)) + (surrogate - surrogate.detach())
    return torch.where(capped, pinned, free)


@dataclass(frozen=True)
class GaussianDropout:
    """One iteration's draw: which Gaussians the photometric render keeps, and at what rate."""

    keep: Tensor
    """(N,) bool, True for the Gaussians that are rendered."""
    rate: float
    """The drop probability the draw used (the compensation is ``1 / (1 - rate)``)."""

    @functools.cached_property
    def index(self) -> Tensor:
        """(K,) int64 positions of the kept Gaussians, ascending (found once per draw)."""
        return torch.nonzero(self.keep, as_tuple=False).reshape(-1)

    def select(self, per_gaussian: Tensor) -> Tensor:
        """The kept rows of an (N, ...) per-Gaussian tensor (differentiable)."""
        if per_gaussian.shape[0] != self.keep.shape[0]:
            raise ConfigError(
                f"dropout: tensor has {per_gaussian.shape[0]} rows, the draw {self.keep.shape[0]}"
            )
        # By index, not by mask: a mask finds the kept rows again on every call, and its
        # backward is a masked put several times slower than index_select's index_add.
        return per_gaussian.index_select(0, self.index)

    def opacity_logits(self, opacity_logits: Tensor, ceiling: float = OPACITY_CEILING) -> Tensor:
        """(K,) compensated opacity logits of the kept Gaussians (:func:`compensated_logits`)."""
        return compensated_logits(self.select(opacity_logits), self.rate, ceiling)

    def scatter(self, kept_values: Tensor, fill: float = 0.0) -> Tensor:
        """Put (K, ...) values of the kept Gaussians back at their (N, ...) rows; dropped rows
        get ``fill`` (use for ``radii`` and the screen-space gradient densification reads)."""
        n = self.keep.shape[0]
        out = kept_values.new_full((n, *kept_values.shape[1:]), fill)
        return out.index_copy_(0, self.index, kept_values)


def draw_dropout(
    n: int, rate: float, generator: torch.Generator, device: torch.device | str = "cpu"
) -> GaussianDropout:
    """Drop each of ``n`` Gaussians independently with probability ``rate``.

    The draw uses ``generator`` (a CPU generator, the trainer's) so runs replay; the mask is
    then moved to ``device``. ``rate == 0`` keeps everything without consuming random numbers.
    """
    if n < 0:
        raise ConfigError(f"dropout: Gaussian count must be >= 0, got {n}")
    if not (math.isfinite(rate) and 0.0 <= rate < 1.0):
        raise ConfigError(f"dropout rate must be in [0, 1), got {rate}")
    if rate == 0.0:
        keep = torch.ones(n, dtype=torch.bool)
    else:
        keep = torch.rand(n, generator=generator) >= rate
    return GaussianDropout(keep.to(device), rate)


class PhotometricDropout:
    """The trainer's dropout part (hook ``photometric_inputs``): one draw per iteration, from
    the run's generator (checkpointed with the run, so resumed runs replay the same draws).
    No state of its own."""

    def __init__(
        self, settings: DropoutConfig, generator: torch.Generator, clock: ScheduleClock
    ) -> None:
        """``generator``: the run's CPU generator; ``clock``: the run's schedule position
        (the progressive rate follows it over ``clock.total``)."""
        self.settings = settings
        self.schedule = DropoutSchedule(settings.rate, settings.progressive)
        """The rate over training."""
        self.generator = generator
        self.clock = clock

    def draw(self, iteration: int, n: int, device: torch.device | str) -> GaussianDropout | None:
        """This iteration's draw over ``n`` Gaussians; None when the rate is 0 (nothing drawn)
        or when the draw keeps no Gaussian (the render then uses every Gaussian, uncompensated,
        rather than an empty image)."""
        rate = self.schedule.rate(self.clock.position(iteration), self.clock.total)
        if rate == 0.0:
            return None
        drop = draw_dropout(n, rate, self.generator, device)
        if not bool(drop.keep.any()):
            return None
        return drop


def scatter_output(drop: GaussianDropout, out: RasterOutput) -> RasterOutput:
    """``out`` (a render of the kept rows, after its backward) with ``radii`` and ``means2d``
    (and its ``.grad``) back on all N rows: dropped Gaussians get radius 0 (not visible) and a
    zero screen gradient, so the densification statistics stay row-aligned with the model."""
    means2d = drop.scatter(out.means2d.detach())
    if out.means2d.grad is not None:
        means2d.grad = drop.scatter(out.means2d.grad)
    return dataclasses.replace(out, radii=drop.scatter(out.radii), means2d=means2d)
