"""Wire schema of render requests: a camera (or a camera path) and what to return."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from sparsesplat.api.cameras import PinholeCamera

RenderOutput = Literal["png", "jpeg", "webp", "depth16", "npy", "alpha"]
"""``png``/``jpeg``/``webp``: the colour image; ``depth16``: view-space depth as a 16-bit PNG
(millimetres of scene units: value / 1000 = depth, 0 = empty; see the ``X-Depth-Scale``
header); ``npy``: float32 depth (H, W) as a NumPy file; ``alpha``: coverage as an 8-bit PNG."""

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
