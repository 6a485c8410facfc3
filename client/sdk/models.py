"""Model handles: :class:`ModelHandle` and its asyncio twin :class:`AsyncModelHandle`, side by
side (renders, camera paths, videos, the live view, exports)."""

from __future__ import annotations

import asyncio
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sparsesplat.api.cameras import PinholeCamera
from sparsesplat.api.jobs import ModelInfo
from sparsesplat.api.names import ExportFormat
from sparsesplat.api.renders import DEFAULT_RENDER_MODE, LiveOutput, RenderMode, RenderOutput
from sparsesplat.client import cameras as cams
from sparsesplat.client import media
from sparsesplat.client.sdk._output import (
    model_cameras,
    output_for,
    unzip_frames,
    write_file,
    write_frames,
)
from sparsesplat.client.sdk.live import AsyncLiveView, LiveView

if TYPE_CHECKING:
    import numpy as np
    from PIL import Image

    from sparsesplat.client.sdk._client import AsyncClient, Client


class ModelHandle:
    """A trained model: renders at any camera, camera paths, videos and exports."""

    def __init__(self, client: Client, model_id: str) -> None:
        self.client = client
        self.id = model_id
        """Model id (= the job id)."""

    def info(self) -> ModelInfo:
        """Size, final metrics, exports and the cameras it was trained with."""
        return self.client._send(self.client._c_model(self.id))

    def cameras(self, split: str | None = "train") -> list[PinholeCamera]:
        """The uploaded cameras of ``split`` (``train``, ``test``; None: all)."""
        return model_cameras(self.info(), split)

    def render_bytes(
        self,
        camera: PinholeCamera | dict[str, Any],
        output: RenderOutput = "png",
        *,
        downscale: int = 1,
        quality: int = 90,
        mode: RenderMode = DEFAULT_RENDER_MODE,
    ) -> bytes:
        """The encoded render (PNG/JPEG/WebP image, 16-bit depth PNG, .npy depth, alpha).
        ``mode``: ``neural`` (the model's exact colours, the default) or ``baked`` (the
        view-independent SH bake of the .ply export)."""
        call = self.client._c_render(self.id, camera, None, output, downscale, quality, mode)
        return self.client._send(call)

    def render(
        self,
        camera: PinholeCamera | dict[str, Any],
        *,
        downscale: int = 1,
        mode: RenderMode = DEFAULT_RENDER_MODE,
    ) -> np.ndarray:
        """The render as an (H, W, 3) uint8 array (``images`` extra)."""
        return media.decode_array(self.render_bytes(camera, downscale=downscale, mode=mode))

    def render_image(
        self,
        camera: PinholeCamera | dict[str, Any],
        *,
        downscale: int = 1,
        mode: RenderMode = DEFAULT_RENDER_MODE,
    ) -> Image.Image:
        """The render as a PIL image (``images`` extra)."""
        return media.decode_image(self.render_bytes(camera, downscale=downscale, mode=mode))

    def render_depth(
        self, camera: PinholeCamera | dict[str, Any], *, downscale: int = 1
    ) -> np.ndarray:
        """View-space depth as an (H, W) float32 array, 0 where empty (``images`` extra)."""
        return media.decode_array(self.render_bytes(camera, "npy", downscale=downscale))

    def render_to(
        self,
        camera: PinholeCamera | dict[str, Any],
        path: str | Path,
        *,
        output: RenderOutput | None = None,
        downscale: int = 1,
        mode: RenderMode = DEFAULT_RENDER_MODE,
    ) -> Path:
        """Render into a file; the output follows the suffix (.png .jpg .webp .npy)."""
        path = Path(path)
        kind = output_for(path, output)
        data = self.render_bytes(camera, kind, downscale=downscale, mode=mode)
        return write_file(path, data)

    def render_path_bytes(
        self,
        cameras: Sequence[PinholeCamera | dict[str, Any]],
        output: RenderOutput = "png",
        *,
        downscale: int = 1,
        quality: int = 90,
        mode: RenderMode = DEFAULT_RENDER_MODE,
    ) -> list[bytes]:
        """Every camera of a path rendered in one request: the encoded frames, in order."""
        call = self.client._c_render(self.id, None, cameras, output, downscale, quality, mode)
        return unzip_frames(self.client._send(call))

    def render_path(
        self,
        cameras: Sequence[PinholeCamera | dict[str, Any]],
        *,
        downscale: int = 1,
        mode: RenderMode = DEFAULT_RENDER_MODE,
    ) -> list[np.ndarray]:
        """A camera path as (H, W, 3) uint8 arrays (``images`` extra)."""
        frames = self.render_path_bytes(cameras, downscale=downscale, mode=mode)
        return [media.decode_array(f) for f in frames]

    def render_path_to(
        self,
        cameras: Sequence[PinholeCamera | dict[str, Any]],
        folder: str | Path,
        output: RenderOutput = "png",
        *,
        downscale: int = 1,
        mode: RenderMode = DEFAULT_RENDER_MODE,
    ) -> list[Path]:
        """A camera path written as numbered files ``0000.png``… into ``folder``."""
        frames = self.render_path_bytes(cameras, output, downscale=downscale, mode=mode)
        return write_frames(folder, frames, output)

    def orbit(
        self,
        n: int = 60,
        *,
        intrinsics: cams.Intrinsics | None = None,
        radius_scale: float = 1.0,
        arc_deg: float = 360.0,
        elevation_deg: float | None = None,
    ) -> list[PinholeCamera]:
        """A camera orbit fitted to the model's training cameras (see
        :func:`~sparsesplat.client.cameras.orbit_around`)."""
        return cams.orbit_around(
            self.cameras("train"),
            n,
            intrinsics=intrinsics,
            radius_scale=radius_scale,
            arc_deg=arc_deg,
            elevation_deg=elevation_deg,
        )

    def video(
        self,
        cameras: Sequence[PinholeCamera | dict[str, Any]],
        path: str | Path,
        *,
        fps: float = 30.0,
        downscale: int = 1,
        mode: RenderMode = DEFAULT_RENDER_MODE,
    ) -> Path:
        """Render a camera path and encode it as a video (.mp4…; ``video`` extra)."""
        media.require("imageio", "writing a video")
        frames = self.render_path_bytes(cameras, downscale=downscale, mode=mode)
        return media.write_video(frames, path, fps)

    def live(
        self,
        *,
        output: LiveOutput = "jpeg",
        quality: int = 85,
        mode: RenderMode = DEFAULT_RENDER_MODE,
        downscale: int = 1,
    ) -> LiveView:
        """A live view (``/v1/models/{id}/live``): send poses, receive frames (a
        :class:`~sparsesplat.api.renders.LiveFrame` header and the image bytes) as the
        server renders them; only the newest waiting pose is rendered. Use it as a context
        manager; see :class:`~sparsesplat.client.sdk.live.LiveView`."""
        return LiveView(self.client, self.id, output, quality, mode, downscale)

    def export(self, format: ExportFormat, path: str | Path) -> Path:
        """Download the model as ``ply`` (INRIA layout), ``splat`` or ``checkpoint``."""
        return write_file(path, self.client._send(self.client._c_export(self.id, format)))

    def pin(self, pinned: bool = True) -> ModelInfo:
        """Keep the model past the service's model expiry (``pinned=False``: let it expire)."""
        return self.client._send(self.client._c_pin(self.id, pinned))

    def __repr__(self) -> str:
        return f"ModelHandle({self.id!r})"


