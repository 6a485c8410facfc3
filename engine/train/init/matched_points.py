"""The run's matched points: the training photos matched once (``engine/match``) and
triangulated with the training cameras, for the init (``init.add_matched``) and the
matched-depth term (``correspondence``).

Matching needs the ``match`` extra (XFeat's weights, kornia). A run that asks for matches and
cannot have them (the extra missing, fewer than two training photos, nothing matched) trains
without them: the parts that wanted them are not built, and the reason is logged and stored in
``metrics['matches']``. The matches are cached under the run's prior cache (a content hash of
the photos and the settings), so a resumed or repeated run does not match again.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.errors import EngineError
from sparsesplat.engine.train.config import MatchesConfig

log = logging.getLogger(__name__)


@dataclass
class RunMatches:
    """The matched start of one run (or why there is none)."""

    points: np.ndarray
    """(N, 3) float32 triangulated points (N may be 0)."""
    colours: np.ndarray
    """(N, 3) float32 RGB in [0, 1] sampled from the photos."""
    angles: np.ndarray
    """(N,) float32 triangulation angle of each point (degrees): its depth's precision."""
    point: np.ndarray
    """(O,) int64 point index of each observation."""
    view: np.ndarray
    """(O,) int64 training-view position of each observation."""
    xy: np.ndarray
    """(O, 2) float32 pixel coordinates of each observation (centres at +0.5)."""
    seconds: float
    """Wall seconds this run spent on matching and triangulation (a cache hit: reading)."""
    summary: dict[str, Any]
    """What ``metrics['matches']`` reports: method, points, observations, seconds, cached, or
    ``error`` where matching was asked for and could not run."""

    @property
    def empty(self) -> bool:
        """Whether there is no point to use."""
        return len(self.points) == 0


def _none(seconds: float, method: str, why: str) -> RunMatches:
    log.warning("matches (%s) not used: %s", method, why)
    zeros = np.zeros((0, 3), np.float32)
    return RunMatches(
        zeros,
        zeros.copy(),
        np.zeros(0, np.float32),
        np.zeros(0, np.int64),
        np.zeros(0, np.int64),
        np.zeros((0, 2), np.float32),
        seconds,
        {"method": method, "points": 0, "error": why, "seconds": round(seconds, 3)},
    )


def run_matches(
    cfg: MatchesConfig,
    photos: list[Any],
    cameras: list[Camera],
    cache_dir: Path | None,
) -> RunMatches:
    """Match ``photos`` ((H, W, 3) float RGB in [0, 1], the training views in order), then
    triangulate the matches with ``cameras``; never raises for a matching failure (see the
    module docstring), only for a programming error."""
    start = time.perf_counter()
    if len(photos) < 2:
        return _none(0.0, cfg.method, f"{len(photos)} training photo(s): nothing to match")
    # Imported here: the engine imports without the match extra, and a run that does not
    # use matches never loads the matcher (nor kornia).
    from sparsesplat.engine.match import (
        MatchSettings,
        TriangulationSettings,
        cached_match,
        matched_start,
    )

    try:
        settings = MatchSettings(
            method=cfg.method, max_keypoints=cfg.keypoints, min_side=cfg.min_side
        )
        found, cached = cached_match(photos, settings, cache_dir)
        points = matched_start(
            found,
            cameras,
            photos,
            TriangulationSettings(max_error_px=cfg.max_error_px, min_angle_deg=cfg.min_angle_deg),
        )
    except (EngineError, ImportError) as exc:  # MatchError, MissingMatchDependency
        return _none(time.perf_counter() - start, cfg.method, str(exc))
    seconds = time.perf_counter() - start
    obs = points.observations
    summary: dict[str, Any] = {
        "method": cfg.method,
        "points": len(points.points),
        "observations": len(obs.point),
        "matches": int(sum(len(r) for r in found.matches.values())),
        "seconds": round(seconds, 3),
        "cached": cached,
        "counts": points.counts,
    }
    if not len(points.points):
        summary["error"] = "no match survived triangulation"
        log.warning("matches (%s): no match survived triangulation", cfg.method)
    else:
        log.info(
            "matches (%s): %d points from %d matches in %.1f s%s",
            cfg.method, len(points.points), summary["matches"], seconds,
            " (cached)" if cached else "",
        )  # fmt: skip
    return RunMatches(
        points.points, points.colours, points.angles, obs.point, obs.view, obs.xy, seconds, summary
    )
