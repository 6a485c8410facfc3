"""The SDK's render ``mode`` and live view against a real ``sparsesplat serve`` (the shared smoke
job): what the SDK and the CLI return equals what the HTTP API returns for the same request."""

from __future__ import annotations

import asyncio
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from sparsesplat.api.cameras import PinholeCamera
from sparsesplat.client import (
    AsyncClient,
    Client,
    LiveView,
    NotFound,
    ValidationFailed,
    media,
)
from tests.client.conftest import Trained

pytestmark = pytest.mark.shared_data


def _api_render(url: str, model_id: str, camera: PinholeCamera, **body: Any) -> bytes:
    """``POST /v1/models/{id}/render`` with plain httpx."""
    answer = httpx.post(
        f"{url}/v1/models/{model_id}/render",
        json={"camera": camera.model_dump(mode="json"), **body},
        timeout=120,
    )
    assert answer.status_code == 200, answer.text
    return answer.content


def test_sdk_and_cli_baked_renders_are_the_api_baked_render(
    trained: Trained, tmp_path: Path
) -> None:
    camera = trained.upload.test_cameras()[0]
    baked = _api_render(trained.url, trained.job.id, camera, mode="baked")
    neural = _api_render(trained.url, trained.job.id, camera, mode="neural")
    with Client(trained.url) as client:
        model = client.model(trained.job.id)
        assert model.render_bytes(camera, mode="baked") == baked
        assert model.render_bytes(camera) == neural, "neural stays the default"
        written = model.render_to(camera, tmp_path / "baked.png", mode="baked")
        assert written.read_bytes() == baked
        (frame,) = model.render_path_bytes([camera], mode="baked")
        assert frame == baked
        # The mode is sent as given: the server names a mode it does not know.
        with pytest.raises(ValidationFailed, match="mode"):
            model.render_bytes(camera, mode="nope")  # type: ignore[arg-type]

    async def twin() -> bytes:
        async with AsyncClient(trained.url) as client:
            return await client.model(trained.job.id).render_bytes(camera, mode="baked")

    assert asyncio.run(twin()) == baked

    env = {**os.environ, "SPARSESPLAT_URL": trained.url}
    cli = subprocess.run(
        [sys.executable, "-m", "sparsesplat", "render", trained.job.id, "--view", "test:0",
         "--mode", "baked", "-o", "cli.png"],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert cli.returncode == 0, cli.stderr
    assert (tmp_path / "cli.png").read_bytes() == baked
    wrong = subprocess.run(
        [sys.executable, "-m", "sparsesplat", "render", trained.job.id, "--view", "test:0",
         "--mode", "exact", "-o", "x.png"],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert wrong.returncode == 2 and "neural" in wrong.stderr and "baked" in wrong.stderr


def test_live_view_frames_are_the_render_api_images(trained: Trained) -> None:
    """A frame of the SDK's live view is, pixel for pixel, the render API's image of the same
    pose and mode; a refused pose raises and the view stays usable; iterating ends when every
    pose sent is rendered or dropped."""
    camera = trained.upload.test_cameras()[1]
    api = {
        mode: media.decode_array(_api_render(trained.url, trained.job.id, camera, mode=mode))
        for mode in ("neural", "baked")
    }
    with Client(trained.url) as client:
        model = client.model(trained.job.id)
        with model.live(output="png") as view:
            assert isinstance(view, LiveView)
            assert view.send(camera, t=1.5) == 1.5
            header, image = view.recv()
            assert (header.t, header.seq, header.media) == (1.5, 1, "image/png")
            assert np.array_equal(media.decode_array(image), api["neural"])
            assert view.pending == 0

            bad = {**camera.model_dump(mode="json"), "fx": -1}
            view.send(bad, t=2)
            with pytest.raises(ValidationFailed, match="fx"):
                view.recv()
            assert view.pending == 0

            for t in (3.0, 4.0, 5.0):
                view.send(camera, t=t)
            frames = list(view)
            times = [h.t for h, _ in frames]
            assert times == sorted(times) and times[-1] == 5.0
            assert len(frames) + frames[-1][0].dropped == 3 and view.pending == 0

        with model.live(output="png", mode="baked") as view:
            view.send(camera, t=6)
            header, image = view.recv()
            assert np.array_equal(media.decode_array(image), api["baked"])

        with pytest.raises(NotFound), client.model("job_nope").live() as view:
            view.send(camera)
            view.recv(timeout=60)


def test_async_live_view_twin(trained: Trained) -> None:
    camera = trained.upload.test_cameras()[0]
    expected = media.decode_array(
        _api_render(trained.url, trained.job.id, camera, mode="baked", output="png")
    )

    async def main() -> list[Any]:
        async with (
            AsyncClient(trained.url) as client,
            client.model(trained.job.id).live(output="png", mode="baked") as view,
        ):
            await view.send(camera, t=7)
            await view.send(camera, t=8)
            return [frame async for frame in view]

    frames = asyncio.run(main())
    assert frames[-1][0].t == 8 and len(frames) + frames[-1][0].dropped == 2
    assert all(np.array_equal(media.decode_array(image), expected) for _, image in frames)
