"""The sections of the training configuration for the loop itself: init, colour, optimizer,
photometric loss, depth, densification, records, guard and pose refinement (the regularizer
parts' sections are in ``regularizer_sections.py``).

Values follow the DNGaussian reference code (dngaussian-method.md §1.5-§1.9); the defaults are
its 6000-iteration LLFF recipe. Each part of the trainer takes its own section (``config.depth``
goes to the depth regulariser, ``config.densify`` to the densification strategy, ...), so a
setting is declared once; :class:`~sparsesplat.engine.train.config.train_config.TrainConfig`
gathers them. The ``raster`` section is the model's (``engine/model/raster.py``): a stored
model renders with it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

from sparsesplat.api.names import ColorModelName, InitName
from sparsesplat.engine.errors import ConfigError, PriorError
from sparsesplat.engine.priors.base import parse_prior_spec

__all__ = [
    "AuxiliaryStepName",
    "Box",
    "ColorConfig",
    "DensifyConfig",
    "DepthConfig",
    "GuardConfig",
    "InitConfig",
    "OptimConfig",
    "PhotometricConfig",
    "PoseConfig",
    "RecordConfig",
]
"""The sections and the names of their values: the package (``config/__init__.py``) re-exports
these as its public surface, so the list lives here, beside the definitions."""

AuxiliaryStepName = Literal["separate", "joint"]
"""How the auxiliary passes (hard depth, soft depth, DTU background alpha) update the model."""

Box = tuple[tuple[float, float, float], tuple[float, float, float]]
"""An axis-aligned box as (lowest corner, highest corner)."""


@dataclass(frozen=True)
class InitConfig:
    """``init``: the initial Gaussians."""

    method: InitName = "random"
    """'random': uniform points in the init box (the reference). 'dense': the training
    pixels whose metric depth is confident, back-projected (``engine/train/init/dense_init.py``);
    the depth is the run's prior when it is metric (plane sweep), else a plane-sweep prior
    computed for the init (cached under ``out_dir/priors``). SH colour takes the pixel colours
    as DC. Falls back to 'random' with a warning (``metrics['init']``) when no pixel is
    confident. 'sparse': the scene's sparse points (``Scene.sparse_points``, from the camera
    estimation of photos uploaded without cameras) with their colours, topped up with jittered
    copies to the point count; falls back to 'random' saying why when the scene has none.
    'auto': 'dense' when the training cameras face forward, 'random' when they look inward
    (``datasets.common.camera_layout``), the choice named in ``metrics['init']``."""
    box: Box | None = None
    """Box for random init; None uses the scene's ``init_box``, else one fitted to the frusta."""
    points: int | None = None
    """Number of random points; None: ``points_density`` x (largest side of the init box
    / median distance from the training cameras to the box centre), clamped to
    [``points_min``, ``points_max``]."""
    points_density: float = 1000.0
    """Automatic point count per "scene length" of the init box's largest side, the scene
    length being the median camera-to-box-centre distance: a ratio of two lengths, so the
    count does not depend on the scene's unit (the reference's 50 points per LLFF unit does).
    1000 gives 1.0-1.7k points on the LLFF-format and instant-ngp scenes of shared/data, about
    what the reference rule gave after its 1000-point floor."""
    points_min: int = 1000
    """Lower bound on the automatic point count."""
    points_max: int = 100_000
    """Upper bound on the automatic point count (CPU budget)."""
    opacity: float = 0.1
    """Initial opacity of every Gaussian."""
    dense_points: int | None = None
    """Number of points drawn for ``method='dense'`` (all confident pixels when fewer); None:
    the random init's count (``points`` or the automatic count)."""
    dense_min_confidence: float = 0.5
    """Smallest prior confidence of a pixel used by ``method='dense'``."""
    dense_min_points: int = 0
    """Floor for ``method='dense'``: when fewer pixels than this (or than the target, if
    smaller) pass ``dense_min_confidence``, the most confident pixels are taken instead, this
    many (pixels of zero confidence never); the run's ``init`` note says how far the cut went
    down. 0: no floor."""
    add_matched: bool = False
    """Add the matched start to the init's points: the learned matches between the training
    photos (``matches``) triangulated with the training cameras, coloured from the photos
    (``engine/match/triangulate.py``). Without the ``match`` extra, or when matching finds
    nothing, the init is left as it is and ``metrics['matches']`` says why."""

    def validate(self) -> None:
        """Raise :class:`ConfigError` naming the first invalid field."""
        if not 0.0 < self.opacity < 1.0:
            raise ConfigError(f"init.opacity must be in (0, 1), got {self.opacity}")
        if self.dense_points is not None and self.dense_points < 1:
            raise ConfigError(f"init.dense_points must be >= 1, got {self.dense_points}")
        if self.dense_min_points < 0:
            raise ConfigError(f"init.dense_min_points must be >= 0, got {self.dense_min_points}")


