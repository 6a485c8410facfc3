"""Run COLMAP (pycolmap) on a folder of photos with one shared pinhole camera."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sparsesplat.engine.sfm.attempts import Attempt
from sparsesplat.engine.sfm.colmap import require_pycolmap
from sparsesplat.engine.sfm.uncertainty import BundleProblem


@dataclass(frozen=True)
class CameraPrior:
    """The shared pinhole camera COLMAP starts from."""

    fx: float
    """Focal length along x in pixels."""
    fy: float
    """Focal length along y in pixels."""
    cx: float
    """Principal point x in pixels."""
    cy: float
    """Principal point y in pixels."""
    fixed: bool
    """True when the user gave the intrinsics: bundle adjustment keeps them."""

    def scaled(self, factor: float) -> CameraPrior:
        """The same camera for photos resized by ``factor`` (pixel units times ``factor``)."""
        f = factor
        return CameraPrior(self.fx * f, self.fy * f, self.cx * f, self.cy * f, self.fixed)


@dataclass
class PairStats:
    """What matching found between two photos."""

    inliers: int
    """Geometrically verified matches."""
    displacement_px: float
    """Median image distance between the verified matches (~0 for copies of one photo)."""


@dataclass
class MatchStats:
    """Features per photo and verified matches per pair (indices in the order given)."""

    keypoints: list[int]
    """SIFT features found in each photo."""
    pairs: dict[tuple[int, int], PairStats] = field(default_factory=dict)
    """(i, j) with i < j -> what matching found; pairs without verified matches are absent."""

    def inliers(self, i: int, j: int) -> int:
        """Verified matches between photos ``i`` and ``j`` (0 when none)."""
        stats = self.pairs.get((min(i, j), max(i, j)))
        return stats.inliers if stats else 0

    def scaled(self, factor: float) -> MatchStats:
        """The same statistics with pixel distances times ``factor`` (counts unchanged)."""
        pairs = {k: PairStats(p.inliers, p.displacement_px * factor) for k, p in self.pairs.items()}
        return MatchStats(list(self.keypoints), pairs)


@dataclass(frozen=True)
class Observed:
    """The observations of a reconstruction's points, one row each."""

    photo: np.ndarray
    """(M,) int: the photo index (in the order given) that made the observation."""
    point: np.ndarray
    """(M,) int: the point observed (row of ``Reconstruction.points``)."""
    pixels: np.ndarray
    """(M, 2) float64: where, in COLMAP's pixels (centres at +0.5)."""


@dataclass
class Reconstruction:
    """A COLMAP model in plain arrays, photos indexed in the order given."""

    world_to_camera: dict[int, np.ndarray]
    """Registered photo index -> (4, 4) float64 world-to-camera, OpenCV axes."""
    intrinsics: tuple[float, float, float, float]
    """The shared camera's (fx, fy, cx, cy) after bundle adjustment."""
    points: np.ndarray
    """(N, 3) float64 triangulated points."""
    colours: np.ndarray
    """(N, 3) float32 RGB in [0, 1]."""
    point_views: list[list[int]]
    """The photo indices observing each point."""
    reprojection_error_px: float
    """Mean reprojection error over all observations."""
    observations: Observed
    """Which photo saw which point where: the bundle adjustment's data."""

    def scaled(self, factor: float) -> Reconstruction:
        """The same solution in pixels times ``factor`` (intrinsics, observations and
        reprojection error; poses and points keep their units)."""
        fx, fy, cx, cy = self.intrinsics
        seen = self.observations
        return dataclasses.replace(
            self,
            intrinsics=(fx * factor, fy * factor, cx * factor, cy * factor),
            reprojection_error_px=self.reprojection_error_px * factor,
            observations=Observed(seen.photo, seen.point, seen.pixels * factor),
        )

    def bundle_problem(self) -> tuple[list[int], BundleProblem]:
        """The placed photos' indices in order, and the solution as a :class:`BundleProblem`
        (its cameras in that order)."""
        placed = sorted(self.world_to_camera)
        row = np.full(max(placed) + 1, -1, dtype=np.int64)
        row[placed] = np.arange(len(placed))
        problem = BundleProblem(
            world_to_camera=np.stack([self.world_to_camera[i] for i in placed]),
            intrinsics=self.intrinsics,
            points=self.points,
            camera_index=row[self.observations.photo],
            point_index=self.observations.point,
            pixels=self.observations.pixels,
        )
        return placed, problem


