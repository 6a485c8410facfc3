"""POST -> train -> render on a small synthetic scene, so a clone without ``../shared`` runs
the service's whole path too: a real uvicorn and worker processes, the SDK on the client side."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from sparsesplat.client import Client
from tests.service.live import LiveService

torch = pytest.importorskip("torch")

SIZE = (48, 32)
"""Image width and height: small, yet above the 16-pixel minimum (SSIM/LPIPS windows)."""
ITERATIONS = 30


def write_synthetic_upload(folder: Path) -> Path:
    """An upload folder of a random Gaussian blob rendered from 3 training and 2 held-out
    cameras (``engine.synthetic``: views that agree with each other), OpenCV world-to-camera."""
    from sparsesplat.engine.synthetic import make_scene

    scene, _ = make_scene(seed=0, width=SIZE[0], height=SIZE[1], n_train=3, n_test=2)
    folder.mkdir(parents=True)
    frames = []
    for split, views in (("train", scene.train), ("test", scene.test)):
        for view in views:
            image = (view.image.numpy() * 255.0 + 0.5).astype(np.uint8)
            Image.fromarray(image).save(folder / f"{view.name}.png")
            cam = view.camera
            frames.append(
                {
                    "image": f"{view.name}.png",
                    "matrix": cam.world_to_camera.double().tolist(),
                    "fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy,
                    "split": split,
                }
            )  # fmt: skip
    document = {"convention": "opencv", "pose": "world_to_camera", "frames": frames,
                "near": scene.near, "far": scene.far}  # fmt: skip
    (folder / "cameras.json").write_text(json.dumps(document))
    return folder


def test_synthetic_upload_trains_and_renders(live: LiveService, tmp_path: Path) -> None:
    folder = write_synthetic_upload(tmp_path / "upload")
    live.start_api()
    live.wait_ready()
    with Client(live.url) as client:
        job = client.submit_folder(folder, {"iterations": ITERATIONS, "record_interval_s": 1.0})
        assert (job.info.n_train_views, job.info.n_test_views) == (3, 2)
        events = list(job.events(timeout=600))
        final = job.refresh()
        assert final.state.value == "succeeded", final.error
        assert [e.seq for e in events] == list(range(1, len(events) + 1))
        states = [e.data["state"] for e in events if e.type == "state"]
        assert states[0] == "queued" and "running" in states and states[-1] == "succeeded"
        records = [e.data for e in events if e.type == "record"]
        assert records and records[-1]["final"] and records[-1]["iteration"] == ITERATIONS
        assert all(np.isfinite(r["psnr"]) for r in records)

        camera = job.model.cameras("test")[0]
        served = job.model.render(camera).astype(np.int16)
        assert served.shape == (SIZE[1], SIZE[0], 3)

    # The service's render is the trained model's own render of that camera.
    from sparsesplat.engine.camera import Camera
    from sparsesplat.engine.model import load_model

    model = load_model(live.data_dir / "jobs" / job.id / "run")
    reference = model.render(Camera.from_wire(camera)).image.clamp(0, 1)
    expected = (reference.permute(1, 2, 0).numpy() * 255.0 + 0.5).astype(np.int16)
    assert np.abs(served - expected).max() <= 1
    assert served.max() > 0, "the trained model renders something at a held-out camera"

    # The job trained exactly what `sparsesplat train` trains from the same folder and seed
    # (one run recipe: same preset, same defaults), at the worker's thread count.
    import subprocess
    import sys

    out = tmp_path / "cli"
    command = [sys.executable, "-m", "sparsesplat", "train", str(folder), "--out", str(out),
               "--iterations", str(ITERATIONS), "--seed", "0", "--set", "threads=1",
               "--set", "record.eval_interval_s=1.0"]  # fmt: skip
    subprocess.run(command, check=True, capture_output=True, timeout=600)
    job_run = live.data_dir / "jobs" / job.id / "run"
    assert (out / "model.ply").read_bytes() == (job_run / "model.ply").read_bytes()
    cli = json.loads((out / "metrics.json").read_text())
    assert final.progress is not None and cli["preset"] == final.progress.preset
    assert cli["psnr"] == pytest.approx(records[-1]["psnr"], rel=0, abs=0)
