"""The initial Gaussians' centres (and colours where the init has them), by ``init.method``.

``random`` (the reference: uniform in the init box), ``dense`` (confident metric depth of the
training views, back-projected; ``dense_init.py``) and ``sparse`` (the points of the camera
estimation; ``engine/sfm/points.py``). The last two fall back to ``random`` and say why.
``auto`` is ``dense`` when the training cameras face forward and ``random`` when they look
inward: the plane sweep behind ``dense`` is confident on most pixels of a forward-facing
capture (overlapping frusta, small rotation) and on few, clustered ones of an orbit, where
the back-projected cloud lost to the random box (docs/experiments/2026-11-25-dense-init-llff.md).
``init.add_matched`` appends the run's matched points (``matched_points.py``) to whichever
start was made.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.datasets.common import camera_layout
from sparsesplat.engine.errors import PriorError, SceneError
from sparsesplat.engine.scene import Scene
from sparsesplat.engine.sfm.points import sparse_initial_points
from sparsesplat.engine.train.config import InitConfig
from sparsesplat.engine.train.init.dense_init import dense_points_from_priors, init_priors
from sparsesplat.engine.train.init.matched_points import RunMatches
from sparsesplat.engine.train.init.random_init import initial_point_count

log = logging.getLogger(__name__)


def with_matched(
    cfg: InitConfig,
    start: tuple[Tensor, Tensor | None, str | None],
    matched: RunMatches | None,
) -> tuple[Tensor, Tensor | None, str | None]:
    """``start`` (points, colours, note as :func:`initial_points` returns them) with the run's
    matched points appended when ``cfg.add_matched`` (rows without a colour of their own, from
    the random box, get grey); unchanged otherwise or when there is none."""
    points, colours, note = start
    if not cfg.add_matched or matched is None or matched.empty:
        return start
    extra = torch.from_numpy(matched.points).to(points)
    extra_colours = torch.from_numpy(matched.colours).to(points)
    if colours is None:
        colours = torch.full_like(points, 0.5)
    note = f"{note or 'random'}; + {len(extra)} matched points"
    return torch.cat([points, extra]), torch.cat([colours, extra_colours]), note


def initial_points(
    cfg: InitConfig,
    scene: Scene,
    box: tuple[Tensor, Tensor],
    cameras: list[Camera],
    depth: list[Any] | None,
    prior_cache: Path | None,
    generator: torch.Generator,
) -> tuple[Tensor, Tensor | None, str | None]:
    """(points (N, 3), colours (N, 3) or None, a note on how they were made or None for the
    plain random box). ``depth``: metric priors for ``dense`` (None: a plane sweep is computed,
    cached under ``prior_cache``)."""
    lo, hi = box
    if cfg.points is not None:
        n = cfg.points
    else:
        n = initial_point_count(cfg, lo, hi, [c.center.cpu() for c in cameras])
    note, method = None, cfg.method
    if method == "auto":
        layout = camera_layout(cameras)
        method = "dense" if layout.forward_facing else "random"
        note = f"random: training cameras {layout.describe()}" if method == "random" else None
    if method == "sparse":
        try:
            points, colours = sparse_initial_points(scene.sparse_points, n, generator)
            return points, colours, f"sparse: {len(points)} points"
        except SceneError as exc:
            note = f"random: sparse init failed ({exc})"
            log.warning("init='sparse' fell back to a random box: %s", exc)
    if method == "dense":
        try:
            drawn = dense_points_from_priors(
                [v.image for v in scene.train],
                [v.camera for v in scene.train],
                init_priors(scene, depth, prior_cache),
                target=cfg.dense_points or n,
                generator=generator,
                min_confidence=cfg.dense_min_confidence,
                min_points=cfg.dense_min_points,
            )
            described = drawn.describe(cfg.dense_min_confidence)
            if drawn.cut < cfg.dense_min_confidence:
                log.warning("init='dense': %s", described)
            return drawn.points, drawn.colours, described
        except PriorError as exc:
            note = f"random: dense init failed ({exc})"
            log.warning("init='dense' fell back to a random box: %s", exc)
    return lo + torch.rand(n, 3, generator=generator) * (hi - lo), None, note