@dataclass(frozen=True)
class ColorConfig:
    """``color``: the colour model."""

    model: ColorModelName = "neural"
    """'neural' (hash grid + MLPs, DNGaussian) or 'sh' (per-Gaussian SH, 3DGS)."""
    sh_degree: int = 3
    """Maximum SH degree 0..3 for model 'sh' (ignored for 'neural')."""
    sh_degree_interval: int = 1000
    """Iterations between SH degree increases (3DGS schedule)."""
    hash_log2_size: int = 19
    """log2 of the hash table entries per level (reference 19)."""
    hash_finest_resolution: int = 2048
    """Finest grid resolution over the grid cube. Deviation: the reference uses 512 x bound
    (scene-unit dependent); a fixed value keeps results independent of scene scale."""
    view_degree: int = 3
    """Highest SH band of the view direction the neural field's colour head sees (0..3; the
    reference's 3). Lower bands make colour less view-dependent."""
    view_degree_interval: int | None = None
    """Iterations between increases of the neural field's view degree, from 0 up to
    ``view_degree``, as 3DGS grows its SH degree (None: every band from the start, the
    reference's)."""

    def validate(self) -> None:
        """Raise :class:`ConfigError` naming the first invalid field."""
        if not 0 <= self.sh_degree <= 3:
            raise ConfigError(f"color.sh_degree must be 0..3, got {self.sh_degree}")
        if not 0 <= self.view_degree <= 3:
            raise ConfigError(f"color.view_degree must be 0..3, got {self.view_degree}")
        if self.view_degree_interval is not None and self.view_degree_interval < 1:
            raise ConfigError(
                f"color.view_degree_interval must be None or >= 1, got {self.view_degree_interval}"
            )


@dataclass(frozen=True)
class OptimConfig:
    """``optim``: learning rates (Adam) and how the auxiliary passes step."""

    lr_means_init: float = 0.016
    """Initial centre LR, multiplied by the scene extent."""
    lr_means_final: float = 0.00016
    """Final centre LR, multiplied by the scene extent."""
    lr_means_start: int = 500
    """Iteration after which the centre LR starts its log-linear decay."""
    lr_means_steps: int = 5500
    """Length of the centre LR decay in iterations."""
    lr_opacity: float = 0.05
    """Opacity-logit LR."""
    lr_scaling: float = 0.003
    """Log-scale LR."""
    lr_rotation: float = 0.001
    """Quaternion LR."""
    lr_hash_grid: float = 5e-3
    """Hash table LR."""
    lr_mlp: float = 5e-4
    """LR of both MLPs."""
    lr_sh: float = 0.0025
    """SH DC LR (the rest uses lr_sh / 20, as 3DGS)."""
    adam_eps: float = 1e-15
    """Adam epsilon (reference value)."""
    auxiliary_step: AuxiliaryStepName = "separate"
    """'separate' (the reference code): the hard-depth, soft-depth and DTU background-alpha
    passes each take their own step of the run's shared Adam optimizer before the photometric
    step, so the centres get two Adam steps per iteration (and the hard step carries the
    photometric momentum). 'joint' (the paper's single objective L = L_color + R_hard +
    R_soft): their gradients are added to the photometric gradient and the iteration takes
    one step."""

    @property
    def joint(self) -> bool:
        """Whether the auxiliary passes leave their gradients for the photometric step."""
        return self.auxiliary_step == "joint"