class AsyncModelHandle:
    """asyncio twin of :class:`ModelHandle`."""

    def __init__(self, client: AsyncClient, model_id: str) -> None:
        self.client = client
        self.id = model_id
        """Model id (= the job id)."""

    async def info(self) -> ModelInfo:
        """See :meth:`ModelHandle.info`."""
        return await self.client._send(self.client._c_model(self.id))

    async def cameras(self, split: str | None = "train") -> list[PinholeCamera]:
        """See :meth:`ModelHandle.cameras`."""
        return model_cameras(await self.info(), split)

    async def render_bytes(
        self,
        camera: PinholeCamera | dict[str, Any],
        output: RenderOutput = "png",
        *,
        downscale: int = 1,
        quality: int = 90,
        mode: RenderMode = DEFAULT_RENDER_MODE,
    ) -> bytes:
        """See :meth:`ModelHandle.render_bytes`."""
        call = self.client._c_render(self.id, camera, None, output, downscale, quality, mode)
        return await self.client._send(call)

    async def render(
        self,
        camera: PinholeCamera | dict[str, Any],
        *,
        downscale: int = 1,
        mode: RenderMode = DEFAULT_RENDER_MODE,
    ) -> np.ndarray:
        """See :meth:`ModelHandle.render`."""
        data = await self.render_bytes(camera, downscale=downscale, mode=mode)
        return media.decode_array(data)

    async def render_image(
        self,
        camera: PinholeCamera | dict[str, Any],
        *,
        downscale: int = 1,
        mode: RenderMode = DEFAULT_RENDER_MODE,
    ) -> Image.Image:
        """See :meth:`ModelHandle.render_image`."""
        data = await self.render_bytes(camera, downscale=downscale, mode=mode)
        return media.decode_image(data)

    async def render_depth(
        self, camera: PinholeCamera | dict[str, Any], *, downscale: int = 1
    ) -> np.ndarray:
        """See :meth:`ModelHandle.render_depth`."""
        return media.decode_array(await self.render_bytes(camera, "npy", downscale=downscale))

    async def render_to(
        self,
        camera: PinholeCamera | dict[str, Any],
        path: str | Path,
        *,
        output: RenderOutput | None = None,
        downscale: int = 1,
        mode: RenderMode = DEFAULT_RENDER_MODE,
    ) -> Path:
        """See :meth:`ModelHandle.render_to`."""
        path = Path(path)
        kind = output_for(path, output)
        data = await self.render_bytes(camera, kind, downscale=downscale, mode=mode)
        return write_file(path, data)

    async def render_path_bytes(
        self,
        cameras: Sequence[PinholeCamera | dict[str, Any]],
        output: RenderOutput = "png",
        *,
        downscale: int = 1,
        quality: int = 90,
        mode: RenderMode = DEFAULT_RENDER_MODE,
    ) -> list[bytes]:
        """See :meth:`ModelHandle.render_path_bytes`."""
        call = self.client._c_render(self.id, None, cameras, output, downscale, quality, mode)
        return unzip_frames(await self.client._send(call))

    async def render_path(
        self,
        cameras: Sequence[PinholeCamera | dict[str, Any]],
        *,
        downscale: int = 1,
        mode: RenderMode = DEFAULT_RENDER_MODE,
    ) -> list[np.ndarray]:
        """See :meth:`ModelHandle.render_path`."""
        frames = await self.render_path_bytes(cameras, downscale=downscale, mode=mode)
        return [media.decode_array(f) for f in frames]

    async def render_path_to(
        self,
        cameras: Sequence[PinholeCamera | dict[str, Any]],
        folder: str | Path,
        output: RenderOutput = "png",
        *,
        downscale: int = 1,
        mode: RenderMode = DEFAULT_RENDER_MODE,
    ) -> list[Path]:
        """See :meth:`ModelHandle.render_path_to`."""
        frames = await self.render_path_bytes(cameras, output, downscale=downscale, mode=mode)
        return write_frames(folder, frames, output)

    async def orbit(
        self,
        n: int = 60,
        *,
        intrinsics: cams.Intrinsics | None = None,
        radius_scale: float = 1.0,
        arc_deg: float = 360.0,
        elevation_deg: float | None = None,
    ) -> list[PinholeCamera]:
        """See :meth:`ModelHandle.orbit`."""
        return cams.orbit_around(
            await self.cameras("train"),
            n,
            intrinsics=intrinsics,
            radius_scale=radius_scale,
            arc_deg=arc_deg,
            elevation_deg=elevation_deg,
        )

    async def video(
        self,
        cameras: Sequence[PinholeCamera | dict[str, Any]],
        path: str | Path,
        *,
        fps: float = 30.0,
        downscale: int = 1,
        mode: RenderMode = DEFAULT_RENDER_MODE,
    ) -> Path:
        """See :meth:`ModelHandle.video`."""
        media.require("imageio", "writing a video")
        frames = await self.render_path_bytes(cameras, downscale=downscale, mode=mode)
        return await asyncio.to_thread(media.write_video, frames, path, fps)

    def live(
        self,
        *,
        output: LiveOutput = "jpeg",
        quality: int = 85,
        mode: RenderMode = DEFAULT_RENDER_MODE,
        downscale: int = 1,
    ) -> AsyncLiveView:
        """See :meth:`ModelHandle.live` (``async with model.live() as view``)."""
        return AsyncLiveView(self.client, self.id, output, quality, mode, downscale)

    async def export(self, format: ExportFormat, path: str | Path) -> Path:
        """See :meth:`ModelHandle.export`."""
        return write_file(path, await self.client._send(self.client._c_export(self.id, format)))

    async def pin(self, pinned: bool = True) -> ModelInfo:
        """See :meth:`ModelHandle.pin`."""
        return await self.client._send(self.client._c_pin(self.id, pinned))

    def __repr__(self) -> str:
        return f"AsyncModelHandle({self.id!r})"
