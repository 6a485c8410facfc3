"""Wire schema of render requests: a camera (or a camera path) and what to return; the live
view's poses and frames."""

from __future__ import annotations

import struct
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from sparsesplat.api.cameras import PinholeCamera
from sparsesplat.api.names import ImageFormat

RenderOutput = Literal[ImageFormat, "depth16", "npy", "alpha"]
"""``png``/``jpeg``/``webp``: the colour image; ``depth16``: view-space depth as a 16-bit PNG
(millimetres of scene units: value / 1000 = depth, 0 = empty; see the ``X-Depth-Scale``
header); ``npy``: float32 depth (H, W) as a NumPy file; ``alpha``: coverage as an 8-bit PNG."""

RenderMode = Literal["neural", "baked"]
"""How the model is coloured: ``neural`` evaluates its own colour function exactly (DNGaussian's
neural colour field, equal to the trainer's evaluation render); ``baked`` its degree-3 SH bake
(the colours of the .ply export, an approximation). The same for a model trained with SH colour."""
DEFAULT_RENDER_MODE: RenderMode = "neural"
"""Measured: with the field's view-independent part computed once per loaded model, the exact
neural colours cost about what the baked SH cost (a few ms at 50k Gaussians next to a ~40 ms
rasterization), so the exact mode is the default."""

MEDIA_TYPES: dict[str, str] = {
    "png": "image/png",
    "jpeg": "image/jpeg",
    "webp": "image/webp",
    "depth16": "image/png",
    "npy": "application/x-npy",
    "alpha": "image/png",
    "zip": "application/zip",
}
"""Content type of each output; a camera path answers with a ZIP of numbered frames."""


RENDER_WARNING_HEADER = "X-Render-Warning"
"""Response header present when a render sees (nearly) nothing of the model: its value says
so and what to check. ``X-Coverage`` always gives each camera's mean alpha (comma-separated)."""
EMPTY_RENDER_COVERAGE = 0.01
"""A render whose mean alpha is below this sees (nearly) nothing of the model."""


def empty_renders(coverages: list[float]) -> list[int]:
    """The positions of the renders (given by their mean alpha, in camera order) that see
    (nearly) nothing of the model: the one rule behind the service's
    :data:`RENDER_WARNING_HEADER` and the local ``sparsesplat render`` warning (each words it
    for its own reader)."""
    return [i for i, coverage in enumerate(coverages) if coverage < EMPTY_RENDER_COVERAGE]


class RenderRequest(BaseModel):
    """Body of ``POST /v1/models/{id}/render``: exactly one of ``camera`` or ``path``."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {
                    "camera": {
                        "convention": "opencv",
                        "pose": "camera_to_world",
                        "matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, -4], [0, 0, 0, 1]],
                        "fx": 400.0,
                        "fy": 400.0,
                        "cx": 200.0,
                        "cy": 150.0,
                        "width": 400,
                        "height": 300,
                    },
                    "output": "png",
                }
            ]
        },
    )

    camera: PinholeCamera | None = None
    """One camera."""
    path: list[PinholeCamera] | None = Field(default=None, min_length=1)
    """A camera path: the answer is a ZIP of frames ``0000.png``, ``0001.png``…"""
    output: RenderOutput = "png"
    """What to return."""
    downscale: int = Field(default=1, ge=1, le=16)
    """Integer factor the image size and focal lengths are divided by."""
    quality: int = Field(default=90, ge=1, le=100)
    """JPEG/WebP quality."""
    mode: RenderMode = DEFAULT_RENDER_MODE
    """``neural`` (exact) or ``baked`` (the SH of the export)."""

    @model_validator(mode="before")
    @classmethod
    def _camera_not_wrapped(cls, data: Any) -> Any:
        # A bare camera posted as the body would otherwise answer one 'extra input' line per
        # camera field, without saying what the body should look like.
        if isinstance(data, dict):
            stray = [
                k for k in data if k in PinholeCamera.model_fields and k not in cls.model_fields
            ]
            if stray:
                raise ValueError(
                    f"camera field(s) {', '.join(repr(k) for k in stray)} at the top level of "
                    'the body: send {"camera": {...}} (one camera) or {"path": [{...}, ...]} '
                    "(a camera path), with 'output' and 'downscale' beside it"
                )
        return data

    @model_validator(mode="after")
    def _one_of(self) -> RenderRequest:
        if (self.camera is None) == (self.path is None):
            raise ValueError("give exactly one of 'camera' or 'path'")
        return self

    @property
    def cameras(self) -> list[PinholeCamera]:
        """The cameras to render, in order."""
        return [self.camera] if self.camera is not None else list(self.path or [])


LiveOutput = Literal["jpeg", "png", "webp"]
"""Image formats of the live view (``jpeg``: the cheapest to encode and to decode)."""


class LivePose(BaseModel):
    """A text message of the live view (``/v1/models/{id}/live``): the camera to render now.

    Poses that arrive while a render is running replace one another: only the latest is
    rendered next, so the view follows the camera without a backlog."""

    model_config = ConfigDict(extra="forbid")

    camera: PinholeCamera
    """Where to look from."""
    t: float = 0.0
    """The client's timestamp of this pose, echoed in the frame rendered from it (how old a
    frame is when it is shown: the client's clock now minus ``t``)."""
    output: LiveOutput = "jpeg"
    """Image format of the frames."""
    quality: int = Field(default=85, ge=1, le=100)
    """JPEG/WebP quality."""
    mode: RenderMode = DEFAULT_RENDER_MODE
    """``neural`` (exact) or ``baked``."""
    downscale: int = Field(default=1, ge=1, le=16)
    """Integer factor the image size and focal lengths are divided by."""

    def render_request(self) -> RenderRequest:
        """The render this pose asks for."""
        return RenderRequest(
            camera=self.camera, output=self.output, quality=self.quality, mode=self.mode,
            downscale=self.downscale,
        )  # fmt: skip


class LiveFrame(BaseModel):
    """The header of a live-view frame. A frame is one binary message: the header's length as
    4 bytes (big-endian), the header as UTF-8 JSON, then the encoded image."""

    t: float
    """The ``t`` of the pose rendered."""
    seq: int
    """1, 2, … per connection."""
    media: str
    """Content type of the image bytes."""
    render_ms: float
    """Milliseconds the API waited for the render worker (render, encoding and the hop)."""
    dropped: int
    """Poses replaced by a newer one before they were rendered, so far on this connection."""


def pack_live_frame(header: LiveFrame, image: bytes) -> bytes:
    """One live-view binary message: header length (4 bytes, big-endian), header JSON, image."""
    head = header.model_dump_json().encode()
    return struct.pack(">I", len(head)) + head + image


def unpack_live_frame(message: bytes) -> tuple[LiveFrame, bytes]:
    """The header and image bytes of a message made by :func:`pack_live_frame`."""
    if len(message) < 4:
        raise ValueError("live frame shorter than its 4-byte header length")
    (n,) = struct.unpack(">I", message[:4])
    if len(message) < 4 + n:
        raise ValueError(f"live frame of {len(message)} bytes cannot hold a {n}-byte header")
    return LiveFrame.model_validate_json(message[4 : 4 + n]), message[4 + n :]
