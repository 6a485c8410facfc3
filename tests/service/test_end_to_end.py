"""The flow users have, against a real uvicorn on 127.0.0.1 and real worker processes:
upload 3 views + held-out views, stream events to completion, render a held-out pose, export."""

from __future__ import annotations

import io
import json
from typing import Any

import httpx
import numpy as np
import pytest
from PIL import Image
from websockets.sync.client import connect

from tests.service.live import LiveService, submit

pytestmark = pytest.mark.shared_data

TERMINAL = {"succeeded", "failed", "cancelled"}


def _stream(url: str, job_id: str, after: int = 0) -> list[dict]:
    events = []
    ws_url = url.replace("http://", "ws://") + f"/v1/jobs/{job_id}/events?after={after}"
    with connect(ws_url, open_timeout=30) as ws:
        for message in ws:
            event = json.loads(message)
            events.append(event)
            if event["type"] == "state" and event["data"]["state"] in TERMINAL:
                break
    return events


def test_upload_train_stream_render_export(live: LiveService, mic_upload) -> None:
    live.start_api()
    live.wait_ready()
    # The default recipe: PyDNet++ prior (real ONNX inference), neural colour, both depth passes.
    job = submit(live.url, mic_upload, {"iterations": 40, "record_interval_s": 2.0})
    assert job["state"] == "queued" and job["n_train_views"] == 3 and job["n_test_views"] == 2

    events = _stream(live.url, job["id"])
    seqs = [e["seq"] for e in events]
    assert seqs == list(range(1, len(seqs) + 1)), "events arrive in order, without gaps"
    states = [e["data"]["state"] for e in events if e["type"] == "state"]
    assert states[0] == "queued" and "running" in states and states[-1] == "succeeded", states
    records = [e["data"] for e in events if e["type"] == "record"]
    assert len(records) >= 2 and records[-1]["final"] and records[-1]["iteration"] == 40
    assert all(np.isfinite(r["psnr"]) for r in records)

    # The model renders the held-out pose exactly as the trainer's own evaluation does.
    model = httpx.get(f"{live.url}/v1/models/{job['id']}").json()
    held_out = next(c for c in model["cameras"] if c["split"] == "test")
    camera = {k: held_out[k] for k in ("convention", "pose", "matrix", "fx", "fy", "cx", "cy",
                                        "width", "height")}  # fmt: skip
    answer = httpx.post(f"{live.url}/v1/models/{job['id']}/render", json={"camera": camera},
                        timeout=120)  # fmt: skip
    assert answer.status_code == 200 and answer.headers["content-type"] == "image/png"
    served = np.asarray(Image.open(io.BytesIO(answer.content)).convert("RGB"), dtype=np.int16)

    from sparsesplat.engine.datasets import load_scene
    from sparsesplat.engine.model import load_model

    run = live.data_dir / "jobs" / job["id"]
    scene = load_scene(run / "upload", format="folder")
    # Held-out views keep the order of cameras.json.
    view = scene.test[[c for c in model["cameras"] if c["split"] == "test"].index(held_out)]
    reference = load_model(run / "run").render(view.camera).image.clamp(0, 1)
    expected = (reference.permute(1, 2, 0).numpy() * 255.0 + 0.5).astype(np.int16)
    # Same model, same camera, same kernel: equal up to one 8-bit step of rounding.
    assert np.abs(served - expected).max() <= 1

    # The baked mode renders the SH of the run's .ply export (the trainer's bake).
    from sparsesplat.engine.export.ply import read_ply

    local = load_model(run / "run")
    local.use_baked_sh(read_ply(run / "run" / "model.ply")["sh"])
    baked_ref = local.render(view.camera, mode="baked").image.clamp(0, 1)
    baked_ref = (baked_ref.permute(1, 2, 0).numpy() * 255.0 + 0.5).astype(np.int16)
    answer = httpx.post(f"{live.url}/v1/models/{job['id']}/render",
                        json={"camera": camera, "mode": "baked"}, timeout=120)  # fmt: skip
    baked = np.asarray(Image.open(io.BytesIO(answer.content)).convert("RGB"), dtype=np.int16)
    assert np.abs(baked - baked_ref).max() <= 1

    _check_outputs(live.url, job["id"], camera, served)
    _check_live_view(live.url, job["id"], camera, served)
    assert model["background"] is not None and len(model["background"]) == 3

    # Uploaded images and the depth priors are served back (the web page shows them).
    first = httpx.get(f"{live.url}/v1/jobs/{job['id']}/images/0")
    assert first.status_code == 200 and first.headers["content-type"] == "image/png"
    assert first.content == (run / "upload" / "images" / "000.png").read_bytes()
    assert httpx.get(f"{live.url}/v1/jobs/{job['id']}/images/5").status_code == 404
    prior = httpx.get(f"{live.url}/v1/jobs/{job['id']}/priors/0")
    assert prior.status_code == 200
    assert Image.open(io.BytesIO(prior.content)).size == (100, 100)

    ply = httpx.get(f"{live.url}/v1/models/{job['id']}/export/ply", timeout=60)
    assert ply.status_code == 200
    path = live.data_dir.parent / "model.ply"
    path.write_bytes(ply.content)
    from sparsesplat.engine.export.ply import read_ply

    assert len(read_ply(path)["means"]) == model["n_gaussians"] > 0


