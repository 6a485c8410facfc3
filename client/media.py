"""Images on the client side: sizes read from file headers in pure Python, and the NumPy /
Pillow / imageio conversions, imported only by the calls that need them.

The base install (no NumPy, no Pillow) can submit PNG, JPEG and WebP files as they are and
download renders as bytes or files; arrays and PIL images need the ``images`` extra, videos
the ``video`` extra. A call without its extra raises :class:`MissingExtra` naming it.
"""

from __future__ import annotations

import importlib
import io
import struct
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

from sparsesplat.client.errors import InvalidInput, MissingExtra

if TYPE_CHECKING:
    import numpy as np
    from PIL import Image

EXTRA_OF_MODULE = {
    "numpy": "images",
    "PIL": "images",
    "imageio": "video",
    "imageio_ffmpeg": "video",
    "pandas": "pandas",
}
"""Which extra provides each optional module."""

UPLOAD_FORMATS = {"png": "image/png", "jpeg": "image/jpeg", "webp": "image/webp"}
"""Image formats the service accepts as they are (others are converted with Pillow)."""


def require(module: str, what: str) -> ModuleType:
    """Import ``module`` or raise :class:`MissingExtra` naming the extra that provides it."""
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as exc:
        top = module.split(".")[0]
        raise MissingExtra(top, EXTRA_OF_MODULE.get(top, "images"), what) from exc


def sniff(data: bytes) -> str | None:
    """``png``, ``jpeg`` or ``webp`` from the first bytes of a file, else None."""
    if data[:8] == b"\x89PNG\r\n\x1a\n":
        return "png"
    if data[:3] == b"\xff\xd8\xff":
        return "jpeg"
    if data[:4] == b"RIFF" and data[8:12] == b"WEBP":
        return "webp"
    return None


def image_size(data: bytes, name: str = "image") -> tuple[int, int]:
    """(width, height) of a PNG, JPEG or WebP from its header, without decoding it."""
    kind = sniff(data)
    try:
        if kind == "png":
            width, height = struct.unpack(">II", data[16:24])
            return int(width), int(height)
        if kind == "jpeg":
            return _jpeg_size(data)
        if kind == "webp":
            return _webp_size(data)
    except (struct.error, IndexError, ValueError) as exc:
        raise InvalidInput(f"{name}: truncated or corrupt {kind} header ({exc})") from exc
    raise InvalidInput(f"{name}: not a PNG, JPEG or WebP image")


def _jpeg_size(data: bytes) -> tuple[int, int]:
    i = 2
    while i < len(data):
        while data[i] != 0xFF:
            i += 1
        while data[i] == 0xFF:
            i += 1
        marker = data[i]
        i += 1
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:
            continue
        (length,) = struct.unpack(">H", data[i : i + 2])
        if marker in (0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE):
            height, width = struct.unpack(">HH", data[i + 3 : i + 7])
            return int(width), int(height)
        i += length
    raise ValueError("no SOF marker")


def _webp_size(data: bytes) -> tuple[int, int]:
    chunk = data[12:16]
    if chunk == b"VP8 ":
        width, height = struct.unpack("<HH", data[26:30])
        return int(width & 0x3FFF), int(height & 0x3FFF)
    if chunk == b"VP8L":
        b = data[21:25]
        width = 1 + (((b[1] & 0x3F) << 8) | b[0])
        height = 1 + (((b[3] & 0xF) << 10) | (b[2] << 2) | ((b[1] & 0xC0) >> 6))
        return width, height
    if chunk == b"VP8X":
        width = 1 + int.from_bytes(data[24:27], "little")
        height = 1 + int.from_bytes(data[27:30], "little")
        return width, height
    raise ValueError(f"unknown WebP chunk {chunk!r}")


def encode_png(image: Any, what: str = "an image array") -> bytes:
    """PNG bytes of an (H, W, 3|4) or (H, W) array (uint8, or float in [0, 1]) or a PIL image."""
    pil = require("PIL.Image", f"uploading {what}")
    if not isinstance(image, pil.Image):
        image = to_pil(image)
    buffer = io.BytesIO()
    image.save(buffer, format="PNG")
    return buffer.getvalue()


def to_pil(array: Any) -> Image.Image:
    """A PIL image of an (H, W[, C]) array; floats are taken as [0, 1]."""
    np_ = require("numpy", "converting an array to an image")
    pil = require("PIL.Image", "converting an array to an image")
    a = np_.asarray(array)
    if a.dtype.kind == "f":
        a = (np_.clip(a, 0.0, 1.0) * 255.0 + 0.5).astype(np_.uint8)
    elif a.dtype != np_.uint8:
        raise InvalidInput(f"image array: expected uint8 or float in [0, 1], got {a.dtype}")
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[..., 0]
    if a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[2] not in (3, 4)):
        raise InvalidInput(f"image array: expected (H, W), (H, W, 3) or (H, W, 4), got {a.shape}")
    image: Image.Image = pil.fromarray(a)
    return image


