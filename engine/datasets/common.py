"""Helpers shared by the format loaders: building views, bounds and the initialization box."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.camera_convert import project, undistort_image
from sparsesplat.engine.errors import SceneError
from sparsesplat.engine.images import composite, read_mask, read_rgba, resize
from sparsesplat.engine.scene import Scene, View

Box = tuple[tuple[float, float, float], tuple[float, float, float]]
WHITE = (1.0, 1.0, 1.0)
BLACK = (0.0, 0.0, 0.0)


MIN_IMAGE_SIDE = 16
"""Smallest image side (pixels) a scene may have: LPIPS-VGG pools four times (16 -> 1) and
SSIM's 11-pixel window and the depth patches need some room; smaller images fail later with
errors that name the wrong cause."""


def check_image_size(width: int, height: int, source: str) -> None:
    """Raise SceneError unless both sides are at least :data:`MIN_IMAGE_SIDE` pixels."""
    if min(width, height) < MIN_IMAGE_SIDE:
        raise SceneError(
            f"{source}: image is {width}x{height} pixels; at least "
            f"{MIN_IMAGE_SIDE}x{MIN_IMAGE_SIDE} is needed (SSIM/LPIPS windows, depth patches)"
        )


def load_view(
    name: str,
    image_path: Path,
    camera: Camera,
    background: Sequence[float],
    downscale: int = 1,
    mask_path: Path | None = None,
    depth: np.ndarray | None = None,
    depth_source: Path | None = None,
    distortion: tuple[float, ...] | None = None,
) -> View:
    """Read one image (composited on ``background``; its alpha kept on the view), check its
    size against the intrinsics, remove lens ``distortion`` (OpenCV k1, k2, p1, p2) if given,
    optionally shrink it by the integer ``downscale`` and attach a mask / user depth."""
    image, alpha = read_rgba(image_path)
    h, w = image.shape[:2]
    if (w, h) != (camera.width, camera.height):
        raise SceneError(
            f"{image_path}: image is {w}x{h} but its camera intrinsics say "
            f"{camera.width}x{camera.height}"
        )
    if distortion is not None and any(distortion):
        image = undistort_image(image, camera.fx, camera.fy, camera.cx, camera.cy, distortion)
        if alpha is not None:
            k = (camera.fx, camera.fy, camera.cx, camera.cy)
            alpha = undistort_image(alpha[..., None], *k, distortion)[..., 0]
    mask = read_mask(mask_path) if mask_path is not None else None
    if mask is not None and mask.shape != (h, w):
        raise SceneError(f"{mask_path}: mask is {mask.shape[1]}x{mask.shape[0]}, image {w}x{h}")
    if depth is not None and depth.shape != (h, w):
        raise SceneError(
            f"{depth_source or name}: depth map is {depth.shape[1]}x{depth.shape[0]}, image {w}x{h}"
        )
    if downscale != 1:
        camera = camera.scaled(1.0 / downscale)
        size = (camera.width, camera.height)
        if alpha is not None:
            # Shrink in premultiplied alpha so transparent pixels' colours do not bleed in.
            premult = resize(image * alpha[..., None], size)
            alpha = resize(alpha, size)
            image = premult / np.maximum(alpha, 1e-6)[..., None]
            image = np.clip(image, 0.0, 1.0).astype(np.float32)
        else:
            image = resize(image, size)
        if mask is not None:
            mask = resize(mask.astype(np.float32), size) >= 0.5
        if depth is not None:
            depth = resize(depth, size, nearest=True)
    check_image_size(camera.width, camera.height, str(image_path))
    image = composite(image, alpha, background)
    return View(
        name=name,
        image=torch.from_numpy(np.ascontiguousarray(image)),
        camera=camera,
        mask=torch.from_numpy(mask) if mask is not None else None,
        depth=torch.from_numpy(depth.astype(np.float32)) if depth is not None else None,
        alpha=torch.from_numpy(np.ascontiguousarray(alpha, dtype=np.float32))
        if alpha is not None
        else None,
    )


def split_scene(
    root: Path,
    fmt: str,
    views: tuple[list[View], list[View], Sequence[float]],
    bounds: tuple[float, float],
    box: Box | None,
    split: tuple[list[int], list[int]],
    **extra: Any,
) -> Scene:
    """The Scene a reader assembles from its parts, named after ``root``.

    ``views``: the (train, test, background) triple (as :func:`on_default_background` returns
    it); ``bounds``: near and far; ``box``: the initial box; ``split``: the (train, test) view
    indices into the source; ``extra``: the other Scene fields a format supplies."""
    train, test, background = views
    return Scene(
        name=root.name,
        format=fmt,
        train=train,
        test=test,
        background=torch.tensor(background),
        near=bounds[0],
        far=bounds[1],
        init_box=box,
        train_indices=split[0],
        test_indices=split[1],
        **extra,
    )


def has_alpha(scene: Scene) -> bool:
    """Whether any view of ``scene`` came from an image with an alpha channel."""
    return any(v.alpha is not None for v in scene.train + scene.test)


PLAIN_BORDER_FRACTION = 0.95
"""A capture without alpha is 'on a plain background' when at least this fraction of the
training images' border pixels are pure white (or pure black), within 4/255."""


