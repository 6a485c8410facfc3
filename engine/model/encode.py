"""Turning one render into the bytes a client asked for (image, depth, alpha): the one image
writer of the render worker and the local ``render`` command."""

from __future__ import annotations

import io
import threading
import zlib
from concurrent.futures import ThreadPoolExecutor
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
    """(H, W, 3) colours in [0, 1] -> uint8, clipped and rounded to the nearest level; a
    C-contiguous (row-major) array, what the image writers read."""
    # The scaling works in place on the clip's copy, in the render's own memory order (its
    # image is a (3, H, W) tensor seen as (H, W, 3)); the one transposing pass is the cast.
    scaled = np.clip(image, 0.0, 1.0)
    scaled *= 255.0
    scaled += 0.5
    return scaled.astype(np.uint8, order="C")


def encode_image(image: np.ndarray, fmt: str, **options: Any) -> bytes:
    """The colour image ``image`` (H, W, 3) in [0, 1] as a ``fmt`` file (png, jpeg or webp).
    ``options`` go to Pillow's writer; none: Pillow's defaults (the local ``render``
    command's files), :func:`encode` passes the service's."""
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(rgb8(image)).save(buffer, format=fmt.upper(), **options)
    return buffer.getvalue()


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_FILTER_UP = 2
"""PNG filter type 2: each byte minus the byte above it (the first row: minus zero)."""


PNG_SPLIT_BYTES = 256 * 1024
"""Filtered images at least this large are deflated in two halves at once (see
:func:`_deflate`); below it the second thread's hand-off costs about what it saves."""
_pool: ThreadPoolExecutor | None = None
_pool_lock = threading.Lock()


def _deflate_pool() -> ThreadPoolExecutor:
    """The one helper thread of the split deflate, started on first use."""
    global _pool
    with _pool_lock:
        if _pool is None:
            _pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="png-deflate")
        return _pool


def _deflate_part(data: memoryview, last: bool) -> bytes:
    """Raw deflate of ``data`` (Z_RLE; see :func:`encode_png`); a part that is not ``last``
    ends byte-aligned on a sync flush, so that the next part's blocks can follow it."""
    deflate = zlib.compressobj(1, zlib.DEFLATED, -15, 8, zlib.Z_RLE)
    return deflate.compress(data) + deflate.flush(zlib.Z_FINISH if last else zlib.Z_SYNC_FLUSH)


def _deflate(data: memoryview) -> bytes:
    """The zlib stream of ``data``: large inputs as two raw deflate streams made at once on
    two threads (zlib releases the GIL) and joined as pigz joins them, between the zlib header
    and the Adler-32 of the whole. The render worker's threads are idle while it encodes:
    on a 504x378 render the halves take about half of the 4-5 ms of one pass."""
    if len(data) < PNG_SPLIT_BYTES:
        deflate = zlib.compressobj(1, zlib.DEFLATED, 15, 8, zlib.Z_RLE)
        return deflate.compress(data) + deflate.flush()
    half = len(data) // 2
    first = _deflate_pool().submit(_deflate_part, data[:half], False)
    second = _deflate_part(data[half:], True)
    checksum = zlib.adler32(data)
    # 0x78 0x01: deflate with a 32 KB window, the "fastest" level hint, header check bits.
    return b"\x78\x01" + first.result() + second + checksum.to_bytes(4, "big")


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    crc = zlib.crc32(data, zlib.crc32(kind))
    return len(data).to_bytes(4, "big") + kind + data + crc.to_bytes(4, "big")


def encode_png(pixels: np.ndarray) -> bytes:
    """A PNG of 8-bit ``pixels``: (H, W) grey or (H, W, 3) RGB, written for latency.

    The service's PNG writer (a render's PNG is on every request's critical path). Every row is
    'Up'-filtered in one numpy subtraction and the filtered rows are deflated once by zlib with
    its run-length strategy. Pillow at ``compress_level=1`` took 11-16 ms on a 504x378 render
    (it picks a filter per row by trying all five, then runs zlib's fastest level); this takes
    about 5 ms there and writes 10-20% fewer bytes, and it stays fast on the worst cases: a
    mostly empty frame (zero rows become runs) and noise (RLE finds nothing to search for).
    What it gives up: long-distance matches, so a synthetic pattern that repeats along a row
    (a sawtooth ramp) stays larger than Pillow writes it. Lossless: a decoder returns exactly
    ``pixels``.
    """
    if (
        pixels.dtype != np.uint8
        or pixels.ndim not in (2, 3)
        or (pixels.ndim == 3 and pixels.shape[2] != 3)
    ):
        raise ValueError(f"uint8 (H, W) or (H, W, 3) pixels expected, got {pixels.dtype} "
                         f"{pixels.shape}")  # fmt: skip
    height, width = pixels.shape[:2]
    if height == 0 or width == 0:
        raise ValueError("a PNG needs at least one pixel")
    rows = np.ascontiguousarray(pixels).reshape(height, -1)
    filtered = np.empty((height, rows.shape[1] + 1), dtype=np.uint8)
    filtered[:, 0] = _PNG_FILTER_UP
    filtered[0, 1:] = rows[0]
    np.subtract(rows[1:], rows[:-1], out=filtered[1:, 1:])  # uint8: wraps modulo 256, as PNG's
    # Z_RLE only looks for repeats of the previous byte: after the Up filter that is what an
    # image has (flat and smooth areas become runs of zeros); the level does not change it.
    data = _deflate(filtered.data.cast("B"))
    colour_type = 2 if pixels.ndim == 3 else 0  # truecolour or greyscale, 8 bits, no interlace
    header = width.to_bytes(4, "big") + height.to_bytes(4, "big") + bytes([8, colour_type, 0, 0, 0])
    return b"".join((_PNG_SIGNATURE, _png_chunk(b"IHDR", header), _png_chunk(b"IDAT", data),
                     _png_chunk(b"IEND", b"")))  # fmt: skip


def encode(
    output: str, image: np.ndarray, depth: np.ndarray, alpha: np.ndarray, quality: int
) -> bytes:
    """Bytes of ``output`` (see ``api.renders.RenderOutput``) for one view.

    ``image`` (H, W, 3) in [0, 1]; ``depth`` and ``alpha`` (H, W) as the rasterizer returns them.
    """
    from PIL import Image

    buffer = io.BytesIO()
    if output == "png":
        return encode_png(rgb8(image))
    if output in ("jpeg", "webp"):
        # Chosen for latency: WebP's fastest method (about 5x faster to encode than its
        # default, a little larger).
        options: dict[str, Any] = {
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
        return encode_png((np.clip(alpha, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8))
    else:
        raise ValueError(f"unknown render output {output!r}")
    return buffer.getvalue()