def run_colmap(
    image_dir: Path,
    names: list[str],
    prior: CameraPrior,
    attempt: Attempt,
    work_dir: Path,
    threads: int,
    seed: int,
) -> tuple[Reconstruction | None, MatchStats]:
    """Extract, match and map ``names`` (files in ``image_dir``) with ``attempt``'s settings;
    the largest model found (None when COLMAP found no initial pair) and the match stats."""
    pycolmap = require_pycolmap()
    pycolmap.set_random_seed(seed)
    work_dir.mkdir(parents=True, exist_ok=True)
    database = work_dir / "database.db"
    database.unlink(missing_ok=True)
    reader = pycolmap.ImageReaderOptions()
    same_focal = abs(prior.fx - prior.fy) < 1e-9 * prior.fx
    reader.camera_model = "SIMPLE_PINHOLE" if same_focal else "PINHOLE"
    params = [prior.fx] if same_focal else [prior.fx, prior.fy]
    reader.camera_params = ",".join(f"{v:.10g}" for v in [*params, prior.cx, prior.cy])
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = threads
    extraction.sift.peak_threshold = attempt.peak_threshold
    extraction.sift.domain_size_pooling = attempt.domain_size_pooling
    extraction.sift.estimate_affine_shape = attempt.affine_shape
    cpu = pycolmap.Device.cpu
    pycolmap.extract_features(
        database, image_dir, names, pycolmap.CameraMode.SINGLE, reader, extraction, cpu
    )
    verification = pycolmap.TwoViewGeometryOptions()
    verification.min_num_inliers = attempt.min_inliers
    verification.ransac.random_seed = seed
    if attempt.matcher is not None:
        from sparsesplat.engine.sfm.learned import import_matches, learned_matches

        found = learned_matches(
            image_dir, names, attempt.matcher, attempt.match_min_side, attempt.match_max_side
        )
        pairs = import_matches(pycolmap, database, names, found, work_dir)
        pycolmap.verify_matches(database, pairs, options=verification)
    else:
        matching = pycolmap.FeatureMatchingOptions()
        matching.num_threads = threads
        matching.guided_matching = attempt.guided_matching
        pycolmap.match_exhaustive(
            database, matching_options=matching, verification_options=verification, device=cpu
        )
    stats = _match_stats(pycolmap, database, names)
    return map_database(database, image_dir, names, prior, attempt, threads, seed), stats


def map_database(
    database: Path,
    image_dir: Path,
    names: list[str],
    prior: CameraPrior,
    attempt: Attempt,
    threads: int,
    seed: int,
) -> Reconstruction | None:
    """COLMAP's incremental mapper on the verified matches of ``database`` (the photos
    ``names`` in ``image_dir``); the largest model, or None when no initial pair was found.
    The model is written next to the database (``sparse_<database stem>``)."""
    pycolmap = require_pycolmap()
    options = _mapper_options(pycolmap, prior, attempt, threads, seed)
    out = database.parent / ("sparse" if database.stem == "database" else f"sparse_{database.stem}")
    out.mkdir(exist_ok=True)
    models = pycolmap.incremental_mapping(database, image_dir, out, options=options)
    if not models:
        return None
    best = max(models.values(), key=lambda r: (r.num_reg_images(), r.num_points3D()))
    return _plain(best, names)


