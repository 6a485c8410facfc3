"""Bad input gets a 4xx naming the problem, and leaves no job and no file behind.

In-process (the ASGI app with its lifespan, no workers): these are about validation, and about
what the job routes answer whatever a worker does meanwhile.
"""

from __future__ import annotations

import io
import json
import struct
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from PIL import Image

from sparsesplat.api.settings import Settings
from sparsesplat.api.store.jobs import JobStore
from sparsesplat.server.app import create_app

SIZE = 32


def _png(width: int = SIZE, height: int = SIZE, seed: int = 0) -> bytes:
    rng = np.random.default_rng(seed)
    buffer = io.BytesIO()
    Image.fromarray(rng.integers(0, 255, (height, width, 3), dtype=np.uint8)).save(buffer, "PNG")
    return buffer.getvalue()


def _png_bomb(width: int, height: int) -> bytes:
    """A PNG whose header claims ``width`` x ``height`` pixels but carries almost no data:
    anything that decodes it before checking the size would allocate gigabytes."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        body = kind + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body))

    header = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    idat = zlib.compress(b"\x00" * 1024)
    return (
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")
    )


def _frame(name: str, split: str = "train", x: float = 0.0) -> dict[str, Any]:
    return {
        "image": name,
        "matrix": [[1, 0, 0, x], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],
        "fx": 30.0,
        "fy": 30.0,
        "cx": SIZE / 2,
        "cy": SIZE / 2,
        "split": split,
    }


def _with_first(**frame: Any) -> dict[str, Any]:
    """The 3-view cameras with the first frame's fields replaced by ``frame``."""
    cameras = _cameras()
    cameras["frames"][0] = {**cameras["frames"][0], **frame}
    return cameras


def _cameras(n: int = 3, **top: Any) -> dict[str, Any]:
    doc = {"convention": "opencv", "pose": "camera_to_world"}
    doc.update(top)
    doc["frames"] = [_frame(f"v{i}.png", x=0.1 * i) for i in range(n)]
    return doc


def _parts(
    cameras: Any,
    images: dict[str, bytes] | None = None,
    spec: Any = None,
    masks: dict[str, bytes] | None = None,
) -> list:
    text = cameras if isinstance(cameras, str) else json.dumps(cameras)
    parts: list = [("cameras", ("cameras.json", text.encode(), "application/json"))]
    if images is None:
        images = {f"v{i}.png": _png(seed=i) for i in range(3)}
    parts += [("images", (name, data, "image/png")) for name, data in images.items()]
    parts += [("masks", (name, data, "image/png")) for name, data in (masks or {}).items()]
    if spec is not None:
        parts.append(("spec", (None, spec if isinstance(spec, str) else json.dumps(spec))))
    return parts


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    settings = Settings(data_dir=tmp_path / "data", workers=0, render_workers=0)
    with TestClient(create_app(settings)) as test_client:
        test_client.data_dir = settings.data_dir  # type: ignore[attr-defined]
        yield test_client


def _nothing_left(client: TestClient) -> None:
    assert client.get("/v1/jobs").json()["jobs"] == []
    data: Path = client.data_dir  # type: ignore[attr-defined]
    assert list((data / "jobs").iterdir()) == []
    assert list((data / "staging").iterdir()) == []


def test_a_valid_upload_is_accepted_and_stored_under_our_names(client: TestClient) -> None:
    response = client.post("/v1/jobs", files=_parts(_cameras()), data={})
    assert response.status_code == 201, response.text
    job = response.json()
    assert response.headers["location"] == f"/v1/jobs/{job['id']}"
    upload = client.data_dir / "jobs" / job["id"] / "upload"  # type: ignore[attr-defined]
    stored = json.loads((upload / "cameras.json").read_text())
    assert [f["image"] for f in stored["frames"]] == [f"images/00{i}.png" for i in range(3)]
    assert all((upload / f["image"]).is_file() for f in stored["frames"])


class _ClaimingAtOnce:
    """A dispatcher whose worker claims the job the moment it is announced."""

    def __init__(self, jobs: JobStore) -> None:
        self.jobs = jobs

    def enqueue(self, job_id: str) -> None:
        claim = self.jobs.claim("eager", lease_s=60)
        assert claim is not None and claim.job_id == job_id

    def close(self) -> None:
        pass