def decode_image(data: bytes) -> Image.Image:
    """A decoded PIL image of encoded bytes."""
    pil = require("PIL.Image", "decoding a render into an image")
    image: Image.Image = pil.open(io.BytesIO(data))
    image.load()
    return image


def decode_array(data: bytes) -> np.ndarray:
    """An array of encoded bytes: an image as (H, W, C) uint8 / (H, W) for 8/16-bit grey, or
    a ``.npy`` file as stored."""
    np_ = require("numpy", "decoding a render into an array")
    if data[:6] == b"\x93NUMPY":
        out: np.ndarray = np_.load(io.BytesIO(data), allow_pickle=False)
        return out
    array: np.ndarray = np_.asarray(decode_image(data))
    return array


def resize(data: bytes, width: int, height: int) -> bytes:
    """An image resized (area-averaged, alpha kept) and re-encoded as PNG."""
    pil = require("PIL.Image", "downscaling images before upload")
    image = decode_image(data)
    if image.mode not in ("RGB", "RGBA", "L", "LA"):
        image = image.convert("RGBA" if "A" in image.getbands() else "RGB")
    small = image.resize((width, height), pil.Resampling.BOX)
    buffer = io.BytesIO()
    small.save(buffer, format="PNG")
    return buffer.getvalue()


def to_png(data: bytes) -> bytes:
    """Any image Pillow reads (BMP, TIFF…) re-encoded as PNG for the upload."""
    image = decode_image(data)
    buffer = io.BytesIO()
    image.save(buffer, format="PNG")
    return buffer.getvalue()


def write_video(frames: list[bytes], path: str | Path, fps: float = 30.0) -> Path:
    """Encode frames (encoded images) as a video file with imageio's bundled ffmpeg."""
    np_ = require("numpy", "writing a video")
    imageio = require("imageio.v2", "writing a video")
    require("imageio_ffmpeg", "writing a video")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = [np_.asarray(decode_image(f).convert("RGB")) for f in frames]
    # H.264 wants even sizes.
    h, w = arrays[0].shape[:2]
    arrays = [a[: h - h % 2, : w - w % 2] for a in arrays]
    imageio.mimwrite(str(path), arrays, fps=fps, macro_block_size=1)
    return path


def side_by_side(*images: Any) -> Image.Image:
    """Images (arrays or PIL, same height) placed left to right."""
    pil = require("PIL.Image", "composing images")
    tiles = [i if isinstance(i, pil.Image) else to_pil(i) for i in images]
    tiles = [t.convert("RGB") for t in tiles]
    out: Image.Image = pil.new(
        "RGB", (sum(t.width for t in tiles), max(t.height for t in tiles)), "white"
    )
    x = 0
    for t in tiles:
        out.paste(t, (x, 0))
        x += t.width
    return out


def psnr(a: Any, b: Any) -> float:
    """PSNR in dB between two images (uint8 or float in [0, 1]; RGB channels compared)."""
    np_ = require("numpy", "computing PSNR")

    def as_float(x: Any) -> Any:
        arr = np_.asarray(x)
        arr = arr.astype(np_.float64) / 255.0 if arr.dtype == np_.uint8 else arr.astype(float)
        return arr[..., :3] if arr.ndim == 3 else arr

    fa, fb = as_float(a), as_float(b)
    if fa.shape != fb.shape:
        raise InvalidInput(f"psnr: shapes differ {fa.shape} vs {fb.shape}")
    mse = float(np_.mean((fa - fb) ** 2))
    return float("inf") if mse == 0 else float(-10.0 * np_.log10(mse))


def composite_on(image: Any, background: tuple[float, float, float] = (1.0, 1.0, 1.0)) -> Any:
    """An RGBA array or PIL image composited on ``background`` (RGB array, uint8)."""
    np_ = require("numpy", "compositing an image")
    if hasattr(image, "convert"):
        image = image.convert("RGBA" if "A" in image.getbands() else "RGB")
    a = np_.asarray(image)
    if a.ndim == 2:
        return np_.repeat(a[..., None], 3, axis=2)
    if a.shape[2] != 4:
        return a[..., :3]
    f = a.astype(np_.float64) / 255.0
    rgb = f[..., :3] * f[..., 3:] + np_.asarray(background) * (1 - f[..., 3:])
    return (rgb * 255.0 + 0.5).astype(np_.uint8)
