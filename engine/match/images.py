"""Photos as the networks take them, and where in a photo a keypoint counts as evidence."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from sparsesplat.engine.match.errors import MatchError
from sparsesplat.engine.match.settings import resize_factor

TEXTURE_WINDOW = 9
"""Side of the window (pixels, odd) whose grey-level spread decides whether a patch is flat."""


@dataclass
class Prepared:
    """One photo shrunk and padded for a network, with the map of usable pixels."""

    tensor: Tensor
    """(1, 3, Hp, Wp) float32 RGB in [0, 1]: the photo resized by ``scale`` and padded at the
    bottom and right (edge pixels repeated) to a multiple of the network's stride."""
    scale: tuple[float, float]
    """(sx, sy): the resized photo's size over the photo's own, per axis."""
    resized: tuple[int, int]
    """(width, height) of the resized photo before padding."""
    size: tuple[int, int]
    """(width, height) of the photo itself."""
    usable: np.ndarray
    """(H, W) bool in the photo's own pixels: where a keypoint may lie (inside the caller's
    mask, on a textured patch)."""


def as_float_rgb(image: np.ndarray | Tensor, index: int) -> np.ndarray:
    """(H, W, 3) float32 in [0, 1] from uint8 or float RGB (a grey (H, W) photo repeated)."""
    arr = image.detach().cpu().numpy() if isinstance(image, Tensor) else np.asarray(image)
    if arr.ndim == 2:
        arr = np.repeat(arr[..., None], 3, axis=2)
    if arr.ndim != 3 or arr.shape[2] not in (3, 4):
        raise MatchError(f"photo {index + 1}: expected (H, W, 3) RGB, got shape {arr.shape}")
    arr = arr[..., :3]
    if arr.dtype == np.uint8:
        return arr.astype(np.float32) / 255.0
    if not np.issubdtype(arr.dtype, np.floating):
        raise MatchError(f"photo {index + 1}: pixels must be uint8 or float, got {arr.dtype}")
    if not np.isfinite(arr).all():
        raise MatchError(f"photo {index + 1}: pixels contain NaN or infinity")
    return np.clip(arr, 0.0, 1.0).astype(np.float32)


def texture_map(rgb: np.ndarray, window: int = TEXTURE_WINDOW) -> np.ndarray:
    """(H, W) float32 standard deviation of the grey level over the ``window`` x ``window``
    patch around each pixel (the patch clipped at the border)."""
    grey = torch.from_numpy(rgb).double().mean(dim=2)[None, None]
    pad = window // 2
    mean = F.avg_pool2d(grey, window, 1, pad, count_include_pad=False)
    mean_sq = F.avg_pool2d(grey * grey, window, 1, pad, count_include_pad=False)
    return (mean_sq - mean * mean).clamp(min=0).sqrt()[0, 0].float().numpy()


def prepare(
    rgb: np.ndarray,
    mask: np.ndarray | None,
    sides: tuple[int, int],
    stride: int,
    min_texture: float,
    index: int,
) -> Prepared:
    """Resize ``rgb`` (H, W, 3 float) so its longer side lies within ``sides`` = (min_side,
    max_side) (0: no bound), pad it to a multiple of ``stride`` and mark the usable pixels:
    inside ``mask`` (when given) and textured (grey-level spread at least ``min_texture``)."""
    min_side, max_side = sides
    h, w = rgb.shape[:2]
    if min(h, w) < 16:
        raise MatchError(f"photo {index + 1}: {w}x{h} pixels is too small to match")
    if mask is not None and mask.shape != (h, w):
        raise MatchError(f"photo {index + 1}: mask is {mask.shape[::-1]}, the photo {w}x{h}")
    factor = resize_factor(max(h, w), min_side, max_side)
    rw, rh = max(16, round(w * factor)), max(16, round(h * factor))
    x = torch.from_numpy(np.ascontiguousarray(rgb)).permute(2, 0, 1)[None]
    if (rw, rh) != (w, h):
        # Antialiased: a plain bilinear shrink aliases fine texture into false features.
        x = F.interpolate(
            x, size=(rh, rw), mode="bilinear", align_corners=False, antialias=factor < 1
        ).clamp(0, 1)
    ph, pw = -rh % stride, -rw % stride
    if ph or pw:
        x = F.pad(x, (0, pw, 0, ph), mode="replicate")
    usable = texture_map(rgb) >= min_texture
    if mask is not None:
        usable &= mask.astype(bool)
    return Prepared(x.contiguous(), (rw / w, rh / h), (rw, rh), (w, h), usable)


def to_photo(points: Tensor | np.ndarray, prep: Prepared, offset: float = 0.5) -> np.ndarray:
    """Network keypoints (N, 2), in the resized photo's pixel indices (pixel k spans [k, k+1)),
    as (N, 2) float32 coordinates of the photo itself with pixel centres at +0.5."""
    pts = points.detach().cpu().numpy() if isinstance(points, Tensor) else np.asarray(points)
    pts = pts.astype(np.float64).reshape(-1, 2)
    return ((pts + offset) / np.array(prep.scale)).astype(np.float32)


def usable_at(points: np.ndarray, prep: Prepared) -> np.ndarray:
    """(N,) bool: the photo coordinates ``points`` lie inside the photo, on a usable pixel."""
    w, h = prep.size
    inside = (points[:, 0] >= 0) & (points[:, 0] < w) & (points[:, 1] >= 0) & (points[:, 1] < h)
    ok = np.zeros(len(points), bool)
    ix = np.clip(points[:, 0].astype(np.int64), 0, w - 1)
    iy = np.clip(points[:, 1].astype(np.int64), 0, h - 1)
    ok[inside] = prep.usable[iy[inside], ix[inside]]
    return ok
