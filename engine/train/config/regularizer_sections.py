"""The sections of the training configuration for the switchable regularizer parts:
DropGaussian, DTU's background pieces, warp consistency, binocular self-consistency, learned
matches and the correspondence term, near-camera pruning. Each part of the trainer takes its
own section, so a setting is declared once; ``TrainConfig`` (``train_config.py``) gathers them
with the loop's sections (``sections.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from sparsesplat.engine.errors import ConfigError

__all__ = [
    "BinocularConfig",
    "ConsistencyConfig",
    "ConsistencyPartnersName",
    "CorrespondenceConfig",
    "DropoutConfig",
    "DtuConfig",
    "MatcherName",
    "MatchesConfig",
    "NearPruneConfig",
    "PartnerDepthName",
    "PseudoConfig",
]
"""The sections and the names of their values, re-exported by the package
(``config/__init__.py``)."""

ConsistencyPartnersName = Literal["nearest", "all"]
"""Which training views the warp-consistency term warps into the current one."""
PartnerDepthName = Literal["render", "last"]
"""Where the warp-consistency term's occlusion check takes the partner view's depth from."""


@dataclass(frozen=True)
class DropoutConfig:
    """``dropout``: DropGaussian (``regularizers/dropout.py``), on in the ``llff`` and
    ``default`` presets."""

    enabled: bool = False
    """Drop each Gaussian from the photometric render with probability ``rate``, compensating
    the kept opacities by ``1 / (1 - rate)``. Evaluation, export and the depth passes render
    every Gaussian."""
    rate: float = 0.1
    """The drop rate in [0, 1) reached at the last iteration (progressive) or used throughout."""
    progressive: bool = True
    """Grow the rate linearly from 0 to ``rate`` over the run (the paper) instead of a
    constant rate (the authors' snippet)."""

    def validate(self) -> None:
        """Raise :class:`ConfigError` naming the first invalid field."""
        if not (math.isfinite(self.rate) and 0.0 <= self.rate < 1.0):
            raise ConfigError(f"dropout.rate must be in [0, 1), got {self.rate}")


@dataclass(frozen=True)
class DtuConfig:
    """``dtu``: the DTU black-background handling of the reference
    (``regularizers/dtu_background.py``): a per-view dark-background mask and the pieces below;
    thresholds per scan from the scene name."""

    enabled: bool = False
    """Build the part (the switches below apply only then)."""
    blacken_target: bool = True
    """Set the masked target pixels to black in the photometric loss."""
    depth_fill: bool = True
    """Fill the masked pixels of rendered and prior depth with their foreground means in the
    hard and soft depth passes."""
    alpha_loss: bool = True
    """A pass of its own (after the soft-depth pass) pushing the rendered alpha on the masked
    pixels to 0; moves only opacities."""
    black_white: bool = True
    """The near-black / near-white Gaussian rule at each densification."""


@dataclass(frozen=True)
class ConsistencyConfig:
    """``consistency``: the warp-consistency term (``regularizers/consistency.py``), added to the
    photometric loss: the partner training views warped into the current one through the
    rendered depth."""

    weight: float = 0.0
    """Weight of the term; 0 = off (the part is not built)."""
    start: int = 0
    """The term applies for iterations > this."""
    occlusion: bool = True
    """Check occlusion with the partner view's depth (``partner_depth`` says where from)."""
    partner_depth: PartnerDepthName = "render"
    """``render``: a no-gradient depth render of the partner view each time (one more pass per
    partner and iteration); ``last``: the depth of the partner's own latest photometric
    render, kept when that view was trained (free, and a few iterations old: with 3 views each
    is trained every third iteration; with DropGaussian, the render of the Gaussians that
    iteration kept). A partner not trained yet is rendered."""
    partners: ConsistencyPartnersName = "nearest"
    """``nearest``: the one training view whose camera centre is nearest; ``all``: every other
    training view, the term being the mean over them (one more no-gradient depth render and
    warp per extra partner)."""

    @property
    def enabled(self) -> bool:
        """Whether the term is on."""
        return self.weight > 0

    def validate(self) -> None:
        """Raise :class:`ConfigError` naming the first invalid field."""
        if not (math.isfinite(self.weight) and self.weight >= 0.0):
            raise ConfigError(f"consistency.weight must be >= 0, got {self.weight}")


@dataclass(frozen=True)
class BinocularConfig:
    """``binocular``: binocular self-consistency (``regularizers/binocular.py``, after
    Binocular3DGS), added to the photometric loss: the model is rendered from a virtual camera
    shifted along the training camera's own x-axis, that render is warped back into the
    training view through the training view's rendered depth, and compared with the training
    photo. Every pixel of every training view is regularised, not only where another training
    photo overlaps it."""

    weight: float = 0.0
    """Weight of the term; 0 = off (the part is not built)."""
    baseline: float = 0.1
    """The largest shift of the virtual camera, as a fraction of the scene extent (1.1 x the
    largest distance of a training camera from their mean). Each use draws the shift
    uniformly in [-baseline, baseline] x extent (Binocular3DGS: a magnitude uniform in [0, 0.4]
    scene units and a random sign). Binocular3DGS's 0.4 is 0.115 of flower's extent (3.47,
    COLMAP units) and 0.063 of horns' (6.32); the shift seen at depth z is fx x shift / z
    pixels (flower's near bound, 22.6 units at fx 447: 7.9 px for 0.4 units)."""
    start: int = 0
    """The term applies for iterations > this (Binocular3DGS: the last third of its run) ..."""
    until: int | None = None
    """... and < this (None: to the end) ..."""
    every: int = 1
    """... on every this-many-th iteration (each use costs a render and its backward)."""
    min_alpha: float = 0.5
    """Training pixels whose rendered opacity is below this are left out (no depth to warp
    with)."""
    occlusion: bool = True
    """Leave out the training pixels the virtual camera sees behind something else (its own
    rendered depth, detached, disagrees by more than 5 %); Binocular3DGS masks only the
    pixels that leave the virtual frame."""

    @property
    def enabled(self) -> bool:
        """Whether the term is on."""
        return self.weight > 0

    def validate(self) -> None:
        """Raise :class:`ConfigError` naming the first invalid field."""
        if not (math.isfinite(self.weight) and self.weight >= 0.0):
            raise ConfigError(f"binocular.weight must be >= 0, got {self.weight}")
        if not (math.isfinite(self.baseline) and self.baseline >= 0.0):
            raise ConfigError(f"binocular.baseline must be >= 0, got {self.baseline}")
        if self.every < 1:
            raise ConfigError(f"binocular.every must be >= 1, got {self.every}")
        if not 0.0 <= self.min_alpha < 1.0:
            raise ConfigError(f"binocular.min_alpha must be in [0, 1), got {self.min_alpha}")


@dataclass(frozen=True)
class PseudoConfig:
    """``pseudo``: depth at pseudo views (``regularizers/pseudo_views.py``, after FSGS): the
    model rendered between two training cameras, the run's monocular depth network run on
    that render, and DNGaussian's hard depth pass (centres only) against it, with its own
    optimizer step."""

    weight: float = 0.0
    """Weight of the pass's loss; 0 = off (the part is not built, the network not loaded)."""
    start: int = 0
    """The pass runs for iterations > this ..."""
    until: int | None = None
    """... and < this (None: to the end) ..."""
    every: int = 10
    """... on every this-many-th iteration (each use costs a render, a run of the depth
    network and a depth pass with its backward)."""
    t_min: float = 0.25
    """The pseudo camera lies between t_min and 1 - t_min of the way between two training
    cameras ..."""
    shift: float = 0.0
    """... moved in its own image plane (its x and y axes) by a point drawn uniformly in a
    disc of this radius x the scene extent (0: on the line between the two). A forward-facing
    capture's held-out views can lie well off the training cameras' line (flower's
    ``image008`` is 2.5 extents to the side of all three)."""
    mode: Literal["hard", "soft", "full"] = "hard"
    """What the pass moves: 'hard' the centres (opacities held at ``depth.hard_opacity``,
    scales and rotations detached: DNGaussian's hard depth), 'soft' the opacities alone (the
    soft depth), 'full' every Gaussian parameter through the render's own depth (FSGS)."""
    min_alpha: float = 0.0
    """Pixels of the pseudo view the model covers with less opacity than this are left out
    (their rendered and network depths set to the covered pixels' means); 0: every pixel."""

    @property
    def enabled(self) -> bool:
        """Whether the pass is on."""
        return self.weight > 0

    def validate(self) -> None:
        """Raise :class:`ConfigError` naming the first invalid field."""
        if not (math.isfinite(self.weight) and self.weight >= 0.0):
            raise ConfigError(f"pseudo.weight must be >= 0, got {self.weight}")
        if self.every < 1:
            raise ConfigError(f"pseudo.every must be >= 1, got {self.every}")
        if not 0.0 <= self.t_min <= 0.5:
            raise ConfigError(f"pseudo.t_min must be in [0, 0.5], got {self.t_min}")
        if self.mode not in ("hard", "soft", "full"):
            raise ConfigError(f"pseudo.mode must be hard, soft or full, got {self.mode!r}")
        if not (math.isfinite(self.shift) and self.shift >= 0.0):
            raise ConfigError(f"pseudo.shift must be >= 0, got {self.shift}")


MatcherName = Literal["xfeat-lighterglue", "xfeat-semidense", "xfeat-mnn", "disk-lightglue"]
"""The matchers of ``engine/match`` (``engine.match.settings.METHODS``)."""


@dataclass(frozen=True)
class MatchesConfig:
    """``matches``: the learned matches between the training photos and their triangulation
    with the training cameras (``engine/match``), computed once per run, before the first
    iteration, when ``init.add_matched`` or the correspondence term uses them (never
    otherwise). Their seconds count as training seconds (the run's clock starts with them)."""

    method: MatcherName = "xfeat-semidense"
    """The matcher. XFeat's semi-dense matcher triangulated 3x the points of the sparse
    XFeat + LighterGlue on flower and 1.6x on horns, closer to the plane sweep's depths
    (docs/experiments/2026-11-28-matchers.md)."""
    keypoints: int = 0
    """Keypoints (semi-dense: coarse features) per photo; 0: the matcher's default."""
    min_side: int = 800
    """Photos whose longer side is shorter are enlarged to it before matching (0: never)."""
    max_error_px: float = 2.0
    """A triangulated point is kept when it reprojects within this many pixels in every
    photo that sees it."""
    min_angle_deg: float = 1.0
    """... and was seen under at least this triangulation angle (degrees)."""

    def validate(self) -> None:
        """Raise :class:`ConfigError` naming the first invalid field."""
        if self.keypoints != 0 and self.keypoints < 8:
            raise ConfigError(f"matches.keypoints must be 0 or >= 8, got {self.keypoints}")
        if self.min_side < 0:
            raise ConfigError(f"matches.min_side must be >= 0, got {self.min_side}")
        if not (math.isfinite(self.max_error_px) and self.max_error_px > 0):
            raise ConfigError(f"matches.max_error_px must be > 0, got {self.max_error_px}")
        if not (math.isfinite(self.min_angle_deg) and 0 <= self.min_angle_deg < 90):
            raise ConfigError(f"matches.min_angle_deg must be in [0, 90), got {self.min_angle_deg}")


@dataclass(frozen=True)
class CorrespondenceConfig:
    """``correspondence``: the matched-depth term (``regularizers/correspondence.py``), added
    to the photometric loss: at each pixel where a training photo saw a matched, triangulated
    point, the rendered depth must be that point's depth, so matched pixels of two photos land
    on each other through the rendered geometry."""

    weight: float = 0.0
    """Weight of the term; 0 = off (the part is not built)."""
    start: int = 0
    """The term applies for iterations > this ..."""
    until: int | None = None
    """... and < this (None: to the end)."""
    tolerance: float = 0.01
    """Relative depth error below which a pixel costs nothing, at the least."""
    pixel_error: float = 1.0
    """The matches' pixel error (px) behind each point's own dead zone: a point seen under a
    triangulation angle a by a camera of focal length f (px) has a relative depth uncertainty
    of about pixel_error / (f tan a), so its pixels cost nothing within the larger of that and
    ``tolerance``. Forward-facing captures triangulate at a few degrees (5 % at 3 degrees and
    f = 400 px), object orbits at tens (0.4 % at 33 degrees). 0: ``tolerance`` alone."""
    min_alpha: float = 0.5
    """Pixels whose rendered opacity is below this are skipped (no surface to move yet)."""
    max_error: float | None = None
    """Observations whose relative depth error exceeds this are skipped on that iteration: a
    match the render disagrees with by that much is more likely wrong (glass, repeated
    structure) than a surface to pull there. None: every observation counts."""

    @property
    def enabled(self) -> bool:
        """Whether the term is on."""
        return self.weight > 0

    def validate(self) -> None:
        """Raise :class:`ConfigError` naming the first invalid field."""
        if not (math.isfinite(self.weight) and self.weight >= 0.0):
            raise ConfigError(f"correspondence.weight must be >= 0, got {self.weight}")
        if not (math.isfinite(self.tolerance) and self.tolerance >= 0.0):
            raise ConfigError(f"correspondence.tolerance must be >= 0, got {self.tolerance}")
        if not (math.isfinite(self.pixel_error) and self.pixel_error >= 0.0):
            raise ConfigError(f"correspondence.pixel_error must be >= 0, got {self.pixel_error}")
        if not 0.0 <= self.min_alpha < 1.0:
            raise ConfigError(f"correspondence.min_alpha must be in [0, 1), got {self.min_alpha}")
        if self.max_error is not None and not (
            math.isfinite(self.max_error) and self.max_error > 0.0
        ):
            raise ConfigError(f"correspondence.max_error must be > 0 or None, got {self.max_error}")


@dataclass(frozen=True)
class NearPruneConfig:
    """``near_prune``: near-plane pruning of the reference's LLFF runs
    (``regularizers/near_prune.py``): delete Gaussians close to the scene's render path in
    training (the LLFF spiral; other formats: the training cameras) and leave those close to a
    held-out camera out of its evaluation."""

    enabled: bool = False
    """Build the part."""
    radius: float = 0.5
    """The radius as a fraction of the scene's near bound (the reference's absolute 10 units
    would delete most of a scene whose near bound is 1-3 units)."""
    start: int = 2000
    """The training-time prune runs for iterations > this ..."""
    every: int = 25
    """... on every this-many-th iteration."""

    def validate(self) -> None:
        """Raise :class:`ConfigError` naming the first invalid field."""
        if not (math.isfinite(self.radius) and self.radius > 0.0):
            raise ConfigError(f"near_prune.radius must be > 0, got {self.radius}")
        if self.every < 1:
            raise ConfigError(f"near_prune.every must be >= 1, got {self.every}")
