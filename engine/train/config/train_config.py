"""The training configuration: a typed, nested dataclass with the run's own fields and one
section per part of the trainer (``sections.py``; the ``raster`` section is the model's).

Presets are data (``presets.py``); values, overrides and stored configs are read by
``overrides.py`` (dotted names, old flat names), their types checked by ``values.py``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Literal

from sparsesplat.engine.errors import ConfigError
from sparsesplat.engine.model.raster import RasterConfig
from sparsesplat.engine.train.config.regularizer_sections import (
    BinocularConfig,
    ConsistencyConfig,
    CorrespondenceConfig,
    DropoutConfig,
    DtuConfig,
    MatchesConfig,
    NearPruneConfig,
    PseudoConfig,
)
from sparsesplat.engine.train.config.sections import (
    ColorConfig,
    DensifyConfig,
    DepthConfig,
    GuardConfig,
    InitConfig,
    OptimConfig,
    PhotometricConfig,
    PoseConfig,
    RecordConfig,
)
from sparsesplat.engine.train.config.values import check_types

REFERENCE_ITERATIONS = 6000
"""The run length every preset's schedule is written for (the reference code trains each
format for 6000 iterations)."""


@dataclass
class TrainConfig:
    """Everything one training run needs besides the scene and the depth priors: the run's
    own fields, then one section per part of the trainer."""

    preset: str = "default"
    """Name of the preset this config was built from (informative)."""
    seed: int = 0
    """Seed of the trainer's private torch.Generator (init, view order, patches, splits)."""
    iterations: int = REFERENCE_ITERATIONS
    """Number of training iterations (the schedule's length). The defaults are the reference's
    6000-iteration LLFF schedule; ``presets.preset`` compresses each preset's schedule to its
    default run length or to the length asked for. Under a time budget, the nominal length
    the schedule is written for (the run ends at the deadline instead)."""
    time_budget_s: float | None = None
    """Train until this many training seconds are spent (a deadline) instead of for
    ``iterations``; the schedule of ``iterations`` nominal iterations then follows the elapsed
    fraction of the budget (``ScheduleClock``). None: a fixed iteration count."""
    time_limit_s: float | None = None
    """At most this many training seconds: the run ends after ``iterations`` or at the limit,
    whichever comes first. Where the limit would come first, the schedule follows the elapsed
    fraction of the limit from the moment that is further along than the iteration count, so
    the LR decay and densification window still complete (``ScheduleClock``); the
    result then says so (``time_limited``). A preset's default run length carries
    ``presets.DEFAULT_TIME_LIMIT_S``; a length asked for, or a time budget, carries none.
    None: no limit."""
    threads: int | None = None
    """torch CPU threads to use; None leaves the process setting alone."""
    background: tuple[float, float, float] | Literal["mean"] | None = None
    """Background RGB in [0, 1] for targets and renders alike: images with alpha are
    composited on it and the renderer blends onto it. ``"mean"``: the training photos' mean
    colour, so that the model cannot darken a pixel by leaving it transparent (no preset sets
    it: docs/experiments/2026-11-30-mean-background.md). None uses the scene's (white for
    images with alpha, the object-capture convention; black for LLFF/DTU/instant-ngp photos).
    On the command line ``--set background=white`` (or black, gray, mean, or [r, g, b]) works
    too."""
    init: InitConfig = field(default_factory=InitConfig)
    """The initial Gaussians."""
    color: ColorConfig = field(default_factory=ColorConfig)
    """The colour model."""
    optim: OptimConfig = field(default_factory=OptimConfig)
    """Learning rates and optimizer steps."""
    photometric: PhotometricConfig = field(default_factory=PhotometricConfig)
    """The photometric loss and its regularizers."""
    depth: DepthConfig = field(default_factory=DepthConfig)
    """Depth prior and depth passes."""
    densify: DensifyConfig = field(default_factory=DensifyConfig)
    """Densification."""
    record: RecordConfig = field(default_factory=RecordConfig)
    """Evaluation, checkpoints, exports."""
    guard: GuardConfig = field(default_factory=GuardConfig)
    """Divergence checks."""
    dropout: DropoutConfig = field(default_factory=DropoutConfig)
    """DropGaussian."""
    dtu: DtuConfig = field(default_factory=DtuConfig)
    """DTU background handling."""
    consistency: ConsistencyConfig = field(default_factory=ConsistencyConfig)
    """The warp-consistency term."""
    binocular: BinocularConfig = field(default_factory=BinocularConfig)
    """Binocular self-consistency with a virtual shifted camera."""
    pseudo: PseudoConfig = field(default_factory=PseudoConfig)
    """Depth at pseudo views between the training cameras."""
    near_prune: NearPruneConfig = field(default_factory=NearPruneConfig)
    """Near-plane pruning."""
    matches: MatchesConfig = field(default_factory=MatchesConfig)
    """The learned matches between the training photos (used by ``init.add_matched`` and
    ``correspondence``)."""
    correspondence: CorrespondenceConfig = field(default_factory=CorrespondenceConfig)
    """The matched-depth term."""
    poses: PoseConfig = field(default_factory=PoseConfig)
    """Refinement of the training cameras."""
    raster: RasterConfig = field(default_factory=RasterConfig)
    """The rasterizer."""
    extra: dict[str, Any] = field(default_factory=dict)
    """Free-form notes carried into checkpoints and metrics (never read by the trainer)."""

    def validate(self) -> TrainConfig:
        """Raise :class:`ConfigError` naming the first invalid field; return self."""
        if self.iterations < 1:
            raise ConfigError(f"iterations must be >= 1, got {self.iterations}")
        check_types(self)
        budget = self.time_budget_s
        if budget is not None and not (math.isfinite(budget) and budget > 0):
            raise ConfigError(f"time_budget_s must be a positive number of seconds, got {budget}")
        limit = self.time_limit_s
        if limit is not None and not (math.isfinite(limit) and limit > 0):
            raise ConfigError(f"time_limit_s must be a positive number of seconds, got {limit}")
        if budget is not None and limit is not None:
            raise ConfigError(
                "give either a time budget (train until it is spent) or a time limit (at most "
                "that long), not both"
            )
        for item in dataclasses.fields(self):
            section = getattr(self, item.name)
            if dataclasses.is_dataclass(section) and hasattr(section, "validate"):
                section.validate()
        bg = self.background
        rgb = isinstance(bg, tuple) and len(bg) == 3 and all(0.0 <= c <= 1.0 for c in bg)
        if bg is not None and bg != "mean" and not rgb:
            raise ConfigError(
                f"background must be 3 values in [0, 1] (or white, black, gray, mean), got {bg!r}"
            )
        return self

    @property
    def uses_depth(self) -> bool:
        """Whether any depth pass runs (a prior is needed)."""
        return self.depth.used

    @property
    def uses_matches(self) -> bool:
        """Whether the run matches its training photos (the init or a term uses them)."""
        return self.init.add_matched or self.correspondence.enabled

    def with_iterations(self, iterations: int) -> TrainConfig:
        """A copy that trains ``iterations`` iterations on the same schedule, compressed.

        Shortening scales every iteration-counted field (:data:`SCHEDULE_FIELDS`) by the same
        factor, so a short run still densifies, decays its position learning rate and switches
        its depth terms on at the same fractions of the run. ``densify.interval`` is kept: its
        gradient statistics need ~100 iterations to settle. A longer run keeps the schedule;
        the extra iterations refine at the final learning rate, as the reference does.
        """
        if iterations < 1:
            raise ConfigError(f"iterations must be >= 1, got {iterations}")
        factor = min(1.0, iterations / self.iterations)
        out = dataclasses.replace(self, iterations=iterations)
        if factor < 1.0:
            changes: dict[str, dict[str, Any]] = {}
            for path in SCHEDULE_FIELDS:
                section, name = path.split(".")
                value = getattr(getattr(self, section), name)
                # A start of 0 becomes 1, as in every compressed run measured so far (a hard
                # depth pass one iteration earlier moved juicebox_table by 0.75 dB).
                if isinstance(value, int) and not isinstance(value, bool):
                    changes.setdefault(section, {})[name] = max(1, round(value * factor))
            clean = self.densify.clean_iterations
            changes.setdefault("densify", {})["clean_iterations"] = tuple(
                sorted({max(1, round(i * factor)) for i in clean})
            )
            out = dataclasses.replace(
                out,
                **{s: dataclasses.replace(getattr(self, s), **c) for s, c in changes.items()},
            )
        return out.validate()

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON nested dict of every field (sections as dicts)."""
        return dataclasses.asdict(self)


SCHEDULE_FIELDS = (
    "optim.lr_means_start",
    "optim.lr_means_steps",
    "densify.start",
    "densify.until",
    "depth.hard_start",
    "depth.soft_start",
    "depth.until",
    "depth.smooth_start",
    "color.sh_degree_interval",
    "color.view_degree_interval",
    "densify.opacity_reset_interval",
    "consistency.start",
    "binocular.start",
    "binocular.until",
    "pseudo.start",
    "pseudo.until",
    "near_prune.start",
    "correspondence.start",
    "correspondence.until",
)
"""Fields counted in iterations, scaled by :meth:`TrainConfig.with_iterations` (with
``densify.clean_iterations``)."""
