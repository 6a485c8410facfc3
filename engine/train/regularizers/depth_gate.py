"""Which training views keep their depth prior: those that agree with the scene's own geometry.

A monocular prior can be wrong in ways no normalisation repairs: on the shared beer_can scene
the bundled PyDNet++ depth ranks pixels *against* the multi-view plane-sweep depth in two of
three views (Spearman -0.33 and -0.25), and training with it loses to training without depth.
The gate measures, per training view, the Spearman rank correlation between the run's prior and
a plane-sweep depth computed from the training views themselves (on the sweep's confident
pixels; ``engine/priors/compare.py``), and the depth passes skip the views below
``depth_min_agreement``. Rank correlation fits because a monocular prior is only known up to a
monotone map. A view without enough confident sweep pixels to judge keeps its prior.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from sparsesplat.engine.priors.base import PriorDepth
from sparsesplat.engine.priors.compare import prior_agreement
from sparsesplat.engine.scene import Scene

log = logging.getLogger(__name__)


def as_prior(value: Any) -> PriorDepth:
    """A PriorDepth as it is, or an (H, W) depth tensor as a fully confident non-metric one."""
    if isinstance(value, PriorDepth):
        return value
    depth = torch.as_tensor(value, dtype=torch.float32)
    return PriorDepth(depth, torch.ones_like(depth), metric=False)


def agreeing_views(
    scene: Scene,
    priors: Sequence[Any],
    threshold: float,
    cache_dir: Path | None = None,
) -> tuple[set[int], list[float]]:
    """(positions of the training views whose prior agrees with the plane sweep at
    ``threshold`` or better, or cannot be judged; the per-view Spearman rho, NaN where it
    cannot be judged). The plane sweep is read from / written to ``cache_dir`` when given."""
    wrapped = [as_prior(p) for p in priors]
    if all(p.kind == "plane_sweep" for p in wrapped):
        return set(range(len(wrapped))), [1.0] * len(wrapped)  # the reference itself
    from sparsesplat.engine.priors import compute_priors

    reference = compute_priors(scene, "plane_sweep", cache_dir=cache_dir)
    rhos = [prior_agreement(p, r)[0] for p, r in zip(wrapped, reference, strict=True)]
    keep = {i for i, rho in enumerate(rhos) if not rho < threshold}  # NaN: no evidence
    if len(keep) < len(rhos):
        log.info(
            "depth prior skipped on %d of %d views (agreement %s < %g)",
            len(rhos) - len(keep), len(rhos), ", ".join(f"{r:.2f}" for r in rhos), threshold,
        )  # fmt: skip
    return keep, rhos