@dataclass(frozen=True)
class PhotometricConfig:
    """``photometric``: the photometric loss and DNGaussian's Gaussian-shape regularizers."""

    lambda_dssim: float = 0.2
    """Weight of (1 - SSIM) added to L1."""
    shape_weight: float = 0.002
    """Weight of mean(max s / min s)."""
    scale_weight: float = 0.001
    """Weight of mean(max s²), with s measured in units of the scene extent (deviation: the
    reference uses raw scene units, which makes the penalty depend on the scene's scale)."""
    opacity_weight: float = 0.001
    """Weight of the opacity penalty."""


@dataclass(frozen=True)
class DepthConfig:
    """``depth``: the depth prior and the hard/soft depth passes
    (``regularizers/depth_regularizer.py``)."""

    prior: str = "pydnet"
    """Prior kind to compute ('pydnet', 'plane_sweep', 'onnx:FILE', 'user') or 'none' for no
    depth loss. PyDNet++ is the default because it had the best AVGE of the three on DTU, LLFF
    and Blender scenes (docs/experiments/)."""
    min_agreement: float | None = None
    """Skip the depth passes on the training views whose prior disagrees with the scene's own
    multi-view geometry: the Spearman rank correlation between the prior and a plane-sweep
    depth of the same view (on the sweep's confident pixels) below this. None: every view uses
    its prior. A view with too few confident sweep pixels to judge keeps its prior; when every
    view is skipped the depth part is not built at all (a no-depth run)."""
    hard: bool = True
    """Hard-depth pass (opacity 0.95, gradients to centres only)."""
    soft: bool = True
    """Soft-depth pass (real opacity, gradients to opacities only)."""
    hard_opacity: float = 0.95
    """Constant opacity of the hard-depth pass."""
    hard_start: int = 0
    """Hard depth runs for iterations > this."""
    hard_downscale: int | None = 1
    """Render the hard pass at 1/n of the training image's side, against the prior averaged
    to that size, with the patch sides divided by n (same image fraction): n² fewer pixels
    for a pass that only shapes the centres' depth. 1: the reference (full resolution).
    None: 2 when the training cameras face forward, 1 when they look inward (on the
    LLFF-format orbits 2 lost held-out PSNR; docs/experiments/2026-11-25-dense-init-llff.md)."""
    soft_start: int = 1000
    """Soft depth runs for iterations > this."""
    every: int = 1
    """Run the depth passes every n-th iteration (Blender: 10)."""
    until: int | None = None
    """Stop the depth passes at this iteration (Blender: densify.until); None = never."""
    soft_fused: bool = True
    """Compute the soft-depth term on the photometric render instead of a render of its own:
    the rasterizer routes its gradient to the opacities alone (the same gradient as the
    reference's detached pass) and it joins the photometric step (the paper's summed
    objective). Saves one full render and backward per iteration. Deviation: with DropGaussian
    on, the term sees the photometric render's kept Gaussians. False: the reference's separate
    pass (``optim.auxiliary_step`` deciding its optimizer step)."""
    soft_ema_gate: float | None = None
    """DTU: take a soft step only while the EMA of the hard loss is below this; None = off."""
    patch_min: int = 5
    """Smallest patch side for the depth normalization (inclusive)."""
    patch_max: int = 17
    """Largest patch side (inclusive)."""
    error_tolerance: float = 0.00025
    """Margin of the error-tolerant L2 (residuals below it are ignored)."""
    global_weight: float = 1.0
    """Weight of the global-normalization term."""
    local_weight: float = 0.1
    """Weight of the local-normalization term (paper gamma)."""
    smooth_weight: float = 0.1
    """Weight of the prior-edge-aware depth smoothness (LLFF only in the reference); the
    rendered depth enters in units of the scene extent (scale-free, a deviation)."""
    smooth_start: int = 3000
    """Smoothness applies for iterations > this."""
    empty_background: bool = False
    """On training pixels that show the pure background colour, replace the prior by its
    nearest value: empty space renders depth 0 (depth is not alpha-normalized), so the target
    agrees with it there instead of asking for geometry in the void (reference: Blender sets
    the target to 0 on pure-white pixels)."""

    @property
    def used(self) -> bool:
        """Whether any depth pass runs (a prior is needed)."""
        return self.prior != "none" and (self.hard or self.soft)

    @property
    def monocular(self) -> bool:
        """Whether the prior is a monocular network (``pydnet`` or ``onnx:…``), which parts
        that run it on a render of the model need (``pseudo``)."""
        try:
            return parse_prior_spec(self.prior).monocular
        except PriorError:
            return False  # a setting that does not parse: validate() names the problem

    @property
    def patch_range(self) -> tuple[int, int]:
        """Smallest and largest patch side of the local normalization (inclusive)."""
        return (self.patch_min, self.patch_max)

    def validate(self) -> None:
        """Raise :class:`ConfigError` naming the first invalid field."""
        try:
            parse_prior_spec(self.prior)
        except PriorError as exc:
            raise ConfigError(f"depth.prior: {exc}") from exc
        if not 1 <= self.patch_min <= self.patch_max:
            raise ConfigError(
                f"depth patch range must satisfy 1 <= depth.patch_min <= depth.patch_max, got "
                f"[{self.patch_min}, {self.patch_max}]"
            )
        if not 0.0 < self.hard_opacity < 1.0:
            raise ConfigError(f"depth.hard_opacity must be in (0, 1), got {self.hard_opacity}")
        if self.every < 1:
            raise ConfigError(f"depth.every must be >= 1, got {self.every}")
        if self.hard_downscale is not None and self.hard_downscale < 1:
            raise ConfigError(f"depth.hard_downscale must be >= 1, got {self.hard_downscale}")
        if self.min_agreement is not None and not -1.0 <= self.min_agreement <= 1.0:
            raise ConfigError(
                f"depth.min_agreement must be in [-1, 1] or None, got {self.min_agreement}"
            )


