"""Exact two- and three-view geometry for the matched start: cameras on an arc looking at a
cube of points, and the MatchSet their exact projections make (no matcher, no photos)."""

from __future__ import annotations

import math

import numpy as np

from sparsesplat.engine.match.geometry import PinholeArrays, project
from sparsesplat.engine.match.result import MatchSet
from sparsesplat.engine.match.settings import MatchSettings
from tests.engine.datasets.synthetic import look_at_c2w

WIDTH, HEIGHT = 640, 480
FOCAL = 500.0
RADIUS = 4.0


def look_at(centre: np.ndarray, target: np.ndarray) -> np.ndarray:
    """World-to-camera (OpenCV axes) of a camera at ``centre`` looking at ``target``, up -y:
    the rigid inverse of the datasets' helper's camera-to-world."""
    rot = look_at_c2w(centre, target)[:3, :3].T
    w2c = np.eye(4)
    w2c[:3, :3] = rot
    w2c[:3, 3] = -rot @ centre
    return w2c


def arc_cameras(count: int, step_deg: float) -> list[PinholeArrays]:
    """``count`` cameras on a horizontal circle of radius :data:`RADIUS` around the origin,
    ``step_deg`` apart, all looking at the origin."""
    k = np.array([[FOCAL, 0, WIDTH / 2], [0, FOCAL, HEIGHT / 2], [0, 0, 1.0]])
    cams = []
    for i in range(count):
        a = math.radians(step_deg * (i - (count - 1) / 2))
        centre = np.array([RADIUS * math.sin(a), 0.3, -RADIUS * math.cos(a)])
        cams.append(PinholeArrays(k, look_at(centre, np.zeros(3))))
    return cams


def cube_points(rng: np.random.Generator, count: int, half: float = 1.0) -> np.ndarray:
    """(count, 3) float64 points uniform in the cube [-half, half]^3."""
    return rng.uniform(-half, half, size=(count, 3))


def exact_matches(
    points: np.ndarray, cams: list[PinholeArrays], rng: np.random.Generator, noise_px: float = 0
) -> MatchSet:
    """The MatchSet of the points' projections in every camera (each photo's keypoints in a
    random order, plus unmatched distractors), every pair matched; ``noise_px`` adds Gaussian
    pixel noise per observation."""
    keypoints, index = [], []
    for cam in cams:
        uv, _ = project(points, cam)
        uv = uv + rng.normal(0.0, noise_px, uv.shape) if noise_px else uv
        extra = rng.uniform([0, 0], [WIDTH, HEIGHT], size=(7, 2))
        all_uv = np.concatenate([uv, extra])
        order = rng.permutation(len(all_uv))
        keypoints.append(all_uv[order].astype(np.float32))
        where = np.empty(len(all_uv), np.int64)
        where[order] = np.arange(len(all_uv))
        index.append(where[: len(points)])
    matches, scores = {}, {}
    for i in range(len(cams)):
        for j in range(i + 1, len(cams)):
            matches[(i, j)] = np.stack([index[i], index[j]], axis=1).astype(np.int32)
            scores[(i, j)] = np.ones(len(points), np.float32)
    return MatchSet(keypoints, matches, scores, [(WIDTH, HEIGHT)] * len(cams), MatchSettings())


def flat_photos(count: int, colour: tuple[float, float, float]) -> list[np.ndarray]:
    """Photos of one colour (the colour a point gets from them is that colour)."""
    return [np.broadcast_to(np.array(colour, np.float32), (HEIGHT, WIDTH, 3)).copy()] * count
