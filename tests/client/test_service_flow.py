"""The SDK against a real ``sparsesplat serve``: upload → wait → render → export, events that
resume after a dropped connection, metrics, paths and videos, the async twin."""

from __future__ import annotations

import asyncio
from pathlib import Path

import numpy as np
import pytest

from sparsesplat.client import AsyncClient, Client, JobState, cameras, media
from sparsesplat.client.scenes import Upload
from tests.client.conftest import Trained
from tests.client.proxy import CuttingProxy

pytestmark = pytest.mark.shared_data


def _held_out(upload: Upload, index: int = 0) -> np.ndarray:
    """The held-out image composited on white, as the Blender preset scores it."""
    name = upload.frame_names("test")[index]
    return np.asarray(media.composite_on(media.decode_image(upload.images[name])))


def test_upload_wait_render_export(trained: Trained, tmp_path: Path) -> None:
    job = trained.job
    assert job.state == JobState.succeeded and job.has_model
    assert (job.n_train_views, job.n_test_views) == (3, 2)
    assert job.spec.preset == "blender"  # from the folder's format
    states = [e.data["state"] for e in trained.events if e.type == "state"]
    assert states[-1] == "succeeded" and "running" in states
    with Client(trained.url) as client:
        model = client.model(job.id)
        info = model.info()
        camera = trained.upload.test_cameras()[0]
        image = model.render(camera)
        assert image.shape == (100, 100, 3) and image.dtype == np.uint8
        # The render scores close to the trainer's own held-out PSNR (mean of 2 views).
        score = media.psnr(image, _held_out(trained.upload))
        assert info.metrics["psnr"] is not None
        assert abs(score - info.metrics["psnr"]) < 3.0, (score, info.metrics)
        assert model.render_image(camera).size == (100, 100)
        depth = model.render_depth(camera)
        assert depth.shape == (100, 100) and depth.dtype == np.float32 and depth.max() > 0
        png = model.render_to(camera, tmp_path / "view.png")
        assert media.sniff(png.read_bytes()) == "png"
        ply = model.export("ply", tmp_path / "model.ply")
        header = ply.read_bytes()[:2000].decode("latin-1")
        assert header.startswith("ply") and f"element vertex {info.n_gaussians}" in header
        splat = model.export("splat", tmp_path / "model.splat")
        assert splat.stat().st_size == 32 * info.n_gaussians
        assert [c.matrix for c in model.cameras("test")] == [
            c.matrix for c in trained.upload.test_cameras()
        ]


def test_events_resume_after_a_dropped_connection(trained: Trained) -> None:
    """The stream is cut mid-frame; the client reconnects with ?after=<last seq> and the
    events it yields are exactly 1..N, no gap, no repeat."""
    port = int(trained.url.rsplit(":", 1)[1])
    proxy = CuttingProxy(port, cut_after=900, cuts=2)
    try:
        with Client(proxy.url) as client:
            events = list(client.events(trained.job.id, timeout=60))
    finally:
        proxy.close()
    # At least one cut landed mid-stream and was resumed. The last cut may instead fall in the
    # closing handshake, after the final event (how many bytes are left for the second
    # connection depends on how many progress events the job stored): then there is nothing
    # to resume and no further connection.
    assert proxy.cut >= 1 and proxy.connections >= 2, "not cut and resumed"
    assert proxy.connections in (proxy.cut, proxy.cut + 1), (proxy.cut, proxy.connections)
    seqs = [e.seq for e in events]
    assert seqs == list(range(1, len(seqs) + 1))
    assert seqs[-1] == trained.events[-1].seq
    assert events[-1].type == "state" and events[-1].data["state"] == "succeeded"
    # What wait() saw through its callback is the same stream.
    assert [e.seq for e in trained.events] == seqs


def test_metrics_rows_and_frame(trained: Trained, tmp_path: Path) -> None:
    with Client(trained.url) as client:
        handle = client.job(trained.job.id)
        rows = handle.metrics()
        assert len(rows) >= 2 and rows[-1].final and rows[-1].iteration == 40
        assert all(r.psnr is not None for r in rows)
        frame = handle.metrics_frame()
        assert list(frame["iteration"]) == [r.iteration for r in rows]
        assert media.sniff(handle.metrics_plot(tmp_path / "m.png").read_bytes()) == "png"


def test_render_path_orbit_and_video(trained: Trained, tmp_path: Path) -> None:
    with Client(trained.url) as client:
        model = client.model(trained.job.id)
        orbit = model.orbit(4)
        train = model.cameras("train")
        centre = cameras.center_of_interest(train)
        assert all(abs(c) < 0.5 for c in centre)  # mic sits at the origin
        frames = model.render_path(orbit)
        assert len(frames) == 4 and all(f.shape == (100, 100, 3) for f in frames)
        a, b = model.cameras("test")
        path = cameras.interpolate(a, b, 3)
        written = model.render_path_to(path, tmp_path / "path")
        assert [p.name for p in written] == ["0000.png", "0001.png", "0002.png"]
        video = model.video(orbit, tmp_path / "orbit.mp4", fps=4)
        assert video.stat().st_size > 1000


def test_async_client_twin(trained: Trained) -> None:
    async def main() -> None:
        async with AsyncClient(trained.url) as client:
            handle = await client.job(trained.job.id)
            assert handle.state == JobState.succeeded
            last = trained.events[-1].seq
            tail = [e.seq async for e in handle.events(after=last - 3)]
            assert tail == [last - 2, last - 1, last]
            final = await handle.wait(progress=False)
            assert final.state == JobState.succeeded
            model = handle.model
            image = await model.render(trained.upload.test_cameras()[1])
            assert image.shape == (100, 100, 3)
            page = await client.jobs(state="succeeded")
            assert trained.job.id in [j.id for j in page.jobs]

    asyncio.run(main())