@dataclass(frozen=True)
class DensifyConfig:
    """``densify``: clone/split/prune, clean-views pruning and the opacity reset."""

    start: int = 500
    """Densify for iterations > this ..."""
    until: int = 6000
    """... and < this (gradient statistics and the opacity reset stop here too)."""
    interval: int = 100
    """Densify every n iterations."""
    grad_threshold: float = 0.0013
    """Mean screen-space gradient (NDC units, as the 3DGS rasterizer reports) to densify."""
    percent_dense: float = 0.01
    """Clone if max scale <= this x extent, else split."""
    split_opacity_threshold: float = 0.1
    """Only Gaussians with opacity above this are cloned or split."""
    prune_opacity: float = 0.01
    """Prune Gaussians with opacity below this at each densification."""
    opacity_decay: float = 1.0
    """Multiply every opacity by this after each optimizer step while densification runs
    (schedule positions < ``until``): Gaussians the views do not keep re-asserting fade and
    are pruned, so floaters do not survive (Binocular3DGS uses 0.995). 1 = off."""
    opacity_reset_interval: int | None = None
    """3DGS opacity reset period (Blender SH recipe: 3000); None = never."""
    max_screen_size: float | None = None
    """Prune Gaussians whose screen radius exceeds this many pixels (after the first opacity
    reset); None = off (and no radii are tracked)."""
    max_world_size: float | None = None
    """Prune Gaussians larger than this x extent; None = off."""
    max_gaussians: int | None = 300_000
    """Cap on the number of Gaussians (CPU safety valve, not in the reference)."""
    clean_iterations: tuple[int, ...] = (1,)
    """Iterations at which Gaussians invisible from every training view are pruned."""

    @property
    def active(self) -> bool:
        """Whether the strategy does anything in a run: statistics (and with them
        densification and the opacity reset) need an iteration below ``until``."""
        return self.until > 1 or bool(self.clean_iterations)

    def validate(self) -> None:
        """Raise :class:`ConfigError` naming the first invalid field."""
        if self.interval < 1:
            raise ConfigError(f"densify.interval must be >= 1, got {self.interval}")
        if not (math.isfinite(self.opacity_decay) and 0.0 < self.opacity_decay <= 1.0):
            raise ConfigError(f"densify.opacity_decay must be in (0, 1], got {self.opacity_decay}")