def _check_outputs(url: str, model_id: str, camera: dict, served: np.ndarray) -> None:
    """Every output kind of the render route, the GET form and a camera path."""
    import zipfile

    render = f"{url}/v1/models/{model_id}/render"

    def post(**body: object) -> httpx.Response:
        response = httpx.post(render, json={"camera": camera, **body}, timeout=120)
        assert response.status_code == 200, response.text
        return response

    h, w = served.shape[:2]
    for output, media in (("jpeg", "image/jpeg"), ("webp", "image/webp")):
        answer = post(output=output)
        assert answer.headers["content-type"] == media
        decoded = np.asarray(Image.open(io.BytesIO(answer.content)).convert("RGB"), np.int16)
        assert decoded.shape == served.shape and np.abs(decoded - served).mean() < 8
    alpha = np.asarray(Image.open(io.BytesIO(post(output="alpha").content)))
    assert alpha.shape == (h, w) and alpha.dtype == np.uint8 and alpha.max() > 0
    depth = np.load(io.BytesIO(post(output="npy").content), allow_pickle=False)
    assert depth.shape == (h, w) and depth.dtype == np.float32 and np.isfinite(depth).all()
    answer = post(output="depth16")
    depth16 = np.asarray(Image.open(io.BytesIO(answer.content)), dtype=np.float64)
    scale = float(answer.headers["x-depth-scale"])
    covered = depth > 0
    assert covered.any() and np.abs(depth16[covered] / scale - depth[covered]).max() <= 1 / scale
    small = np.asarray(Image.open(io.BytesIO(post(downscale=2).content)))
    assert small.shape[:2] == (h // 2, w // 2)

    query = {k: v for k, v in camera.items() if k != "matrix"}
    query["matrix"] = ",".join(str(x) for row in camera["matrix"] for x in row)
    by_get = httpx.get(render, params=query, timeout=120)
    assert by_get.status_code == 200
    assert np.array_equal(np.asarray(Image.open(io.BytesIO(by_get.content)).convert("RGB")),
                          served.astype(np.uint8))  # fmt: skip

    path = httpx.post(render, json={"path": [camera, camera]}, timeout=120)
    assert path.headers["content-type"] == "application/zip"
    with zipfile.ZipFile(io.BytesIO(path.content)) as archive:
        assert archive.namelist() == ["0000.png", "0001.png"]


def _check_live_view(url: str, model_id: str, camera: dict, served: np.ndarray) -> None:
    """The live view's frames are the render API's images; stale poses are dropped, every pose
    is accounted for; a bad pose is answered and the connection stays usable."""
    from websockets.exceptions import ConnectionClosed

    from sparsesplat.api.renders import unpack_live_frame

    ws_url = url.replace("http://", "ws://") + f"/v1/models/{model_id}/live"

    def frame(ws: Any) -> tuple[Any, np.ndarray]:
        message = ws.recv(timeout=120)
        assert isinstance(message, bytes), message
        header, image = unpack_live_frame(message)
        return header, np.asarray(Image.open(io.BytesIO(image)).convert("RGB"), np.int16)

    with connect(ws_url, open_timeout=30, max_size=None) as ws:
        ws.send(json.dumps({"camera": camera, "t": 1.5, "output": "png"}))
        header, image = frame(ws)
        assert (header.t, header.seq, header.media) == (1.5, 1, "image/png")
        assert np.array_equal(image, served), "the live frame is the render API's image"

        ws.send(json.dumps({"camera": {**camera, "fx": -1}, "t": 2}))
        error = json.loads(ws.recv(timeout=30))
        assert error["type"] == "error" and error["code"] == "invalid_pose"
        assert "fx" in error["message"]

        ws.send(json.dumps({"camera": camera, "t": 3, "mode": "baked", "output": "png"}))
        header, baked = frame(ws)
        assert header.t == 3 and header.seq == 2
        answer = httpx.post(f"{url}/v1/models/{model_id}/render",
                            json={"camera": camera, "mode": "baked"}, timeout=120)  # fmt: skip
        want = np.asarray(Image.open(io.BytesIO(answer.content)).convert("RGB"), np.int16)
        assert np.array_equal(baked, want), "a baked live frame is the API's baked render"

        # Six poses sent at once: the newest is always rendered, frames come in order, and every
        # pose is either rendered or counted as dropped. Whether any is overtaken depends on how
        # fast this machine renders, so the drop itself is tested in test_live_pose_queue.py.
        for t in range(10, 16):
            ws.send(json.dumps({"camera": camera, "t": t, "output": "jpeg"}))
        times = []
        while not times or times[-1] != 15:
            header, _ = frame(ws)
            times.append(header.t)
        assert times == sorted(times) and header.media == "image/jpeg"
        assert len(times) + header.dropped == 6, (times, header)

    nope = url.replace("http://", "ws://") + "/v1/models/nope/live"
    with connect(nope) as ws, pytest.raises(ConnectionClosed) as closed:
        ws.recv(timeout=30)
    assert closed.value.rcvd is not None and closed.value.rcvd.code == 4404