def plain_background(views: Sequence[View], border: int = 2) -> tuple[float, ...] | None:
    """WHITE or BLACK when the border pixels of ``views`` are (nearly all) that colour: an
    object photographed on a plain backdrop or rendered on one; else None."""
    if not views:
        return None
    rings = []
    for v in views:
        img = v.image
        b = max(1, min(border, img.shape[0] // 4, img.shape[1] // 4))
        rings += [img[:b].reshape(-1, 3), img[-b:].reshape(-1, 3)]
        rings += [img[b:-b, :b].reshape(-1, 3), img[b:-b, -b:].reshape(-1, 3)]
    pixels = torch.cat(rings).float()
    tol = 4.0 / 255.0
    for colour in (WHITE, BLACK):
        near = ((pixels - torch.tensor(colour)).abs() <= tol).all(dim=1)
        if float(near.float().mean()) >= PLAIN_BORDER_FRACTION:
            return colour
    return None


def default_background(views: Sequence[View], fallback: Sequence[float]) -> tuple[float, ...]:
    """The scene background when the user sets none. Images with alpha: white (the object-
    capture convention of NeRF-synthetic and most cut-out captures: dark objects stay visible
    and an empty model cannot score well by rendering nothing). Without alpha: the plain
    backdrop the images show at their borders (white or black), else ``fallback`` (the
    format's; it only shows through empty space)."""
    if any(v.alpha is not None for v in views):
        return WHITE
    plain = plain_background(views)
    if plain is not None:
        return plain
    return tuple(float(c) for c in fallback)


def on_default_background(
    train: list[View], test: list[View], loaded_on: tuple[float, float, float]
) -> tuple[list[View], list[View], tuple[float, ...]]:
    """Views loaded on ``loaded_on`` moved onto :func:`default_background` (only images with
    alpha change), and that background."""
    background = default_background(train + test, loaded_on)
    if background != loaded_on:
        old, new = torch.tensor(loaded_on), torch.tensor(background)
        train = [recomposite(v, old, new) for v in train]
        test = [recomposite(v, old, new) for v in test]
    return train, test, background


def background_reason(scene: Scene) -> str:
    """Why ``scene.background`` is what it is (one phrase, for ``scene info``)."""
    if scene.format == "blender":
        return "NeRF-synthetic protocol: RGBA composited on white"
    if has_alpha(scene):
        return "images have alpha: composited on white (the object-capture convention)"
    plain = plain_background(scene.train)
    if plain is not None and tuple(scene.background.tolist()) == plain:
        name = "white" if plain == WHITE else "black"
        return f"the images show a plain {name} backdrop at their borders"
    return "no alpha channel: black, seen only where the model is empty"


def recomposite(view: View, old: Tensor, new: Tensor) -> View:
    """``view`` with its image moved from background ``old`` to ``new`` (exact for straight
    alpha: image + (new - old) * (1 - alpha)); views without alpha are returned unchanged."""
    if view.alpha is None or torch.equal(old, new):
        return view
    a = view.alpha.to(view.image.dtype)[..., None]
    delta = (new - old).to(view.image.dtype).view(1, 1, 3)
    image = (view.image + delta * (1.0 - a)).clamp(0.0, 1.0).contiguous()
    return dataclasses.replace(view, image=image)


def with_background(scene: Scene, background: Sequence[float] | Tensor) -> Scene:
    """``scene`` with every image that has alpha composited on ``background`` and
    ``scene.background`` set to it: targets and renders share one background."""
    new = torch.as_tensor(background, dtype=torch.float32).reshape(3)
    old = scene.background.float().reshape(3)
    if torch.equal(old, new):
        return scene
    return dataclasses.replace(
        scene,
        train=[recomposite(v, old, new) for v in scene.train],
        test=[recomposite(v, old, new) for v in scene.test],
        background=new,
    )


def check_downscale(downscale: int, source: str) -> int:
    """Validate the extra integer downscale factor."""
    if int(downscale) != downscale or downscale < 1:
        raise SceneError(f"{source}: downscale must be a positive integer, got {downscale!r}")
    return int(downscale)


def _f64(t: Tensor) -> np.ndarray:
    """A camera tensor as float64 numpy, wherever it lives: the trainer classifies and bounds
    its cameras after moving them to the model's device (a CUDA tensor has no ``.numpy()``)."""
    return t.detach().to("cpu", torch.float64).numpy()


def look_at_bounds(cameras: Sequence[Camera]) -> tuple[float, float]:
    """Near/far for formats without bounds: the point closest (least squares) to all optical
    axes is taken as the scene centre; near = 0.2x and far = 3x its nearest/farthest depth.
    Wide on purpose: priors sweep this range and must not clip the object. Cameras that see
    the centre from behind (parallel or diverging axes) fall back to the baseline scale."""
    centre = _axes_point(cameras)
    depths = []
    for cam in cameras:
        w2c = _f64(cam.world_to_camera)
        depths.append(float((w2c[:3, :3] @ centre + w2c[:3, 3])[2]))
    positive = [d for d in depths if d > 0]
    if not positive:  # cameras looking away from each other: fall back to baseline scale
        centres = np.stack([_f64(c.center) for c in cameras])
        span = float(np.linalg.norm(centres.max(0) - centres.min(0))) or 1.0
        return 0.05 * span, 50.0 * span
    return 0.2 * min(positive), 3.0 * max(positive)


def _frustum_samples(
    cameras: Sequence[Camera], near: Sequence[float], far: Sequence[float], samples: int, seed: int
) -> tuple[list[Tensor], list[Tensor]]:
    """Per camera: ``samples`` world points drawn in its frustum between near and far
    (inverse-depth sampling), and how many of the cameras (itself included) see each point."""
    gen = torch.Generator().manual_seed(seed)
    points, seen_by = [], []
    for i, cam in enumerate(cameras):
        u = torch.rand(samples, generator=gen, dtype=torch.float64) * cam.width
        v = torch.rand(samples, generator=gen, dtype=torch.float64) * cam.height
        inv = 1.0 / near[i] + torch.rand(samples, generator=gen, dtype=torch.float64) * (
            1.0 / far[i] - 1.0 / near[i]
        )
        z = 1.0 / inv
        xc = torch.stack([(u - cam.cx) / cam.fx * z, (v - cam.cy) / cam.fy * z, z], dim=-1)
        c2w = cam.camera_to_world.double()
        pts = xc @ c2w[:3, :3].T + c2w[:3, 3]
        seen = torch.zeros(samples, dtype=torch.int32)
        for other in cameras:
            uv, depth = project(other, pts)
            inside = (
                (depth > 0)
                & (uv[:, 0] >= 0)
                & (uv[:, 0] < other.width)
                & (uv[:, 1] >= 0)
                & (uv[:, 1] < other.height)
            )
            seen += inside.int()
        points.append(pts)
        seen_by.append(seen)
    return points, seen_by


def covisible_box(
    cameras: Sequence[Camera],
    near: Sequence[float],
    far: Sequence[float],
    samples: int = 4096,
    seed: int = 0,
) -> Box:
    """Box around the region seen by at least two of ``cameras`` between their near/far
    (inverse-depth sampling), from the 2nd-98th percentiles of such points per axis.

    This is the stand-in for DNGaussian's box from the COLMAP points (not shipped here)."""
    points, seen_by = _frustum_samples(cameras, near, far, samples, seed)
    pts = torch.cat([p[s >= 2] for p, s in zip(points, seen_by, strict=True)])
    if pts.shape[0] < 100:
        pts = torch.cat(points)
    lo = torch.quantile(pts, 0.02, dim=0).tolist()
    hi = torch.quantile(pts, 0.98, dim=0).tolist()
    return ((lo[0], lo[1], lo[2]), (hi[0], hi[1], hi[2]))


COMMON_VIEW_QUANTILE = 0.10
"""The common-view box spans these lower/upper quantiles of the points all cameras see..."""
COMMON_VIEW_MARGIN = 0.05
"""...widened on each side by this fraction of its size."""


@dataclasses.dataclass(frozen=True)
class CommonView:
    """The region every training camera sees, for uploads that give no bounds."""

    box: Box
    """Box around the points all cameras see (:data:`COMMON_VIEW_QUANTILE` per axis, widened
    by :data:`COMMON_VIEW_MARGIN`)."""
    near: float
    """Nearest depth of the box's corners from any camera (with a 10% margin)."""
    far: float
    """Farthest depth of the box's corners from any camera (with a 10% margin)."""


def common_view(cameras: Sequence[Camera], samples: int = 8192, seed: int = 0) -> CommonView | None:
    """For inward-looking cameras (an object photographed from around it): the region all of
    them see between the look-at bounds, and the depth range of its box.

    The object is where every camera looks: its box is tighter than the region any two see
    (:func:`covisible_box`), which with the wide look-at bounds reaches far behind the object.
    On NeRF-synthetic's three mic views it gives about the [-1, 1] cube and 2 to 6 that the
    format's loaders use. None for forward-facing captures (no common look-at point) or when
    too few samples are seen by all."""
    layout = camera_layout(cameras)
    if layout.kind != "inward-looking":
        return None
    n = len(cameras)
    near, far = look_at_bounds(cameras)
    points, seen_by = _frustum_samples(cameras, [near] * n, [far] * n, samples, seed)
    pts = torch.cat([p[s >= n] for p, s in zip(points, seen_by, strict=True)])
    if pts.shape[0] < 100:
        return None
    # The 10th-90th percentiles plus a 5% margin: the intersection of the cones is wider than
    # the object at its tips (2nd-98th on mic: a box 2.6 x 2.8 x 3.3, 2.9 dB below the SDK's
    # [-1, 1] cube at 300 iterations), and the bare 10th-90th box cuts the object's extremes
    # (1.6 dB below over four seeds); with the margin it trains within 0.4 dB of the cube
    # (docs/experiments/2026-11-25-stored-model-and-bounds.md).
    lo = torch.quantile(pts, COMMON_VIEW_QUANTILE, dim=0)
    hi = torch.quantile(pts, 1.0 - COMMON_VIEW_QUANTILE, dim=0)
    margin = COMMON_VIEW_MARGIN * (hi - lo)
    lo, hi = lo - margin, hi + margin
    corners = torch.cartesian_prod(*[torch.stack([lo[i], hi[i]]) for i in range(3)])
    depths = torch.cat(
        [
            (corners @ c.world_to_camera.double()[:3, :3].T + c.world_to_camera.double()[:3, 3])[
                :, 2
            ]
            for c in cameras
        ]
    )
    if float(depths.min()) <= 0.0:  # a camera inside the box: keep the wide bounds
        return None
    box = ((float(lo[0]), float(lo[1]), float(lo[2])), (float(hi[0]), float(hi[1]), float(hi[2])))
    return CommonView(box, 0.9 * float(depths.min()), 1.1 * float(depths.max()))


def check_overlap(
    cameras: Sequence[Camera],
    names: Sequence[str],
    near: float,
    far: float,
    source: str,
    samples: int = 1024,
) -> list[str]:
    """Raise SceneError when no camera sees anything another camera sees between ``near`` and
    ``far`` (cameras facing away from each other: usually a wrong ``convention`` or ``pose``);
    return the names of cameras that share nothing with the others (the caller warns)."""
    n = len(cameras)
    _, seen_by = _frustum_samples(cameras, [near] * n, [far] * n, samples, seed=1)
    shared = [float((s >= 2).float().mean()) for s in seen_by]
    if max(shared) == 0.0:
        raise SceneError(
            f"{source}: no two cameras see a common region (each faces away from the others). "
            "Check 'convention' (opencv: +z forward; opengl: +z back) and 'pose' "
            "(camera_to_world vs world_to_camera): a matrix read the wrong way looks backwards"
        )
    return [name for name, f in zip(names, shared, strict=True) if f == 0.0]


FORWARD_FACING_MAX_SPREAD_DEG = 30.0
"""A capture whose viewing directions all lie within this angle of their mean direction is
forward-facing (LLFF-style); a wider spread with the optical axes converging in front of every
camera is inward-looking (an orbit around an object)."""


@dataclasses.dataclass(frozen=True)
class CameraLayout:
    """How a set of cameras is arranged (scale-free figures)."""

    kind: str
    """'forward-facing' or 'inward-looking'."""
    spread_deg: float
    """Largest angle between a camera's viewing direction and the mean viewing direction."""
    converges: bool
    """Whether the point nearest all optical axes lies in front of every camera."""

    @property
    def forward_facing(self) -> bool:
        """Whether the cameras face forward (the layout the LLFF-style presets' plane-sweep
        init and half-resolution hard pass are for)."""
        return self.kind == "forward-facing"

    def describe(self) -> str:
        """One phrase for messages, e.g. 'inward-looking (view directions spread 42°)'."""
        return f"{self.kind} (view directions within {self.spread_deg:.0f}° of their mean)"


def _axes_point(cameras: Sequence[Camera]) -> np.ndarray:
    """Least-squares point closest to every optical axis."""
    a = np.zeros((3, 3))
    b = np.zeros(3)
    for cam in cameras:
        c2w = _f64(cam.camera_to_world)
        d, o = c2w[:3, 2], c2w[:3, 3]
        proj = np.eye(3) - np.outer(d, d)
        a += proj
        b += proj @ o
    return np.linalg.lstsq(a, b, rcond=None)[0]


def camera_layout(cameras: Sequence[Camera]) -> CameraLayout:
    """Classify ``cameras`` as forward-facing or inward-looking (see
    :data:`FORWARD_FACING_MAX_SPREAD_DEG`)."""
    dirs = np.stack([_f64(c.camera_to_world)[:3, 2] for c in cameras])
    mean = dirs.mean(axis=0)
    norm = float(np.linalg.norm(mean))
    if norm < 1e-6:  # directions cancel out: cameras all around an object
        spread = 180.0
    else:
        cos = np.clip(dirs @ (mean / norm), -1.0, 1.0)
        spread = float(np.degrees(np.arccos(cos)).max())
    point = _axes_point(cameras)
    depths = []
    for cam in cameras:
        w2c = _f64(cam.world_to_camera)
        depths.append(float((w2c[:3, :3] @ point + w2c[:3, 3])[2]))
    converges = all(d > 0 for d in depths)
    kind = (
        "inward-looking"
        if spread > FORWARD_FACING_MAX_SPREAD_DEG and converges
        else "forward-facing"
    )
    return CameraLayout(kind, spread, converges)


def check_camera_positions(cameras: Sequence[Camera], names: Sequence[str], source: str) -> None:
    """Raise SceneError naming the frame when a camera centre is absurd: beyond 1e12 (float32
    arithmetic on it is meaningless) or 1e4x farther from the other cameras than they are from
    each other (a typo or a matrix in other units)."""
    centres = np.stack([_f64(c.camera_to_world)[:3, 3] for c in cameras])
    w2c_t = np.stack([_f64(c.world_to_camera)[:3, 3] for c in cameras])
    for i, name in enumerate(names):
        size = max(float(np.abs(centres[i]).max()), float(np.abs(w2c_t[i]).max()))
        if not np.isfinite(size) or size > 1e12:
            raise SceneError(
                f"{source}: frame {name!r}: camera translation {size:.3g} is too large "
                "(beyond 1e12): rescale the scene or check the matrix"
            )
    if len(cameras) < 3:
        return
    median = np.median(centres, axis=0)
    dist = np.linalg.norm(centres - median, axis=1)
    typical = float(np.median(dist))
    if typical <= 0:
        return
    for i, name in enumerate(names):
        if dist[i] > 1e4 * typical:
            raise SceneError(
                f"{source}: frame {name!r}: camera is {dist[i]:.3g} from the median camera "
                f"position, the others about {typical:.3g}: a typo in its translation or a "
                "different unit?"
            )