def _mapper_options(
    pycolmap: Any, prior: CameraPrior, attempt: Attempt, threads: int, seed: int
) -> Any:
    options = pycolmap.IncrementalPipelineOptions()
    options.num_threads = threads
    options.random_seed = seed
    options.mapper.random_seed = seed
    options.triangulation.random_seed = seed
    options.multiple_models = False
    options.min_model_size = 2
    options.min_num_matches = attempt.min_inliers
    options.extract_colors = True
    options.mapper.init_min_tri_angle = attempt.init_min_tri_angle_deg
    options.mapper.init_min_num_inliers = attempt.min_inliers
    options.mapper.abs_pose_min_num_inliers = attempt.min_inliers
    options.mapper.abs_pose_min_inlier_ratio = 0.1
    # One shared camera: its focal length is refined by bundle adjustment over all views
    # (unless given), never per view while registering one.
    options.mapper.abs_pose_refine_focal_length = False
    options.mapper.abs_pose_refine_extra_params = False
    options.ba_refine_focal_length = not prior.fixed
    options.ba_refine_principal_point = False
    options.ba_refine_extra_params = False
    # With three photos most points are seen twice: keep two-view tracks.
    options.triangulation.ignore_two_view_tracks = False
    return options


def _match_stats(pycolmap: Any, database: Path, names: list[str]) -> MatchStats:
    db = pycolmap.Database.open(str(database))
    try:
        index = {image.image_id: names.index(image.name) for image in db.read_all_images()}
        keypoints = {i: db.read_keypoints(image_id)[:, :2] for image_id, i in index.items()}
        stats = MatchStats([len(keypoints.get(i, ())) for i in range(len(names))])
        pair_ids, geometries = db.read_two_view_geometries()
        for pair_id, geometry in zip(pair_ids, geometries, strict=True):
            a, b = pycolmap.pair_id_to_image_pair(pair_id)
            i, j = index[a], index[b]
            matches = np.asarray(geometry.inlier_matches).reshape(-1, 2)
            if i > j:
                i, j, matches = j, i, matches[:, ::-1]
            if len(matches) == 0:
                continue
            moved = keypoints[i][matches[:, 0]] - keypoints[j][matches[:, 1]]
            stats.pairs[(i, j)] = PairStats(
                len(matches), float(np.median(np.linalg.norm(moved, axis=1)))
            )
        return stats
    finally:
        db.close()


def _plain(model: Any, names: list[str]) -> Reconstruction:
    poses = {}
    for image in model.images.values():
        if not image.has_pose:
            continue
        w2c = np.eye(4)
        w2c[:3, :] = np.asarray(image.cam_from_world().matrix(), dtype=np.float64)
        poses[names.index(image.name)] = w2c
    camera = next(iter(model.cameras.values()))
    fx, fy, cx, cy = (
        (camera.params[0], camera.params[0], camera.params[1], camera.params[2])
        if len(camera.params) == 3
        else tuple(camera.params[:4])
    )
    image_index = {image_id: names.index(image.name) for image_id, image in model.images.items()}
    points, colours, views = [], [], []
    photo, point_row, pixels = [], [], []
    for row, point in enumerate(model.points3D.values()):
        points.append(np.asarray(point.xyz, dtype=np.float64))
        colours.append(np.asarray(point.color, dtype=np.float32) / 255.0)
        views.append(sorted({image_index[e.image_id] for e in point.track.elements}))
        for e in point.track.elements:
            photo.append(image_index[e.image_id])
            point_row.append(row)
            pixels.append(np.asarray(model.images[e.image_id].points2D[e.point2D_idx].xy))
    return Reconstruction(
        world_to_camera=poses,
        intrinsics=(float(fx), float(fy), float(cx), float(cy)),
        points=np.asarray(points, dtype=np.float64).reshape(-1, 3),
        colours=np.asarray(colours, dtype=np.float32).reshape(-1, 3),
        point_views=views,
        reprojection_error_px=float(model.compute_mean_reprojection_error()),
        observations=Observed(
            photo=np.asarray(photo, dtype=np.int64),
            point=np.asarray(point_row, dtype=np.int64),
            pixels=np.asarray(pixels, dtype=np.float64).reshape(-1, 2),
        ),
    )