@dataclass(frozen=True)
class RecordConfig:
    """``record``: evaluation, checkpoints, exports and profiling."""

    eval_interval_s: float = 60.0
    """Wall-clock seconds of training between held-out evaluations (0 disables the cadence)."""
    eval_every: int | None = None
    """Also evaluate every n iterations (deterministic cadence, mainly for tests)."""
    eval_max_views: int | None = 4
    """Evaluate at most this many held-out views during training, evenly spaced over the
    held-out list (all of them at the end; None: all every time). Interim evaluations are
    monitoring: on 9 LLFF views with LPIPS each costs ~10 s, 16% of a run at a 60 s cadence."""
    eval_lpips: bool = True
    """Compute LPIPS (and AVGE) when the weights are available."""
    checkpoint_interval_s: float = 600.0
    """Wall-clock seconds between checkpoints (0 disables; one is always written at the end)."""
    export: bool = True
    """Write .ply/.splat exports at the end (when the export module is present)."""
    profile: bool = False
    """Time each stage (depth passes, neural field, losses, optimizer) per iteration."""

    def validate(self) -> None:
        """Raise :class:`ConfigError` naming the first invalid field."""
        if self.eval_max_views is not None and self.eval_max_views < 1:
            raise ConfigError(
                f"record.eval_max_views must be >= 1 or None, got {self.eval_max_views}"
            )


def _default_step_limits() -> dict[str, float]:
    return {"means": 0.25, "log_scales": 0.15, "quats": 0.1, "opacity_logits": 1.0}


@dataclass(frozen=True)
class GuardConfig:
    """``guard``: the divergence checks (``loop/guard.py``)."""

    check_every: int = 10
    """Check every parameter group for non-finite values every n iterations."""
    step_limits: dict[str, float] = field(default_factory=_default_step_limits)
    """Per-group limit on the running mean |update| of one photometric Adam step (means in
    units of the scene extent). Sane runs move ~10x less; a blow-up (e.g. learning rates 100x
    too high) moves more and is stopped with TrainingDiverged naming the group."""


@dataclass(frozen=True)
class PoseConfig:
    """``poses``: refinement of the training cameras during training (``loop/poses.py``), for
    cameras estimated from the photos, whose few tenths of a degree of error blur the model.
    The first training camera keeps its pose (it fixes the frame); each other one learns a
    small rigid correction from the photometric loss."""

    enabled: bool = False
    """Refine the training cameras' poses (off: the part is not built, nothing allocated)."""
    lr: float = 3e-4
    """Adam learning rate of the corrections (radians for the rotation, scene extents for the
    shift), decaying log-linearly to 1 % of it at the end of the run."""
    start: float = 0.1
    """Fraction of the schedule before the corrections train (the first iterations' random
    Gaussians carry no pose information)."""
    max_rotation_deg: float = 5.0
    """A correction larger than this stops the run (the cameras are wrong, not imprecise)."""
    max_translation: float = 0.1
    """Likewise for the shift, in scene extents."""

    def validate(self) -> None:
        """Raise :class:`ConfigError` naming the first invalid field."""
        if not (math.isfinite(self.lr) and self.lr > 0.0):
            raise ConfigError(f"poses.lr must be > 0, got {self.lr}")
        if not (math.isfinite(self.start) and 0.0 <= self.start < 1.0):
            raise ConfigError(f"poses.start must be in [0, 1), got {self.start}")
        if not (math.isfinite(self.max_rotation_deg) and 0.0 < self.max_rotation_deg <= 90.0):
            raise ConfigError(
                f"poses.max_rotation_deg must be in (0, 90], got {self.max_rotation_deg}"
            )
        if not (math.isfinite(self.max_translation) and self.max_translation > 0.0):
            raise ConfigError(f"poses.max_translation must be > 0, got {self.max_translation}")
