"""``sparsesplat render`` through the real command: the api PinholeCamera JSON in either
convention, inline or from a file, and a clear message with exit code 2 for each mistake."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from tests.cli.conftest import run_cli
from tests.cli.scenes import frame_matrix, object_cameras


def _camera(convention: str, pose: str, k: int = 4, **changes: Any) -> dict[str, Any]:
    """The k-th ring camera of the trained scene (a held-out one) as render JSON."""
    cam = object_cameras(6, 32)[k]
    spec: dict[str, Any] = {
        "convention": convention,
        "pose": pose,
        "matrix": frame_matrix(cam, convention, pose),
        "fx": cam.fx,
        "fy": cam.fy,
        "cx": cam.cx,
        "cy": cam.cy,
        "width": cam.width,
        "height": cam.height,
    }
    spec.update(changes)
    return spec


def _png(path: Path) -> np.ndarray:
    return np.asarray(Image.open(path)).astype(np.int16)


def test_both_conventions_render_the_same_view(
    trained: tuple[Path, Path, list[str]], tmp_path: Path
) -> None:
    _, run, _ = trained
    gl = tmp_path / "gl.json"
    gl.write_text(json.dumps(_camera("opengl", "camera_to_world")))
    a = run_cli("render", str(run), "--camera", str(gl), "-o", str(tmp_path / "new" / "a.png"))
    assert a.returncode == 0, a.stderr
    # Inline JSON, pretty-printed well past the longest file name (was: OSError).
    inline = json.dumps(_camera("opencv", "world_to_camera"), indent=8)
    assert len(inline) > 300
    b = run_cli("render", str(run), "--camera", inline, "-o", str(tmp_path / "b.png"))
    assert b.returncode == 0, b.stderr
    img_a, img_b = _png(tmp_path / "new" / "a.png"), _png(tmp_path / "b.png")
    assert img_a.shape == (32, 32, 3)
    assert np.abs(img_a - img_b).max() <= 1, "same camera, two conventions"
    assert img_a.std() > 5, "the object is in view (not a blank image)"
    assert "warning" not in a.stderr


# (id, camera JSON or None for the valid one, extra args, needles)
BAD: list[tuple[str, Any, list[str], list[str]]] = [
    ("missing convention", {k: v for k, v in _camera("opencv", "world_to_camera").items()
                            if k != "convention"}, [], ["missing 'convention': say 'opencv'"]),
    ("missing pose", {k: v for k, v in _camera("opencv", "world_to_camera").items()
                      if k != "pose"}, [], ["missing 'pose'"]),
    ("old keys", {**{k: v for k, v in _camera("opencv", "world_to_camera").items()
                     if k != "matrix"}, "world_to_camera": np.eye(4).tolist()}, [],
     ["unknown field 'world_to_camera'", "'matrix'"]),
    ("typo", {**_camera("opengl", "camera_to_world"), "convension": "opengl"}, [],
     ["did you mean 'convention'?"]),
    ("non-rigid", _camera("opencv", "world_to_camera", matrix=(2 * np.eye(4)).tolist()), [],
     ["not rigid"]),
    ("reflection", _camera("opencv", "world_to_camera", matrix=np.diag([1.0, 1, -1, 1]).tolist()),
     [], ["determinant -1"]),
    ("bad convention", {**_camera("opencv", "world_to_camera"), "convention": "OpenGL"}, [],
     ["convention: Input should be 'opencv' or 'opengl', got 'OpenGL'"]),
    ("not json", "{not json", [], ["not valid JSON"]),
    ("no suffix", None, ["-o", "OUT/view"], ["no suffix", ".png"]),
    ("bad suffix", None, ["-o", "OUT/view.txt"], ["'.txt'", ".png"]),
    ("depth suffix", None, ["--depth", "OUT/d.png"], ["--depth", ".npy"]),
]  # fmt: skip


@pytest.mark.parametrize(("camera", "extra", "needles"), [b[1:] for b in BAD],
                         ids=[b[0] for b in BAD])  # fmt: skip
def test_bad_render_input_is_a_message_and_exit_2(
    trained: tuple[Path, Path, list[str]],
    tmp_path: Path,
    camera: Any,
    extra: list[str],
    needles: list[str],
) -> None:
    _, run, _ = trained
    spec = _camera("opencv", "world_to_camera") if camera is None else camera
    path = tmp_path / "cam.json"
    path.write_text(spec if isinstance(spec, str) else json.dumps(spec))
    args = [a.replace("OUT", str(tmp_path)) for a in extra]
    if "-o" not in args:
        args += ["-o", str(tmp_path / "view.png")]
    result = run_cli("render", str(run), "--camera", str(path), *args)
    assert result.returncode == 2, (result.returncode, result.stderr[-3000:])
    assert result.stderr.startswith("sparsesplat render: "), result.stderr
    assert "Traceback" not in result.stderr
    for needle in needles:
        assert needle in result.stderr, result.stderr


def test_missing_camera_file_and_checkpoint(
    trained: tuple[Path, Path, list[str]], tmp_path: Path
) -> None:
    _, run, _ = trained
    result = run_cli("render", str(run), "--camera", "cam.jsno", "-o", str(tmp_path / "v.png"))
    assert result.returncode == 2 and "--camera cam.jsno: file not found" in result.stderr
    cam = tmp_path / "cam.json"
    cam.write_text(json.dumps(_camera("opencv", "world_to_camera")))
    (tmp_path / "empty_run").mkdir()
    result = run_cli("render", str(tmp_path / "empty_run"), "--camera", str(cam), "-o", "v.png")
    assert result.returncode == 2 and "checkpoint.pt: no such file" in result.stderr
    assert "Traceback" not in result.stderr


def test_a_camera_facing_away_warns(trained: tuple[Path, Path, list[str]], tmp_path: Path) -> None:
    _, run, _ = trained
    # The held-out camera read in the wrong convention: it looks straight away from the object.
    spec = _camera("opencv", "camera_to_world")
    spec["matrix"] = _camera("opengl", "camera_to_world")["matrix"]
    path = tmp_path / "cam.json"
    path.write_text(json.dumps(spec))
    result = run_cli("render", str(run), "--camera", str(path), "-o", str(tmp_path / "v.png"))
    assert result.returncode == 0, result.stderr
    assert "warning: the camera sees (almost) nothing of the model" in result.stderr
    assert "'convention'" in result.stderr
