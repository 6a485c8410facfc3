"""Turning one render into the bytes a client asked for (image, depth, alpha): the one image
writer of the render worker and the local ``render`` command."""

from __future__ import annotations

import io
from typing import Any

import numpy as np

DEPTH16_UNITS_PER_SCENE_UNIT = 1000.0
"""A 16-bit depth PNG stores depth x 1000 (millimetres when the scene is in metres)."""
MIN_ALPHA_FOR_DEPTH = 0.01
"""Pixels covered less than this have no depth (0 in the outputs)."""


def expected_depth(depth: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Per-pixel depth of the visible surface: blended z / alpha, 0 where nearly empty."""
    safe = np.where(alpha >= MIN_ALPHA_FOR_DEPTH, alpha, 1.0)
    return np.where(alpha >= MIN_ALPHA_FOR_DEPTH, depth / safe, 0.0).astype(np.float32)


def rgb8(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) colours in [0, 1] -> uint8, clipped and rounded to the nearest level."""
    return (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def encode_image(image: np.ndarray, fmt: str, **options: Any) -> bytes:
    """The colour image ``image`` (H, W, 3) in [0, 1] as a ``fmt`` file (png, jpeg or webp).
    ``options`` go to Pillow's writer; none: Pillow's defaults (the local ``render``
    command's files), :func:`encode` passes the service's."""
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(rgb8(image)).save(buffer, format=fmt.upper(), **options)
    return buffer.getvalue()


def encode(
    output: str, image: np.ndarray, depth: np.ndarray, alpha: np.ndarray, quality: int
) -> bytes:
    """Bytes of ``output`` (see ``api.renders.RenderOutput``) for one view.

    ``image`` (H, W, 3) in [0, 1]; ``depth`` and ``alpha`` (H, W) as the rasterizer returns them.
    """
    from PIL import Image

    buffer = io.BytesIO()
    if output in ("png", "jpeg", "webp"):
        # Chosen for latency: zlib level 1 (level 0 is barely faster and ~10x larger); WebP's
        # fastest method (about 5x faster to encode than its default, a little larger).
        options: dict[str, Any] = {
            "png": {"compress_level": 1},
            "jpeg": {"quality": quality},
            "webp": {"quality": quality, "method": 0},
        }[output]
        return encode_image(image, output, **options)
    if output == "depth16":
        z = expected_depth(depth, alpha) * DEPTH16_UNITS_PER_SCENE_UNIT
        Image.fromarray(np.clip(z + 0.5, 0, 65535).astype(np.uint16)).save(buffer, format="PNG")
    elif output == "npy":
        np.save(buffer, expected_depth(depth, alpha), allow_pickle=False)
    elif output == "alpha":
        a = (np.clip(alpha, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
        Image.fromarray(a).save(buffer, format="PNG", compress_level=1)
    else:
        raise ValueError(f"unknown render output {output!r}")
    return buffer.getvalue()