def test_the_answers_are_the_job_as_the_request_left_it_however_fast_the_worker(
    client: TestClient,
) -> None:
    service = client.app.state.service  # type: ignore[attr-defined]
    service.dispatch = _ClaimingAtOnce(service.jobs)
    response = client.post("/v1/jobs", files=_parts(_cameras()))
    assert response.status_code == 201 and response.json()["state"] == "queued"
    job_id = response.json()["id"]
    assert client.get(f"/v1/jobs/{job_id}").json()["state"] == "running"
    # Cancelling a running job flags it; the answer is the job at the flag, not after.
    assert client.post(f"/v1/jobs/{job_id}/cancel").json()["state"] == "running"
    assert service.jobs.heartbeat(job_id, "eager", 60) == (True, True)


def _mask_png(width: int = SIZE, height: int = SIZE) -> bytes:
    mask = np.zeros((height, width), np.uint8)
    mask[height // 4 : 3 * height // 4, width // 4 : 3 * width // 4] = 255
    buffer = io.BytesIO()
    Image.fromarray(mask).save(buffer, "PNG")
    return buffer.getvalue()


def test_an_object_mask_is_stored_with_its_frame(client: TestClient) -> None:
    cameras = _cameras(4)
    cameras["frames"][3].update(split="test", mask="masks/held_out.png")
    images = {f"v{i}.png": _png(seed=i) for i in range(4)}
    response = client.post(
        "/v1/jobs", files=_parts(cameras, images, masks={"held_out.png": _mask_png()})
    )
    assert response.status_code == 201, response.text
    upload = client.data_dir / "jobs" / response.json()["id"] / "upload"  # type: ignore[attr-defined]
    stored = json.loads((upload / "cameras.json").read_text())
    assert [f.get("mask") for f in stored["frames"]] == [None, None, None, "masks/003.png"]
    assert (upload / "masks" / "003.png").read_bytes() == _mask_png()


def test_depth_bounds_and_init_box_are_stored_with_the_upload(client: TestClient) -> None:
    cameras = {**_cameras(), "near": 0.5, "far": 9.0, "init_box": [[-1, -1, -1], [1, 1, 1]]}
    cameras["frames"][1].update(near=1.0, far=4.0)
    response = client.post("/v1/jobs", files=_parts(cameras))
    assert response.status_code == 201, response.text
    upload = client.data_dir / "jobs" / response.json()["id"] / "upload"  # type: ignore[attr-defined]
    stored = json.loads((upload / "cameras.json").read_text())
    assert (stored["near"], stored["far"]) == (0.5, 9.0)
    assert stored["init_box"] == [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]
    assert [(f.get("near"), f.get("far")) for f in stored["frames"]] == [
        (None, None),
        (1.0, 4.0),
        (None, None),
    ]


BAD_CASES: dict[str, tuple[Any, int, str]] = {
    "mask not uploaded": (lambda: _parts(_with_first(mask="m.png")), 422, "'m.png' was not"),
    "mask of another size": (
        lambda: _parts(_with_first(mask="m.png"), masks={"m.png": _mask_png(SIZE, SIZE // 2)}),
        422,
        "m.png: mask is 32x16, its image 32x32",
    ),
    "mask not an image": (
        lambda: _parts(_with_first(mask="m.png"), masks={"m.png": b"plain text"}),
        422,
        "m.png",
    ),
    "malformed JSON": (lambda: _parts('{"frames": ['), 422, "not valid JSON"),
    "unknown field": (lambda: _parts({**_cameras(), "convension": "opengl"}), 422, "convention"),
    "missing convention": (
        lambda: _parts({k: v for k, v in _cameras().items() if k != "convention"}),
        422,
        "convention",
    ),
    "near beyond far": (
        lambda: _parts({**_cameras(), "near": 5.0, "far": 2.0}),
        422,
        "near (5.0) must be less than far (2.0)",
    ),
    "frame bounds reversed": (
        lambda: _parts(_with_first(near=3.0, far=1.0)),
        422,
        "frame 'v0.png': near (3.0) must be less than far (1.0)",
    ),
    "init box inside out": (
        lambda: _parts({**_cameras(), "init_box": [[0, 0, 0], [1, 1, -1]]}),
        422,
        "init_box: the first corner",
    ),
    "3x3 matrix": (lambda: _parts(_with_first(matrix=[[1, 0, 0]] * 3)), 422, "4x4"),
    "non-rigid rotation": (
        lambda: _parts(
            _with_first(matrix=[[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
        ),
        422,
        "rigid",
    ),
    "NaN focal length": (
        lambda: _parts(json.dumps(_cameras()).replace('"fx": 30.0', '"fx": NaN', 1)),
        422,
        "fx",
    ),
    "count mismatch": (
        lambda: _parts(_cameras(), {"v0.png": _png(), "v1.png": _png()}),
        422,
        "missing: v2.png",
    ),
    "unlisted image": (
        lambda: _parts(_cameras(), {**{f"v{i}.png": _png() for i in range(3)}, "x.png": _png()}),
        422,
        "x.png",
    ),
    "one training view": (lambda: _parts(_cameras(1), {"v0.png": _png()}), 422, "2"),
    "corrupt image": (
        lambda: _parts(_cameras(), {"v0.png": b"not an image", "v1.png": _png(), "v2.png": _png()}),
        422,
        "v0.png",
    ),
    "truncated image": (
        lambda: _parts(_cameras(), {"v0.png": _png()[:300], "v1.png": _png(), "v2.png": _png()}),
        422,
        "v0.png",
    ),
    "100-megapixel bomb": (
        lambda: _parts(
            _cameras(), {"v0.png": _png_bomb(10_000, 10_000), "v1.png": _png(), "v2.png": _png()}
        ),
        413,
        "megapixels",
    ),
    "path traversal": (
        lambda: _parts(
            {**_cameras(), "frames": [_frame("../../etc/passwd"), *_cameras()["frames"][1:]]},
            {"../../etc/passwd": _png(), "v1.png": _png(), "v2.png": _png()},
        ),
        422,
        "no '..'",
    ),
    "path traversal in the file name": (
        lambda: _parts(_cameras(), {"../v0.png": _png(), "v1.png": _png(), "v2.png": _png()}),
        422,
        "plain name",
    ),
    "bad spec": (lambda: _parts(_cameras(), spec={"iterations": -5}), 422, "iterations"),
    "spec typo": (lambda: _parts(_cameras(), spec={"iteration": 5}), 422, "iteration"),
    "both lengths": (
        lambda: _parts(_cameras(), spec={"iterations": 5, "time_budget_s": 60}),
        422,
        "not both",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_CASES))
def test_bad_upload_is_refused_with_a_message_and_leaves_nothing(
    client: TestClient, case: str
) -> None:
    make, status, words = BAD_CASES[case]
    response = client.post("/v1/jobs", files=make())
    assert response.status_code == status, response.text
    body = response.json()
    assert set(body) == {"code", "message"} and body["message"]
    assert words in body["message"], body
    _nothing_left(client)


def test_unknown_deleted_and_unfinished_jobs(client: TestClient) -> None:
    assert client.get("/v1/jobs/job_00000000000000000000").status_code == 404
    assert client.get("/v1/jobs/../../etc").status_code == 404
    job = client.post("/v1/jobs", files=_parts(_cameras())).json()
    camera = {"convention": "opencv", "pose": "camera_to_world",
              "matrix": _frame("x")["matrix"], "fx": 30, "fy": 30, "cx": 16, "cy": 16,
              "width": 32, "height": 32}  # fmt: skip
    response = client.post(f"/v1/models/{job['id']}/render", json={"camera": camera})
    assert response.status_code == 409 and "queued" in response.json()["message"]
    assert client.delete(f"/v1/jobs/{job['id']}").status_code == 204
    assert client.get(f"/v1/jobs/{job['id']}").status_code == 404
    assert client.post(f"/v1/models/{job['id']}/render", json={"camera": camera}).status_code == 404
    _nothing_left(client)


def test_render_request_validation(client: TestClient) -> None:
    job = client.post("/v1/jobs", files=_parts(_cameras())).json()
    url = f"/v1/models/{job['id']}/render"
    no_convention = {"pose": "camera_to_world", "matrix": _frame("x")["matrix"], "fx": 30,
                     "fy": 30, "cx": 16, "cy": 16, "width": 32, "height": 32}  # fmt: skip
    response = client.post(url, json={"camera": no_convention})
    assert response.status_code == 422 and "convention" in response.json()["message"]
    response = client.post(url, json={})
    assert response.status_code == 422 and "exactly one" in response.json()["message"]
    camera = {**no_convention, "convention": "opencv"}
    response = client.post(url, json={"camera": camera, "mode": "fast"})
    assert response.status_code == 422 and "mode" in response.json()["message"]
    query = {k: v for k, v in camera.items() if k != "matrix"}
    query["matrix"] = ",".join(str(x) for row in camera["matrix"] for x in row)
    response = client.get(url, params={**query, "mode": "fast"})
    assert response.status_code == 422 and "mode" in response.json()["message"]
    # A valid request for a model that does not exist yet: 409, nothing stored is touched.
    assert client.get(url, params={**query, "mode": "baked"}).status_code == 409


def test_live_view_of_a_job_without_model_closes_with_4409(client: TestClient) -> None:
    from starlette.websockets import WebSocketDisconnect

    job = client.post("/v1/jobs", files=_parts(_cameras())).json()
    live = client.websocket_connect(f"/v1/models/{job['id']}/live")
    with live as ws, pytest.raises(WebSocketDisconnect) as closed:
        ws.receive_bytes()
    assert closed.value.code == 4409 and "queued" in closed.value.reason
    live = client.websocket_connect("/v1/models/job_nope/live")
    with live as ws, pytest.raises(WebSocketDisconnect) as closed:
        ws.receive_bytes()
    assert closed.value.code == 4404
    assert client.delete(f"/v1/jobs/{job['id']}").status_code == 204
    _nothing_left(client)


def _look_at_opengl(eye: np.ndarray) -> list[list[float]]:
    """Blender-style camera-to-world (OpenGL axes: +z back) of a camera at ``eye`` looking at
    the origin, +z up in the world."""
    back = eye / np.linalg.norm(eye)
    right = np.cross([0.0, 0.0, 1.0], back)
    right /= np.linalg.norm(right)
    up = np.cross(back, right)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, up, back, eye
    return c2w.tolist()


def _orbit(convention: str, pose: str) -> dict[str, Any]:
    """Three views of an orbit of radius 4 around the origin (the NeRF-Blender layout, 400x400
    at a 40° field of view, scaled to SIZE pixels), whose matrices are OpenGL camera-to-world
    whatever ``convention`` and ``pose`` the file claims."""
    focal = 0.5 * SIZE / np.tan(np.radians(20.0))
    frames = []
    for i, azimuth in enumerate((10.0, 120.0, 230.0)):
        a, elevation = np.radians(azimuth), np.radians(30.0)
        eye = 4.0 * np.array([np.cos(a) * np.cos(elevation), np.sin(a) * np.cos(elevation),
                              np.sin(elevation)])  # fmt: skip
        frames.append({"image": f"v{i}.png", "matrix": _look_at_opengl(eye), "fx": focal,
                       "fy": focal, "cx": SIZE / 2, "cy": SIZE / 2})  # fmt: skip
    return {"convention": convention, "pose": pose, "frames": frames}


def test_the_blender_orbit_with_its_own_reading_is_accepted(client: TestClient) -> None:
    response = client.post("/v1/jobs", files=_parts(_orbit("opengl", "camera_to_world")))
    assert response.status_code == 201, response.text


WRONG_READINGS = {
    # claimed (convention, pose) -> the fix the answer must name
    ("opencv", "camera_to_world"): ['"convention": "opengl"'],
    ("opengl", "world_to_camera"): ['"pose": "camera_to_world"'],
    ("opencv", "world_to_camera"): ['"convention": "opengl"', '"pose": "camera_to_world"'],
}


@pytest.mark.parametrize("claimed", sorted(WRONG_READINGS))
def test_matrices_read_the_wrong_way_are_refused_naming_the_fix(
    client: TestClient, claimed: tuple[str, str]
) -> None:
    response = client.post("/v1/jobs", files=_parts(_orbit(*claimed)))
    assert response.status_code == 422, response.text
    body = response.json()
    assert body["code"] == "implausible_poses"
    for fix in WRONG_READINGS[claimed]:
        assert fix in body["message"], body["message"]
    _nothing_left(client)


def test_an_init_box_behind_every_camera_is_refused(client: TestClient) -> None:
    # The bad-input cameras look down +z from z = 0: a box at z < 0 is behind all of them.
    response = client.post(
        "/v1/jobs", files=_parts({**_cameras(), "init_box": [[-1, -1, -5], [1, 1, -3]]})
    )
    assert response.status_code == 422 and "behind" in response.json()["message"]
    _nothing_left(client)


MESSAGE_CASES: dict[str, tuple[Any, str, str]] = {
    # case -> (parts, words the message must hold, words it must not)
    "unknown form part": (lambda: [*_parts(_cameras()), ("spec ", (None, "{}"))], "'spec '", ""),
    "corrupt image": (
        lambda: _parts(_cameras(), {"v0.png": b"not an image", "v1.png": _png(), "v2.png": _png()}),
        "v0.png",
        "BytesIO",
    ),
    "convention in capitals": (
        lambda: _parts({**_cameras(), "convention": "OpenGL"}),
        "got 'OpenGL'",
        "",
    ),
}


@pytest.mark.parametrize("case", sorted(MESSAGE_CASES))
def test_messages_name_what_was_sent(client: TestClient, case: str) -> None:
    make, words, never = MESSAGE_CASES[case]
    response = client.post("/v1/jobs", files=make())
    assert response.status_code == 422, response.text
    message = response.json()["message"]
    assert words in message and (not never or never not in message), message
    _nothing_left(client)


def test_no_error_message_names_a_server_path(client: TestClient) -> None:
    """Every refusal of the bad-input suite, read for the data directory (or any absolute
    path under it): a message is for the user, the server's layout is not."""
    data = str(client.data_dir)  # type: ignore[attr-defined]
    makers = [make for make, _, _ in BAD_CASES.values()]
    makers += [make for make, _, _ in MESSAGE_CASES.values()]
    makers += [lambda c=claimed: _parts(_orbit(*c)) for claimed in WRONG_READINGS]
    messages = [client.post("/v1/jobs", files=make()).json()["message"] for make in makers]
    job = client.post("/v1/jobs", files=_parts(_cameras())).json()
    for url in (f"/v1/jobs/{job['id']}/priors/7", f"/v1/jobs/{job['id']}/images/9",
                f"/v1/models/{job['id']}", "/v1/jobs/job_00000000000000000000"):  # fmt: skip
        messages.append(client.get(url).json()["message"])
    assert len(messages) == len(makers) + 4
    leaking = [m for m in messages if data in m or "/jobs/job_" in m or "staging" in m]
    assert not leaking, leaking


def test_an_index_out_of_range_says_the_range(client: TestClient) -> None:
    job = client.post("/v1/jobs", files=_parts(_cameras())).json()
    response = client.get(f"/v1/jobs/{job['id']}/priors/7")
    assert response.status_code == 404
    assert "3 training views: depth priors 0 to 2" in response.json()["message"]
    response = client.get(f"/v1/jobs/{job['id']}/images/3")
    assert response.status_code == 404 and "indices 0 to 2" in response.json()["message"]
    # In range but not computed yet: the 'none yet' answer stays.
    assert "none yet" in client.get(f"/v1/jobs/{job['id']}/priors/0").json()["message"]


def test_a_bare_camera_body_says_to_wrap_it(client: TestClient) -> None:
    job = client.post("/v1/jobs", files=_parts(_cameras())).json()
    camera = {"convention": "opencv", "pose": "camera_to_world",
              "matrix": _frame("x")["matrix"], "fx": 30, "fy": 30, "cx": 16, "cy": 16,
              "width": 32, "height": 32}  # fmt: skip
    response = client.post(f"/v1/models/{job['id']}/render", json=camera)
    assert response.status_code == 422
    message = response.json()["message"]
    assert '{"camera": {...}}' in message and "Extra inputs" not in message, message
    assert message.count("\n") == 0 and message.count(";") <= 1, message
